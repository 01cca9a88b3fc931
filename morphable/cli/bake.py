"""``morphable bake``: a normal map (screen or UV space) with optional depth and mask PNGs."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .common import add_model_argument


def add_camera_arguments(p, size_default):
    """Camera options shared by bake and render."""
    p.add_argument("--size", type=int, default=None,
                   help=f"image size in pixels: square for MESH (default {size_default}); with "
                        "--fit the fit's image scaled to this width (default its own size)")
    p.add_argument("--camera", choices=("affine", "perspective"), default="affine",
                   help="projection for MESH (default affine); a fit brings its own camera")
    p.add_argument("--yaw", type=float, default=0.0,
                   help="degrees, positive turns the nose to the image right")
    p.add_argument("--pitch", type=float, default=0.0, help="degrees, positive turns the nose down")
    p.add_argument("--roll", type=float, default=0.0, help="degrees, counter-clockwise in the image")
    p.add_argument("--supersample", type=int, default=1, help="antialiasing samples per pixel and axis")


def add_source_arguments(p):
    p.add_argument("mesh", nargs="?", metavar="MESH",
                   help="mesh file (.obj .ply .stl .off .glb) or model name; default the --model mean")
    p.add_argument("--fit", metavar="FIT.json", help="draw a fitted face with its camera instead of MESH")
    p.add_argument("--frame", type=int, default=0, help="frame of the fit report (default 0)")
    add_model_argument(p)
    p.set_defaults(model=None)  # None: MESH, or the fit's own model


def check_outputs(*paths):
    """Fail before any work when an output cannot be written (no partial outputs)."""
    for path in paths:
        if path is None:
            continue
        path = Path(path)
        if path.suffix.lower() != ".png":
            raise InputError(f"{path}: output must be a .png file")
        folder = path.parent if str(path.parent) else Path(".")
        if not folder.is_dir():
            raise InputError(f"{path}: output folder {folder} does not exist")


def source_and_camera(args, size_default):
    """(Mesh, Camera or None) from MESH / --fit / --model and the camera options."""
    from ..io.registry import DEFAULT_MODEL, load_model
    from ..raster import frame_mesh
    from ..raster.inputs import load_fit_frame, load_mesh

    if args.size is not None and args.size <= 0:
        raise InputError(f"--size must be a positive number of pixels, got {args.size}")
    if args.fit and args.mesh:
        raise InputError("give either MESH or --fit, not both")
    if args.fit:
        mesh, cam = load_fit_frame(args.fit, args.frame,
                                   model=None if args.model is None else load_model(args.model))
        if args.size is not None:
            cam = resized(cam, args.size / cam.image_size[0])
        return mesh, cam
    mesh = load_mesh(args.mesh or args.model or DEFAULT_MODEL)
    size = args.size or size_default
    cam = frame_mesh(mesh.vertices, (size, size), yaw=args.yaw, pitch=args.pitch, roll=args.roll,
                     kind=args.camera)
    return mesh, cam


def resized(camera, factor):
    """The camera for the same view in an image scaled by ``factor``."""
    from dataclasses import replace

    W, H = camera.image_size
    size = (max(1, round(W * factor)), max(1, round(H * factor)))
    principal = (camera.principal + 0.5) * factor - 0.5
    return replace(camera, scale=camera.scale * factor, focal=camera.focal * factor,
                   image_size=size, principal=principal)


def add_parser(sub):
    p = sub.add_parser("bake", help="normal map (screen or UV space), depth and mask as PNG")
    add_source_arguments(p)
    p.add_argument("--space", choices=("screen", "uv"), default="screen")
    add_camera_arguments(p, 256)
    p.add_argument("--normals", choices=("camera", "world"), default="camera",
                   help="frame of screen-space normals (default camera: +z towards the viewer)")
    p.add_argument("--tangent", action="store_true", help="UV space: tangent-space normals "
                   "relative to the model's mean (MESH: the mesh itself)")
    p.add_argument("--out", required=True, help="normal map PNG, RGB = (n + 1) / 2")
    p.add_argument("--depth", help="16-bit depth PNG (screen space)")
    p.add_argument("--mask", help="mask PNG")
    return p


def run(args):
    from ..raster import (normal_map, save_depth_png, save_mask_png, save_normal_png,
                          uv_normal_map, visibility)

    check_outputs(args.out, args.depth, args.mask)
    if args.space == "uv" and args.depth:
        raise InputError("--depth is for --space screen (a UV map has no depth)")
    mesh, cam = source_and_camera(args, 256)
    if args.space == "screen":
        vis = visibility(mesh.vertices, mesh.triangles, cam, args.supersample)
        nmap = normal_map(mesh.vertices, mesh.triangles, frame=args.normals, vis=vis)
        save_normal_png(args.out, nmap)
        if args.depth:
            # depth of the pixel centre sample (depth is not averaged across silhouettes)
            s = vis.supersample
            save_depth_png(args.depth, vis.depth[s // 2::s, s // 2::s])
        if args.mask:
            save_mask_png(args.mask, vis.coverage() >= 0.5)
    else:
        nmap = uv_normal_map(mesh.layout, mesh.vertices, size=args.size or 256,
                             tangent=args.tangent)
        save_normal_png(args.out, nmap)
        if args.mask:
            save_mask_png(args.mask, (nmap != 0).any(-1))
    print(args.out)
    return 0
