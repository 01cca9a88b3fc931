"""``morphable render``: a shaded image of a mesh, a model or a fitted face (Lambertian)."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .common import add_camera_arguments, add_source_arguments, check_outputs, source_and_camera


def _numbers(text, n, what):
    try:
        values = [float(x) for x in text.replace(",", " ").split()]
    except ValueError:
        raise InputError(f"{what} {text!r}: expected numbers") from None
    if len(values) not in n:
        raise InputError(f"{what} {text!r}: expected {' or '.join(map(str, n))} numbers")
    return values


def add_parser(sub):
    from ..raster.shaded_images import DEFAULT_AMBIENT, DEFAULT_LIGHT

    p = sub.add_parser("render", help="shaded image of a mesh (vertex colour or texture, "
                       "SH or directional light)")
    add_source_arguments(p)
    add_camera_arguments(p, 512)
    p.add_argument("--texture", help="texture image for the mesh's UVs (default: the OBJ's material map)")
    p.add_argument("--no-texture", action="store_true", help="ignore the OBJ's material map")
    p.add_argument("--color", default="0.75,0.75,0.75", help="surface colour r,g,b in [0, 1] (default 0.75,0.75,0.75)")
    p.add_argument("--light", action="append", metavar="X,Y,Z[,I]|none",
                   help="directional light towards X,Y,Z in the camera frame (+z to the viewer), "
                        "intensity I (default 0.75); repeatable; write --light=-1,0,1 for a "
                        "negative first number; none: unlit, the colour or texture as it is "
                        "(default: one light towards "
                        f"{','.join(f'{x:.2f}' for x in DEFAULT_LIGHT.direction)}, intensity "
                        f"{float(DEFAULT_LIGHT.color[0]):g})")
    p.add_argument("--ambient", type=float, default=DEFAULT_AMBIENT,
                   help=f"ambient light with --light (default {DEFAULT_AMBIENT:g})")
    p.add_argument("--sh", metavar="C0,...,C8", help="9 (grey) or 27 (RGB, per coefficient r,g,b) "
                   "SH coefficients instead of --light; 1,0,...,0 is uniform white")
    p.add_argument("--shadows", action="store_true", help="cast shadows of the directional lights")
    p.add_argument("--background", default="1,1,1", help="r,g,b in [0, 1], or an image of the output size (default 1,1,1: white)")
    p.add_argument("--out", required=True, help="output PNG")
    return p


def run(args):
    import numpy as np

    from ..raster import DirectionalLight, as_texture, render, save_image_png

    check_outputs(args.out)
    if args.supersample is None or args.supersample < 1:
        raise InputError(f"--supersample must be >= 1, got {args.supersample}")
    mesh, cam = source_and_camera(args, 512)
    texture = None
    tex_path = None if args.no_texture else (args.texture or mesh.texture)
    if tex_path is not None:
        if not Path(tex_path).is_file():
            raise InputError(f"{tex_path}: no such texture file")
        if mesh.uv is None:
            raise InputError(f"{args.mesh or args.fit}: the mesh has no UV coordinates for --texture")
        uv, tuv, image = mesh.uv, mesh.triangle_uv, as_texture(tex_path)
        if mesh.model is not None:
            # a model's texture from photos has its own layout (ICT: the face tile only)
            from ..texture import texture_layout

            uv, tuv, _ = texture_layout(mesh.model, image.shape[0])
        texture = (uv, tuv, image)
    color = _numbers(args.color, (3,), "--color")
    if args.sh:
        c = _numbers(args.sh, (9, 27), "--sh")
        light = np.array(c).reshape(9, 3) if len(c) == 27 else np.array(c)
    elif args.light and "none" in args.light:
        if len(args.light) > 1:
            raise InputError("--light none: give no other --light")
        light = np.eye(9)[0]  # uniform white SH: the albedo as it is
    elif args.light:
        light = []
        for item in args.light:
            x = _numbers(item, (3, 4), "--light")
            light.append(DirectionalLight(direction=x[:3], color=x[3] if len(x) == 4 else 0.75))
    else:
        light = None
    bg = args.background
    if Path(bg).suffix.lower() in (".png", ".jpg", ".jpeg", ".ppm", ".bmp", ".tif", ".tiff"):
        if not Path(bg).is_file():
            raise InputError(f"{bg}: no such background image")
    elif not Path(bg).is_file():
        bg = _numbers(bg, (3,), "--background")
    image = render(mesh.vertices, mesh.triangles, cam, colors=np.array(color), texture=texture,
                   light=light, ambient=args.ambient, background=bg, shadows=args.shadows,
                   supersample=args.supersample)
    save_image_png(args.out, image)
    print(args.out)
    return 0
