"""``morphable profile``: a photo turned to another head pose through its fit (face profiling,
:mod:`morphable.profiling`), with the fit's surface points as labels at the new pose."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .common import add_detector_arguments, add_model_argument, check_outputs, model_from


def add_parser(sub):
    p = sub.add_parser("profile", help="turn the face of a photo to another pose through its fit, "
                       "with labels (face profiling)")
    p.add_argument("image", metavar="PHOTO", help="a photo of one face")
    p.add_argument("--landmarks", metavar="PTS",
                   help="its landmarks (iBUG .pts/.ljson, or face-mesh .npy/.json); default: detect")
    add_model_argument(p)
    add_detector_arguments(p)
    p.add_argument("--yaw", type=float, required=True, metavar="DEG",
                   help="turn about the vertical axis, degrees in [-90, 90] (positive: the fit's yaw grows)")
    p.add_argument("--pitch", type=float, default=0.0, metavar="DEG",
                   help="turn about the horizontal axis, degrees in [-60, 60] (default 0)")
    p.add_argument("--texture-size", type=int, default=512, help="texels per side (default 512)")
    p.add_argument("--out", required=True, help="output .png: the turned photo")
    p.add_argument("--labels", metavar="JSON",
                   help="output .json: the 68 iBUG and 478 face-mesh points at the new pose (px, "
                        "0-based; hidden ones where they project) with visibility, and the camera")
    return p


def labels_json(out: dict) -> dict:
    """The JSON-ready labels of :func:`morphable.profiling.profile_photo`'s result (undefined
    points as null)."""
    import numpy as np

    def rows(a):
        return [[float(x), float(y)] if np.isfinite([x, y]).all() else None for x, y in a]

    d = {"camera": out["camera"].to_dict()}
    for k in ("68", "478"):
        d[f"points{k}"] = rows(out["landmarks_px"][k])
        d[f"visible{k}"] = [bool(x) for x in out["visible"][k]]
    return d


def run(args):
    import json

    from ..io.atomic import atomic_path
    from ..pipeline import fit_images
    from ..profiling import MAX_PITCH_DEG, MAX_YAW_DEG, profile_photo
    from ..raster import save_image_png

    check_outputs(args.out)
    if args.labels:
        folder = Path(args.labels).parent
        if Path(args.labels).suffix.lower() != ".json":
            raise InputError(f"{args.labels}: --labels must be a .json file")
        if not (folder if str(folder) else Path(".")).is_dir():
            raise InputError(f"{args.labels}: output folder {folder} does not exist")
    if not abs(args.yaw) <= MAX_YAW_DEG:
        raise InputError(f"--yaw must be within +-{MAX_YAW_DEG:.0f} degrees, got {args.yaw}")
    if not abs(args.pitch) <= MAX_PITCH_DEG:
        raise InputError(f"--pitch must be within +-{MAX_PITCH_DEG:.0f} degrees, got {args.pitch}")
    if not 8 <= args.texture_size <= 8192:
        raise InputError(f"--texture-size must be 8..8192 texels, got {args.texture_size}")
    if not Path(args.image).is_file():
        raise InputError(f"{args.image}: no such photo")
    model = model_from(args)
    if model.uv is None:
        raise InputError(f"{args.model}: the model has no UV coordinates, so the face cannot be textured")
    fit = fit_images(args.image, args.landmarks, model=model, landmark_detector=args.landmark_detector,
                     face_detector=args.face_detector).fit
    out = profile_photo(args.image, fit, args.yaw, args.pitch, texture_size=args.texture_size)
    save_image_png(args.out, out["image"] / 255.0)
    if args.labels:
        d = dict(labels_json(out), image=str(args.image), yaw_deg=args.yaw, pitch_deg=args.pitch)
        with atomic_path(args.labels) as tmp:
            Path(tmp).write_text(json.dumps(d))
    seen = int(out["visible"]["68"].sum())
    print(f"{args.out}: turned {args.yaw:+g} deg yaw, {args.pitch:+g} deg pitch; {seen} of 68 points visible")
    return 0
