"""``morphable fit``: fit the model to the 68 landmarks of one or more images of a person.

Landmarks come from ``--landmarks`` (iBUG ``.pts``, one per image) or are detected with
dlib. Writes the mesh (OBJ with UVs; with several images the shared identity without
expression) and a JSON report; both are written only once the fit has succeeded.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.atomic import atomic_path
from .common import add_model_argument, model_from


def add_parser(sub):
    p = sub.add_parser("fit", help="fit identity, expression and pose to 2D landmarks of images")
    p.add_argument("images", nargs="+", metavar="IMAGE", help="images of one person")
    p.add_argument("--landmarks", nargs="+", metavar="PTS",
                   help="iBUG .pts files, one per image (default: detect with dlib)")
    add_model_argument(p)
    p.add_argument("--camera", choices=("affine", "perspective"), default="affine")
    p.add_argument("--focal", type=float, default=None, help="focal length in px (perspective; default max(W, H))")
    p.add_argument("--iterations", type=int, default=4, help="nonlinear iterations (default 4)")
    p.add_argument("--robust", action="store_true", help="Huber loss against outlying landmarks")
    p.add_argument("--independent", action="store_true",
                   help="fit each image on its own; the mesh is the average identity")
    p.add_argument("--detector", choices=("hog", "cnn"), default="hog", help="dlib face detector")
    p.add_argument("--out-mesh", help="output mesh (.obj with UVs, .ply, .stl)")
    p.add_argument("--report", help="output JSON report")
    p.add_argument("--overlay", help="output .png/.jpg: the image with the fitted mesh and landmarks "
                                     "(several images: NAME_0.png, NAME_1.png, ...)")
    p.add_argument("--overlay-style", choices=("shaded", "wireframe", "none"), default="shaded",
                   help="how --overlay draws the mesh (default shaded)")
    return p


def _image_size(path: Path):
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return im.size
    except FileNotFoundError:
        raise InputError(f"{path}: no such image") from None
    except (OSError, UnidentifiedImageError) as e:
        raise InputError(f"{path}: cannot read image ({e})") from None


def run(args):
    from ..fitting import fit_landmarks
    from ..io.landmarks import read_pts

    if args.overlay:
        from ..overlay import check_overlay_path

        check_overlay_path(args.overlay)
    for out in (args.out_mesh, args.report):
        # check the outputs' folders first: either every output is written or none
        if out and not Path(out).resolve().parent.is_dir():
            raise InputError(f"{out}: folder {Path(out).resolve().parent} does not exist")
    images = [Path(p) for p in args.images]
    sizes = [_image_size(p) for p in images]
    if args.landmarks:
        if len(args.landmarks) != len(images):
            raise InputError(f"--landmarks: {len(args.landmarks)} files for {len(images)} images")
        lms = []
        for path in args.landmarks:
            pts = read_pts(path)
            if pts.shape != (68, 2):
                raise InputError(f"{path}: expected 68 iBUG landmarks, got {len(pts)}")
            lms.append(pts)
    else:
        from ..fitting.detect import detect_landmarks

        lms = [detect_landmarks(p, detector=args.detector) for p in images]
    if args.iterations < 0:
        raise InputError(f"--iterations must be >= 0, got {args.iterations}")
    model = model_from(args)
    res = fit_landmarks(model, np.stack(lms), np.array(sizes, dtype=np.float64), camera=args.camera,
                        focal_px=args.focal, n_iterations=args.iterations,
                        robust="huber" if args.robust else None,
                        shared_identity=not args.independent)
    report = res.to_dict(images=[str(p) for p in images])
    report["landmarks"] = [str(p) for p in args.landmarks] if args.landmarks else f"dlib {args.detector}"
    if args.overlay:  # first: drawing is the likeliest step to fail
        from ..overlay import write_overlays

        style = None if args.overlay_style == "none" else args.overlay_style
        report["overlays"] = [str(p) for p in write_overlays(args.overlay, res, images, mesh=style)]
    if args.out_mesh:
        from ..io.mesh import write_mesh

        verts = res.vertices(0) if res.n_frames == 1 else res.neutral_vertices()
        write_mesh(args.out_mesh, verts, model.triangles, model.uv, model.triangle_uv)
    if args.report:
        with atomic_path(args.report) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=2))
    for f in report["frames"]:
        print(f"{f['image']}: landmark RMSE {f['landmark_rmse_px']:.2f} px, yaw {f['yaw_deg']:.1f}, "
              f"pitch {f['pitch_deg']:.1f}, roll {f['roll_deg']:.1f} deg")
    print(f"{res.iterations} iterations, {res.runtime_ms:.1f} ms"
          + (f"; wrote {args.out_mesh}" if args.out_mesh else "")
          + (f" {args.report}" if args.report else ""))
    return 0
