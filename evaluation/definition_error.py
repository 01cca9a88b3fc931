"""How far a scan's landmark annotations lie from a model's landmark vertices, per group.

A model's landmark vertex (e.g. the SFM's eyebrow points) and an annotation of the same
iBUG landmark on a face are two definitions of one point: they differ by a few millimetres,
the same way in every photo of that face. The landmark fit models this as a per-landmark 3D
offset (``definition_std_mm`` of :func:`morphable.fitting.fit_landmarks`); this script
measures its size. For each scan, the model's identity is fitted to the scan *surface*
(:func:`morphable.fitting.fit_surface`: point-to-plane, so the landmarks play no part beyond
the first alignment), the scan's landmarks are moved rigidly onto the fitted face's landmark
vertices, and what remains is the definition difference. The table gives, per landmark group, its RMS per coordinate (x
right, y up, z out of the face) and over the coordinates (the 3D RMS / sqrt 3): the latter,
rounded, is the fitter's default profile ``DEFINITION_STD_MM``.

Commands::

    python -m evaluation.definition_error --synthetic-scan ict --n-scans 6
    python -m evaluation.definition_error --scan SCAN.obj --scan-landmarks SCAN.ljson

The default profile was measured on ICT FaceKit subjects (seeds 100-105), which are not the
held-out scan. :func:`morphable.fitting.fit_landmarks_3d` fits the model to a scan's own 3D
landmarks with that profile as their error: what the landmarks say about the face's shape
without images (``python -m evaluation.florence ... --methods landmarks-3d``).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors
from morphable.ibug68 import DEFINITION_GROUPS

__all__ = ["definition_offsets", "group_rms", "main"]


def definition_offsets(model, scan, **fit_kw) -> np.ndarray:
    """(68, 3) mm: scan landmark minus the fitted face's landmark vertex, after moving the scan
    landmarks rigidly onto those vertices (model axes); NaN where either is missing."""
    from morphable.fitting import fit_surface
    from morphable.metrics import align_landmarks

    alpha, _ = fit_surface(model, scan.vertices, scan.triangles, scan.landmarks,
                           name=scan.source, **fit_kw)
    ids = np.asarray(model.landmark_ids)
    ok = (ids >= 0) & np.isfinite(scan.landmarks).all(1)
    v = model.vertices(identity=alpha)
    T = align_landmarks(scan.landmarks[ok], v[ids[ok]], scale=False)
    out = np.full((68, 3), np.nan)
    out[ok] = T.apply(scan.landmarks[ok]) - v[ids[ok]]
    return out


def group_rms(offsets) -> dict:
    """``{group: {"xyz_mm": [x, y, z], "per_coordinate_mm": r, "n": n}}`` over the stacked
    (S, 68, 3) or (68, 3) offsets; groups without values are left out."""
    d = np.asarray(offsets, dtype=np.float64).reshape(-1, 68, 3)
    out = {}
    for name, ids in DEFINITION_GROUPS.items():
        g = d[:, ids].reshape(-1, 3)
        g = g[np.isfinite(g).all(1)]
        if len(g):
            out[name] = {"xyz_mm": np.sqrt((g ** 2).mean(0)).round(2).tolist(),
                         "per_coordinate_mm": round(float(np.sqrt((g ** 2).mean())), 2),
                         "n": int(len(g))}
    return out


def _parser():
    p = argparse.ArgumentParser(prog="python -m evaluation.definition_error",
                                description=__doc__.split("\n")[0])
    p.add_argument("--scan", help="scan mesh (OBJ, PLY, STL...)")
    p.add_argument("--scan-landmarks", help="its 68 or 51 3D landmarks")
    p.add_argument("--scan-units", default="auto")
    p.add_argument("--synthetic-scan", metavar="MODEL",
                   help="instead of --scan: subjects sampled from this model (e.g. ict)")
    p.add_argument("--n-scans", type=int, default=6)
    p.add_argument("--scan-seed", type=int, default=100, help="seed of the first subject")
    p.add_argument("--model", default="sfm", help="the model whose landmark vertices are compared")
    p.add_argument("--report", help="JSON to write")
    return p


@one_line_errors("evaluation.definition_error")
def main(argv=None) -> int:
    from morphable import load_model

    from .scans import load_scan, model_scan

    args = _parser().parse_args(argv)
    if (args.synthetic_scan is None) == (args.scan is None):
        raise InputError("give either --scan with --scan-landmarks, or --synthetic-scan")
    if args.scan is not None and args.scan_landmarks is None:
        raise InputError(f"--scan {args.scan}: --scan-landmarks is required")
    if args.report and not Path(args.report).resolve().parent.is_dir():
        raise InputError(f"{args.report}: output folder does not exist")
    if args.n_scans < 1:
        raise InputError(f"--n-scans: need at least 1, got {args.n_scans}")
    model = load_model(args.model)
    if args.synthetic_scan:
        source = load_model(args.synthetic_scan)
        scans = [model_scan(source, args.scan_seed + i) for i in range(args.n_scans)]
    else:
        scans = [load_scan(args.scan, args.scan_landmarks, args.scan_units)]
    offsets = np.stack([definition_offsets(model, s) for s in scans])
    table = group_rms(offsets)
    print(f"{'group':<11s} {'x':>6s} {'y':>6s} {'z':>6s} {'per coord':>10s}  (mm, RMS over "
          f"{len(scans)} scan{'s' * (len(scans) > 1)})")
    for name, row in table.items():
        x, y, z = row["xyz_mm"]
        print(f"{name:<11s} {x:6.2f} {y:6.2f} {z:6.2f} {row['per_coordinate_mm']:10.2f}")
    if args.report:
        from morphable.io.atomic import atomic_path

        with atomic_path(Path(args.report)) as tmp:
            tmp.write_text(json.dumps({"model": model.name, "scans": [s.source for s in scans],
                                       "groups": table,
                                       "command": "python -m evaluation.definition_error "
                                       + " ".join(sys.argv[1:] if argv is None else argv)}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
