"""``morphable texture``: a UV texture from the photos of an existing fit report (e.g. at
another size than the fit's ``--out-texture``), without fitting again."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .common import check_outputs


def add_parser(sub):
    p = sub.add_parser("texture", help="UV texture from the photos of a fit report (fit.json)")
    p.add_argument("fit", metavar="FIT.json", help="report written by morphable fit --report")
    p.add_argument("images", nargs="*", metavar="IMAGE",
                   help="the fit's photos, one per frame in order (default: those the report names)")
    p.add_argument("--size", type=int, default=512, help="texels per side (default 512)")
    p.add_argument("--confidence", metavar="PNG",
                   help="output .png: per texel the cosine of the squarest view that sees it (0: unseen)")
    p.add_argument("--no-mirror", action="store_true",
                   help="fill unseen texels by push-pull only, not from their mirror points")
    p.add_argument("--out", required=True, help="output texture .png")
    return p


def run(args):
    import numpy as np

    from ..raster.inputs import load_fit_frame, read_fit_report
    from ..texture import save_texture, texture_from_views

    check_outputs(args.out, args.confidence)
    if not 8 <= args.size <= 8192:
        raise InputError(f"--size must be 8..8192 texels, got {args.size}")
    report = read_fit_report(args.fit)
    frames = report.get("frames") or []
    images = args.images or [f.get("image") for f in frames]
    if len(images) != len(frames):
        raise InputError(f"{args.fit}: {len(images)} images for a fit of {len(frames)} frames")
    if any(im is None for im in images):
        raise InputError(f"{args.fit}: the report names no image for a frame; give the images")
    for im in images:
        if not Path(im).is_file():
            raise InputError(f"{im}: no such image")
    meshes, cameras = zip(*(load_fit_frame(args.fit, i) for i in range(len(frames))))
    model = meshes[0].model
    tex = texture_from_views(model, np.stack([m.vertices for m in meshes]), cameras, images,
                             size=args.size, mirror=not args.no_mirror)
    save_texture(tex, args.out, args.confidence)
    print(f"{args.out}: {100 * tex.observed[tex.layout].mean():.1f} % of the face seen, "
          f"{100 * tex.mirrored[tex.layout].mean():.1f} % mirrored, {tex.runtime_ms:.0f} ms")
    return 0
