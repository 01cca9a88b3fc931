"""Fitting with a noise per point: error against run time on synthetic faces whose landmarks
carry a known, different noise each (what a detector that predicts its uncertainty gives).

Each face (SFM, random identity and expression, ``|yaw|`` <= 60 degrees, pitch and roll <= 20,
affine camera, 512 px, :func:`evaluation.bench_fitting.make_sample`) gives the face mesh's 478
points in the 3D convention (hidden points where they project,
:func:`morphable.labels.project_labels`). Each point draws its own noise sigma, log-uniform in
[0.5, 8] px, twice that where the point is hidden, and a 40 px error with a 40 px sigma for 5 %
of the points (a detector that knows when it is lost); its 2D position moves by sigma times a
normal draw. Fits (``convention="3d"``), per face and frame count:

- ``one sigma``: one number for every point, the RMS of the points' sigma (a detector
  without an uncertainty, at its right average noise);
- ``auto``: ``landmark_std_px="auto"`` (one noise estimated from the residuals);
- ``per point``: each point's own sigma (``landmark_std_px`` an (N, L) array).

With ``--frames 5`` each face is seen in 5 frames at independent poses, one shared identity.
Reported: mean vertex error after a similarity alignment (mm), median ms per fit (one BLAS
thread, as ``fit_landmarks`` runs).

    python -m evaluation.bench_sigma --n 40 --frames 1 5 --report reports/bench_sigma.json
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors

SIGMA_PX = (0.5, 8.0)
HIDDEN_FACTOR = 2.0
GROSS_FRACTION, GROSS_PX = 0.05, 40.0
METHODS = ("one sigma", "auto", "per point")


def noisy_points(model, sample, schemes, rng):
    """One frame of a face: the 478 labels of ``sample``
    (:func:`~evaluation.bench_fitting.make_sample`) with per-point noise -> points (478, 2) px,
    sigma (478,) px."""
    from morphable.labels import project_labels

    lab = project_labels(sample["verts"], model.triangles, sample["camera"], schemes)
    pts, seen = lab["points478"].astype(np.float64), lab["visible478"]
    L = len(pts)
    sigma = np.exp(rng.uniform(*np.log(SIGMA_PX), L)) * np.where(seen, 1.0, HIDDEN_FACTOR)
    gross = rng.uniform(size=L) < GROSS_FRACTION
    sigma[gross] = GROSS_PX
    step = rng.standard_normal((L, 2))
    step[gross] = GROSS_PX * step[gross] / np.linalg.norm(step[gross], axis=1, keepdims=True)
    return pts + np.where(gross[:, None], step, sigma[:, None] * step), sigma


def run(n: int, frames, seed: int = 0) -> dict:
    from morphable import load_model
    from morphable.fitting import fit_landmarks
    from morphable.labels import label_schemes

    from .bench_fitting import make_sample, similarity_error

    model = load_model("sfm")
    schemes = {"478": label_schemes(model)["478"]}
    rng = np.random.default_rng(seed)
    out = {}
    for k in frames:
        rows = {m: {"mm": [], "ms": []} for m in METHODS}
        for _ in range(n):
            views = [make_sample(model, rng, max_yaw=60.0, max_tilt=20.0)]
            for _ in range(k - 1):       # the same face at other poses
                more = make_sample(model, rng, max_yaw=60.0, max_tilt=20.0)
                more["verts"] = views[0]["verts"]
                views.append(more)
            pts, sig = zip(*(noisy_points(model, v, schemes, rng) for v in views))
            pts, sig = np.stack(pts), np.stack(sig)
            settings = {"one sigma": float(np.sqrt(np.mean(sig ** 2))), "auto": "auto",
                        "per point": sig}
            for m in METHODS:
                t = time.perf_counter()
                res = fit_landmarks(model, pts, (512, 512), convention="3d",
                                    landmark_std_px=settings[m])
                rows[m]["ms"].append((time.perf_counter() - t) * 1e3)
                rows[m]["mm"].append(similarity_error(res.neutral_vertices(),
                                                      model.vertices(views[0]["alpha"])))
        out[str(k)] = {m: {"mean_mm": round(float(np.mean(r["mm"])), 4),
                           "median_mm": round(float(np.median(r["mm"])), 4),
                           "ms": round(float(np.median(r["ms"])), 2)} for m, r in rows.items()}
    return out


@one_line_errors("evaluation.bench_sigma")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=40, help="faces per frame count")
    p.add_argument("--frames", type=int, nargs="+", default=[1, 5],
                   help="frames per face (one shared identity)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--report", type=Path, help="JSON to write")
    a = p.parse_args(argv)
    if a.n < 1 or min(a.frames) < 1:
        raise InputError(f"--n and --frames must be >= 1, got {a.n} and {a.frames}")
    if a.report and not a.report.resolve().parent.is_dir():
        raise InputError(f"{a.report}: output folder does not exist")
    table = run(a.n, a.frames, a.seed)
    print(f"{'frames':>6s} {'fit':>10s} {'mean mm':>8s} {'median mm':>10s} {'ms':>8s}")
    for k, rows in table.items():
        for m, r in rows.items():
            print(f"{k:>6s} {m:>10s} {r['mean_mm']:8.3f} {r['median_mm']:10.3f} {r['ms']:8.1f}")
    if a.report:
        from morphable.io.atomic import write_json

        write_json(a.report, {"n": a.n, "seed": a.seed, "table": table,
                              "command": "python -m evaluation.bench_sigma "
                              + " ".join(sys.argv[1:] if argv is None else argv)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
