"""The photometric fit on synthetic people of known geometry, 1 and several frames each:
``python -m evaluation.bench_photometric --people 6 --frames 1 5 --report bench.json``.

Each person: a random SFM identity and procedural albedo (:class:`neural.faces.renders.SyntheticFaces`,
seed other than the GAR's training), seen in F frames, each with its own expression, pose,
light and background, rendered at ``--image-size`` px by our Lambertian SH renderer. **These
frames are rendered by the same image model the photometric fit assumes (an inverse crime):**
they measure whether the solver finds the truth when the model holds, not how it does on
photographs. The landmarks are the true ones projected plus Gaussian noise
(``--landmark-noise`` px).

Rows (each person fitted with one shared identity over its F frames):

- ``mean face``: the model's mean;
- ``landmark-only``: :func:`morphable.fitting.fit_landmarks` on the noisy landmarks;
- ``landmarks-refit``: the same loop as ``photometric`` with the photometric term off
  (``photo`` weight 0: landmarks and priors in the crop cameras), what the pixels add is
  measured against this;
- ``photometric``: then :func:`morphable.refinement.refine_shared` with the classical
  renderer (``--steps`` Adam steps, one torch thread);
- ``photometric + GAR`` (with ``--gar``): the same loop with the GAR as its renderer (the
  committed weights and inverter, the GAR's default loss weights), as ``--refine gar``.

Metrics averaged over the people: ``neutral_mm`` (mean vertex distance of the identity without
expression from the true one, model frame, mm), ``frames_mm`` (mean over the frames of the
expressive face's vertex distance), ``s_per_frame`` (refinement seconds / F, one core).
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from morphable.errors import InputError, one_line_errors

__all__ = ["synthetic_person", "run_bench", "format_table", "main"]


def synthetic_person(faces, rng, n_frames: int) -> dict:
    """One person seen in ``n_frames`` frames -> dict: ``identity`` (K,), ``images``
    (F, R, R, 3), ``landmarks`` (F, 68, 2) px, ``vertices`` (F, V, 3) mm (model frame)."""
    who = faces.draw_identity(rng)
    images, lms, verts = [], [], []
    for _ in range(n_frames):
        e, pose = faces.draw_expression(rng), faces.draw_pose(rng)
        r = faces.render(who["identity"], who["albedo"], e, pose, faces.draw_light(rng),
                         faces.draw_background(rng))
        images.append(r["image"])
        lms.append(r["landmarks"])
        verts.append(faces.model.vertices(who["identity"], e))
    return {"identity": who["identity"], "images": np.stack(images), "landmarks": np.stack(lms),
            "vertices": np.stack(verts)}


def _errors(model, fit, person) -> tuple[float, float]:
    truth = model.vertices(person["identity"])
    neutral = float(np.linalg.norm(fit.neutral_vertices(np.float64) - truth, axis=1).mean())
    frames = float(np.mean([np.linalg.norm(fit.vertices(i, np.float64) - v, axis=1).mean()
                            for i, v in enumerate(person["vertices"])]))
    return neutral, frames


def run_bench(people: int = 6, frames=(1, 5), *, steps: int = 100, image_size: int = 256,
              landmark_noise: float = 1.0, seed: int = 2024, weights=None, gar: bool = False,
              progress=True) -> dict:
    """The table of the module docstring -> {"F frames": {row: {metric: value}}, ...};
    ``weights`` override the classical renderer's loss weights, ``gar`` adds the GAR's row."""
    from morphable.fitting import fit_landmarks
    from morphable.refinement import refine_shared
    from neural.faces.renders import SyntheticFaces

    faces = SyntheticFaces(resolution=image_size)
    model = faces.model
    # (row, renderer, loss weight overrides)
    refinements = [("landmarks-refit", "classical", {**(weights or {}), "photo": 0.0}),
                   ("photometric", "classical", weights)]
    if gar:
        from morphable.renderer_plugins import get_renderer

        refinements.append(("photometric + GAR", get_renderer("gar"), None))
    out = {}
    for F in frames:
        rng = np.random.default_rng(seed)
        rows = {k: {"neutral_mm": [], "frames_mm": [], "s_per_frame": []}
                for k in ("mean face", "landmark-only", *(r[0] for r in refinements))}
        for k in range(people):
            person = synthetic_person(faces, rng, F)
            lm = person["landmarks"] + rng.normal(0, landmark_noise, person["landmarks"].shape)
            fit = fit_landmarks(model, lm, np.tile([image_size, image_size], (F, 1)).astype(float),
                                n_iterations=4)
            mean = model.vertices(np.zeros(model.n_identity))
            rows["mean face"]["neutral_mm"].append(
                float(np.linalg.norm(mean - model.vertices(person["identity"]), axis=1).mean()))
            rows["mean face"]["frames_mm"].append(float(np.mean(
                [np.linalg.norm(mean - v, axis=1).mean() for v in person["vertices"]])))
            rows["mean face"]["s_per_frame"].append(0.0)
            fits = [("landmark-only", fit, 0.0)]
            for name, renderer, w in refinements:
                t = time.perf_counter()
                new, _, _ = refine_shared(list(person["images"]), fit, renderer, steps=steps,
                                          weights=w)
                fits.append((name, new, (time.perf_counter() - t) / F))
            for name, f, s in fits:
                n_mm, f_mm = _errors(model, f, person)
                rows[name]["neutral_mm"].append(n_mm)
                rows[name]["frames_mm"].append(f_mm)
                rows[name]["s_per_frame"].append(s)
            if progress:
                print(f"{F} frame(s), person {k + 1}/{people}: neutral "
                      + ", ".join(f"{n} {r['neutral_mm'][-1]:.2f}" for n, r in rows.items())
                      + f" mm; {rows['photometric']['s_per_frame'][-1]:.2f} s/frame",
                      file=sys.stderr)
        out[f"{F} frames"] = {n: {m: round(float(np.mean(v)), 3) for m, v in r.items()}
                              for n, r in rows.items()}
    return out


def format_table(result: dict) -> str:
    """A Markdown table of :func:`run_bench`'s result."""
    lines = ["| frames | row | neutral mm | frames mm | s per frame |", "|---|---|---|---|---|"]
    for F, rows in result.items():
        for name, r in rows.items():
            lines.append(f"| {F.split()[0]} | {name} | {r['neutral_mm']:.3f} | {r['frames_mm']:.3f} "
                         f"| {r['s_per_frame']:.2f} |")
    return "\n".join(lines)


@one_line_errors("python -m evaluation.bench_photometric")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.bench_photometric",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--people", type=int, default=6)
    p.add_argument("--frames", type=int, nargs="+", default=[1, 5])
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--image-size", type=int, default=256)
    p.add_argument("--landmark-noise", type=float, default=1.0, help="px")
    p.add_argument("--seed", type=int, default=2024)
    p.add_argument("--loss-weight", nargs="+", metavar="KEY=VALUE", default=[],
                   help="overrides of the refinement's loss weights")
    p.add_argument("--gar", action="store_true",
                   help="add the row of the same loop with the GAR as its renderer")
    p.add_argument("--report", help="output JSON")
    args = p.parse_args(argv)
    from morphable.refinement import parse_loss_weights

    if args.people < 1 or min(args.frames) < 1 or args.steps < 0:
        raise InputError("--people and --frames must be >= 1, --steps >= 0")
    result = run_bench(args.people, args.frames, steps=args.steps, image_size=args.image_size,
                       landmark_noise=args.landmark_noise, seed=args.seed,
                       weights=parse_loss_weights(args.loss_weight), gar=args.gar)
    result = {"command": "python -m evaluation.bench_photometric " + " ".join(argv or sys.argv[1:]),
              "results": result}
    print(format_table(result["results"]))
    if args.report:
        from pathlib import Path

        Path(args.report).write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
