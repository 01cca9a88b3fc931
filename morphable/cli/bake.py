"""``morphable bake``: a normal map (screen or UV space) with optional depth and mask PNGs."""
from __future__ import annotations

from ..errors import InputError
from .common import add_camera_arguments, add_source_arguments, check_outputs, source_and_camera


def add_parser(sub):
    p = sub.add_parser("bake", help="normal map (screen or UV space), depth and mask as PNG")
    add_source_arguments(p)
    p.add_argument("--space", choices=("screen", "uv"), default="screen",
                   help="screen: the camera's image; uv: the mesh's UV layout (default screen)")
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
