"""Reconstruction ablations on held-out synthetic faces with known geometry:
``python -m evaluation.gar_ablation --report ablate.json [--faces 8] [--steps 60]``.

Variants (paper Table 3 style):

- ``landmark-only``: :func:`morphable.fitting.fit_landmarks` on the projected landmarks
  (plus Gaussian pixel noise, ``--landmark-noise``);
- ``landmarks-refit``: then :func:`morphable.refinement.refine` with the photometric terms
  off (landmarks and priors only, in the crop camera): what the photometric terms add is
  measured against this;
- ``classical``: refine with the Lambertian + SH renderer;
- ``gar``: refine with the GAR, ``z`` initialised by the inverter V;
- ``gar-no-initial``: the same without V (``z`` from a fixed seed; paper "w/o initial");
- ``gar-no-norm-cycle``: the GAR trained with lambda_n = 0 (``--generator-n0``, default the
  committed ``weights/gar_tiny_no_norm_cycle.pt``), with V (paper "w/o norm-cycle").
  ``--inverter none``: every GAR variant starts from the default latent (for generators
  without a V of their own, e.g. two runs compared at the same step).

Each face: random SFM identity, expression, pose, procedural albedo, light and background
(:class:`neural.faces.renders.SyntheticFaces`, another seed than training), rendered at
``--image-size`` px. Metrics per variant, averaged over the faces: ``vertex_mm`` (mean
distance between the recovered and true meshes in the model frame), ``normal_deg`` (mean
angle between their vertex normals), ``s_per_image``; ``curves``: the vertex error against
optimisation steps and seconds (landmark fit included) of each refining variant, drawn by
``--plot``. The JSON records which generator and inverter weights were used.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity

__all__ = ["held_out_faces", "geometry_errors", "run_ablation", "plot_curves", "main"]


def held_out_faces(n: int, image_size: int = 256, seed: int = 12345):
    """n dicts: ``image`` (S, S, 3) [0, 1], ``landmarks`` (68, 2) px, ``vertices`` (V, 3) mm."""
    from neural.faces.renders import SyntheticFaces

    faces = SyntheticFaces(resolution=image_size)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        p = faces.draw(rng)
        r = faces.render(p["identity"], p["albedo"], p["expression"], p["pose"], p["sh"],
                         p["background"])
        out.append({"image": r["image"], "landmarks": r["landmarks"],
                    "vertices": faces.model.vertices(p["identity"], p["expression"])})
    return faces.model, out


def geometry_errors(model, fit, true_vertices) -> tuple[float, float]:
    """(mean vertex distance mm, mean vertex-normal angle deg) of frame 0 against the truth,
    both meshes in the model frame."""
    from morphable.normals import vertex_normals

    v = fit.model.vertices(fit.frame_identity[0], fit.expression[0])
    a, b = vertex_normals(v, model.triangles), vertex_normals(true_vertices, model.triangles)
    ang = np.degrees(np.arccos(np.clip((a * b).sum(1), -1, 1)))
    return _vertex_error(v, true_vertices), float(ang.mean())


def _vertex_error(vertices, true_vertices) -> float:
    """Mean distance (mm) between corresponding vertices."""
    return float(np.linalg.norm(vertices - true_vertices, axis=1).mean())


def run_ablation(faces, model, *, steps=60, generator=None, generator_n0="auto", inverter="auto",
                 landmark_noise=1.0, seed=0, progress=True) -> dict:
    from morphable.fitting import fit_landmarks
    from morphable.refinement import NO_PHOTOMETRIC, refine
    from neural.gar.paths import default_inverter_path, default_no_norm_cycle_path
    from neural.gar.inverter import inverter_from
    from neural.gar.renderer import GARRenderer

    rng = np.random.default_rng(seed)
    inv = default_inverter_path() if inverter == "auto" else inverter
    V = inverter_from(inv)          # read once, shared by the GAR variants
    n0 = default_no_norm_cycle_path() if generator_n0 == "auto" else generator_n0
    # name -> None (the landmark fit itself) or (renderer, loss weight overrides)
    variants = {"landmark-only": None,
                "landmarks-refit": ("classical", NO_PHOTOMETRIC),
                "classical": ("classical", None)}
    notes = {}
    try:
        gar = GARRenderer(weights=generator, inverter=V)
        variants["gar"] = (gar, None)
        variants["gar-no-initial"] = (GARRenderer(weights=generator, inverter=None), None)
        notes["generator"] = gar.weights
    except InputError as e:       # no weights: the GAR variants are skipped and say why
        notes["generator"] = f"unavailable ({e})"
    if n0:
        variants["gar-no-norm-cycle"] = (GARRenderer(weights=n0, inverter=V), None)
        notes["generator_n0"] = str(n0)
    notes["inverter"] = str(inv) if inv else None
    results = {k: {"vertex_mm": [], "normal_deg": [], "s_per_image": []} for k in variants}
    every = max(1, steps // 10)
    curves = {k: {"vertex_mm": [], "seconds": []} for k, spec in variants.items() if spec}
    for i, face in enumerate(faces):
        lm = face["landmarks"] + rng.normal(0, landmark_noise, face["landmarks"].shape)
        S = face["image"].shape[0]
        t = time.perf_counter()
        fit = fit_landmarks(model, lm[None], np.array([[S, S]], dtype=np.float64), n_iterations=4)
        t_fit = time.perf_counter() - t
        for name, spec in variants.items():
            t = time.perf_counter()
            if spec is None:
                res, secs = fit, t_fit
            else:
                renderer, weights = spec
                res, rep = refine(face["image"], fit, renderer, steps=steps, trace_every=every,
                                  weights=weights)
                secs = t_fit + time.perf_counter() - t
                curves[name]["vertex_mm"].append(
                    [_vertex_error(model.vertices(np.asarray(p["alpha"]), np.asarray(p["beta"])),
                                   face["vertices"]) for p in rep["trace"]])
                curves[name]["seconds"].append([t_fit + p["seconds"] for p in rep["trace"]])
            d, a = geometry_errors(model, res, face["vertices"])
            for k, v in zip(("vertex_mm", "normal_deg", "s_per_image"), (d, a, secs)):
                results[name][k].append(v)
        if progress:
            print(f"face {i + 1}/{len(faces)}: " + ", ".join(
                f"{k} {v['vertex_mm'][-1]:.2f} mm" for k, v in results.items()), file=sys.stderr)
    table = {k: {m: round(float(np.mean(v)), 3) for m, v in r.items()} for k, r in results.items()}
    steps_traced = list(range(0, steps, every)) + [steps]
    curve = {k: {"step": steps_traced,
                 "seconds": np.round(np.mean(c["seconds"], axis=0), 3).tolist(),
                 "vertex_mm": np.round(np.mean(c["vertex_mm"], axis=0), 3).tolist()}
             for k, c in curves.items() if c["vertex_mm"]}
    return {"variants": table, "curves": curve, "faces": len(faces), "steps": steps,
            "landmark_noise_px": landmark_noise, **notes}


def plot_curves(report: dict, path) -> None:
    """Vertex error (mm) against seconds per image, one line per refining variant, the
    landmark-only fit as a point."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from morphable.io.atomic import atomic_path

    fig, ax = plt.subplots(figsize=(6, 4))
    lo = report["variants"].get("landmark-only")
    if lo:
        ax.plot([lo["s_per_image"]], [lo["vertex_mm"]], "ko", label="landmark-only")
    for name, c in report["curves"].items():
        ax.plot(c["seconds"], c["vertex_mm"], marker=".", label=name)
    ax.set_xlabel("seconds per image (landmark fit + refinement steps)")
    ax.set_ylabel("vertex error (mm)")
    ax.set_title(f"{report['faces']} held-out faces, {report['steps']} steps")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


@one_line_errors("evaluation.gar_ablation")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.gar_ablation",
                                description=__doc__.splitlines()[0])
    p.add_argument("--report", required=True, help="output JSON")
    p.add_argument("--faces", type=int, default=8)
    p.add_argument("--steps", type=int, default=60)
    p.add_argument("--image-size", type=int, default=256)
    p.add_argument("--generator", help="GAR generator.pt (default: the gar renderer's weights)")
    p.add_argument("--generator-n0", default="auto",
                   help="generator.pt of the lambda_n = 0 run (default: the committed one)")
    p.add_argument("--plot", help="PNG of vertex error against seconds per variant")
    p.add_argument("--inverter", default="auto",
                   help="inverter.pt (default: committed/runs); 'none': every GAR variant starts "
                        "from the default latent")
    p.add_argument("--landmark-noise", type=float, default=1.0, help="px")
    p.add_argument("--threads", type=int)
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    out = Path(args.report)
    if not out.resolve().parent.is_dir():
        raise InputError(f"{out}: folder {out.resolve().parent} does not exist")
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    model, faces = held_out_faces(args.faces, args.image_size)
    report = run_ablation(faces, model, steps=args.steps, generator=args.generator,
                          generator_n0=args.generator_n0,
                          inverter=None if args.inverter == "none" else args.inverter,
                          landmark_noise=args.landmark_noise)
    report["command"] = "python -m evaluation.gar_ablation " + " ".join(argv if argv is not None else sys.argv[1:])
    from morphable.io.atomic import atomic_path

    with atomic_path(out) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=2))
    if args.plot:
        plot_curves(report, args.plot)
    print(json.dumps(report["variants"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
