"""Does a refinement stay at the truth when it starts there? ``python -m evaluation.refine_from_truth
--scan james.obj --scan-landmarks james.ljson --report r.json``.

The frames of a Florence video of the scan (:func:`evaluation.florence.protocol.video_landmarks`,
its landmarks projected, no detector) are each refined twice by
:func:`morphable.refinement.refine`: from the frame's landmark fit, and from the same fit with
its identity and expression replaced by the scan's surface fit (the model's closest shape to the
scan, :class:`evaluation.florence.methods.SurfaceFit`; the pose stays the landmark fit's).
Variants: ``gar`` (the gar renderer, ``$MORPHABLE_GAR_WEIGHTS`` or the committed weights),
``classical`` and ``no-photo`` (the classical refinement with its photometric terms off: the
landmark and prior terms alone, the ablation's ``landmarks-refit``).

Per condition, variant and start, the means over the frames: ``mm_start`` / ``mm_end``, the
mean distance (mm, model frame, all vertices) of the frame's identity + expression shape to the
surface fit's, before and after; ``photo_start`` / ``photo_end``, the photometric loss. A
renderer whose loss has its minimum at the scan's shape keeps the surface start near 0 mm and
moves the landmark start towards it more than ``no-photo`` does.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity
from morphable.refinement import NO_PHOTOMETRIC

from .videos import CONDITIONS

__all__ = ["VARIANTS", "refine_from_truth", "format_table", "main"]

VARIANTS = {"gar": ("gar", None), "classical": ("classical", None),
            "no-photo": ("classical", NO_PHOTOMETRIC)}
"""name -> (renderer, loss weight overrides of :func:`morphable.refinement.refine`)."""


def refine_from_truth(scan, model, conditions=tuple(CONDITIONS), *,
                      variants=tuple(VARIANTS), steps: int = 25, n_sampled: int = 5,
                      n_frames: int = 30, seed: int = 0, log=None) -> dict:
    """The report of the module docstring for ``scan`` (:class:`evaluation.scans.Scan`, mm)
    and ``model``: ``{"mean_face_mm", "surface_fit", "conditions": {c: {variant: {start:
    {"mm_start", "mm_end", "photo_start", "photo_end", "frames": [...]}}}}}`` with start
    "landmark" or "surface"."""
    from morphable.fitting import fit_landmarks
    from morphable.refinement import refine
    from morphable.renderer_plugins import get_renderer

    from .florence.methods import SurfaceFit
    from .florence.protocol import video_landmarks

    for v in variants:
        if v not in VARIANTS:
            raise InputError(f"unknown variant {v!r}; choose from {', '.join(VARIANTS)}")
    ids = np.arange(model.n_vertices)
    t = time.perf_counter()
    alpha, beta = SurfaceFit().fit_scan(model, scan)[:2]
    truth = model.vertices_at(ids, alpha, beta)
    report = {"mean_face_mm": float(np.linalg.norm(model.vertices_at(ids) - truth, axis=1).mean()),
              "surface_fit": {"seconds": round(time.perf_counter() - t, 2)}, "steps": int(steps),
              "conditions": {}}
    renderers = {v: get_renderer(VARIANTS[v][0]) for v in variants}

    def distance(fit, i):
        v = model.vertices_at(ids, fit.frame_identity[i], fit.expression[i])
        return float(np.linalg.norm(v - truth, axis=1).mean())

    for c in conditions:
        video, _ = video_landmarks(scan, model, c, n_sampled, n_frames, seed, with_frames=True)
        frames = video.images
        fit = fit_landmarks(model, np.asarray(video.landmarks, dtype=np.float64),
                            list(video.image_size), shared_identity=False, camera="perspective",
                            focal_px=video.focal_px, landmark_std_px="auto")
        cell = {v: {"landmark": [], "surface": []} for v in variants}
        for i, image in enumerate(frames):
            at_truth = dataclasses.replace(fit, frame_identity=fit.frame_identity.copy(),
                                           expression=fit.expression.copy())
            at_truth.frame_identity[i], at_truth.expression[i] = alpha, beta
            for start, f in (("landmark", fit), ("surface", at_truth)):
                d0 = distance(f, i)
                for v in variants:
                    new, rep = refine(image, f, renderers[v], steps=steps, frame=i,
                                      weights=VARIANTS[v][1])
                    cell[v][start].append({
                        "mm_start": d0, "mm_end": distance(new, i),
                        "photo_start": rep["photometric_loss"][0],
                        "photo_end": rep["photometric_loss"][-1], "seconds": rep["runtime_s"]})
        report["conditions"][c] = {v: {s: {**{k: float(np.mean([r[k] for r in rows]))
                                              for k in rows[0]}, "frames": rows}
                                       for s, rows in starts.items()}
                                   for v, starts in cell.items()}
        if log:
            for v, starts in report["conditions"][c].items():
                log(f"{c} {v}: " + ", ".join(f"from {s} {r['mm_start']:.2f} -> {r['mm_end']:.2f} mm"
                                             for s, r in starts.items()))
    return report


def format_table(report: dict) -> str:
    """A Markdown table: one row per condition and variant, mm start -> end from each start."""
    lines = ["| condition | variant | from the landmark fit (mm) | from the surface fit (mm) |",
             "| --- | --- | ---: | ---: |"]
    for c, cell in report["conditions"].items():
        for v, s in cell.items():
            lines.append(f"| {c} | {v} | {s['landmark']['mm_start']:.3f} -> "
                         f"{s['landmark']['mm_end']:.3f} | {s['surface']['mm_start']:.3f} -> "
                         f"{s['surface']['mm_end']:.3f} |")
    return "\n".join(lines)


@one_line_errors("python -m evaluation.refine_from_truth")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.refine_from_truth",
                                description=__doc__.splitlines()[0])
    p.add_argument("--scan", required=True, help="scan mesh (OBJ, PLY, ...)")
    p.add_argument("--scan-landmarks", required=True, help="its 3D landmarks")
    p.add_argument("--model", default="sfm")
    p.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=list(CONDITIONS))
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--steps", type=int, default=25, help="refinement steps per frame")
    p.add_argument("--frames", type=int, default=5, help="sampled frames per video")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--report", required=True, help="output JSON")
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    if args.steps < 1:
        raise InputError(f"--steps {args.steps}: must be at least 1")
    if not Path(args.report).resolve().parent.is_dir():     # before the run, not after it
        raise InputError(f"{args.report}: output folder does not exist")
    from morphable import load_model

    from .scans import load_scan

    model = load_model(args.model)
    scan = load_scan(args.scan, args.scan_landmarks)
    report = refine_from_truth(scan, model, args.conditions, variants=args.variants,
                               steps=args.steps, n_sampled=args.frames, seed=args.seed,
                               log=None if args.quiet else print)
    report["command"] = ("python -m evaluation.refine_from_truth "
                         + " ".join(argv if argv is not None else sys.argv[1:]))
    from morphable.io.atomic import atomic_path

    with atomic_path(args.report) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=1))
    print(format_table(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
