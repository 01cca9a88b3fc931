"""``morphable fit-batch``: fit many images (or subjects of several images), resumably.

Each item gets ``OUT/items/<id>/fit.obj`` and ``fit.json``, and a line in the append-only
``OUT/results.jsonl``; a re-run skips the recorded items, so a killed run resumes where it
stopped. A failed item is recorded with its error and the batch goes on (exit status 1 when
some item failed, 0 when all succeeded). Runs in this process, a local process pool
(``--workers N``) or on Dask (``--scheduler local`` for a LocalCluster, or ``tcp://host:port``).
"""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .common import add_fitting_arguments, add_model_argument


def add_parser(sub):
    p = sub.add_parser("fit-batch", help="fit a folder, glob or CSV/JSONL manifest of images, resumably")
    p.add_argument("input", metavar="INPUT",
                   help="folder of images (sibling .pts/.ljson used), a glob, or a .csv/.jsonl "
                        "manifest with columns image, landmarks, subject (rows of one subject "
                        "are fitted together)")
    p.add_argument("--out", required=True, help="output folder (items/<id>/fit.obj, fit.json, results.jsonl)")
    add_model_argument(p)
    p.add_argument("--workers", type=int, default=1, help="parallel processes or Dask workers (default 1)")
    p.add_argument("--scheduler", help="'local' (a Dask LocalCluster) or a Dask scheduler tcp://host:port "
                                          "(default: a local process pool)")
    add_fitting_arguments(p)
    p.add_argument("--independent", action="store_true",
                   help="fit the frames of a subject each on their own")
    p.add_argument("--mesh-format", choices=("obj", "ply", "stl"), default="obj",
                   help="format of each item's fit mesh (default obj)")
    return p


def run(args):
    from ..batch import read_manifest, run_batch
    from ..detection import resolve_detectors
    from ..io.registry import load_model
    from ..pipeline import fit_item

    if args.workers < 1:
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    if args.n_iterations < 0:
        raise InputError(f"--n-iterations must be >= 0, got {args.n_iterations}")
    if args.focal_px is not None and not args.focal_px > 0:
        raise InputError(f"--focal-px must be positive, got {args.focal_px}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if not out.exists() and not out.parent.resolve().is_dir():
        raise InputError(f"{out}: parent folder {out.parent} does not exist")
    items = read_manifest(args.input)
    for it in items:
        # absolute paths: workers of a remote scheduler do not share this working directory
        it.images = [str(Path(x).absolute()) for x in it.images]
        it.landmarks = [None if x is None else str(Path(x).absolute()) for x in it.landmarks]
    load_model(args.model)  # an unknown model fails here, once, not in every item
    resolve_detectors(args.landmark_detector, args.face_detector)  # likewise a bad detector choice
    options = {"model": args.model, "camera": args.camera, "focal_px": args.focal_px,
               "n_iterations": args.n_iterations, "robust": args.robust,
               "independent": args.independent,
               "landmark_detector": args.landmark_detector, "face_detector": args.face_detector,
               "landmark_std_px": args.landmark_std,
               "mesh_format": args.mesh_format}
    try:
        counts = run_batch(items, out, fit_item, options, workers=args.workers,
                           scheduler=args.scheduler, progress=not args.quiet)
    except PermissionError as e:
        raise InputError(f"{out}: cannot write ({e.strerror})") from None
    print(f"{len(items)} items: {counts['ok']} fitted, {counts['error']} failed, "
          f"{counts['skipped']} already done; results in {out / 'results.jsonl'}")
    return 1 if counts["error"] else 0
