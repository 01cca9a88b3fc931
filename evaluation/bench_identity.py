"""Identity consistency on real photos: does a smile leak into the fitted identity?

The London set (``../shared/data/faces/frl_london``, 102 people, a neutral and a smiling front
photo each, CC BY 4.0): every photo is fitted on its own (SFM), and its identity is taken
without expression (ours: ``FitResult.neutral_vertices``; eos: its shape coefficients' mesh).
Per person, the *within* distance is the mean per-vertex distance (mm) between the neutral
photo's and the smiling photo's identity meshes after the best similarity transform (scale
included). As a scale for it, the *between* distance is the same between different people's
neutral-photo meshes (median over all pairs): an identity that ignores the photo (the mean
face) has within 0 and between 0 and identifies nobody. *Identification*: the rate at which the
nearest identity (by that distance) among all 203 other photos is the same person's other photo
(chance: 1 / 203). Times are wall ms per photo (detection and fit). ``ours-facemesh+gar`` and the like
refine each fit by inverting a renderer first (``--steps``; ``--gar-weights``), to see whether
the photometric refinement keeps the identity consistent. The facemesh478 sidecars
were calibrated on renders wearing the colours of the first 20 people
(:mod:`evaluation.scheme_calibration`): each figure is given over all 102 people and over the
other 82.

No peer reports this; it tests that expression does not leak into identity on real photos.

    python -m evaluation.bench_identity --report reports/bench_identity.json
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from morphable.errors import FitError, InputError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity

from .bench_alignment import add_refine_arguments, data_root, refine_options, refined_methods, refiner
from .bench_fitting import similarity_error
from .bench_report import write_report

__all__ = ["METHODS", "NETWORK_METHODS", "REFINED", "london_pairs", "identity_meshes", "consistency", "main"]

METHODS = ("ours-facemesh", "ours-dlib", "eos-dlib", "eos-facemesh")
NETWORK_METHODS = ("ours-network", "eos-network", "ours-fused")
"""With the landmark network's points (the neural plugin's detector), alone or fused with the face
mesh's (``landmark_detector="fused"``, the default where both can run); chosen by name, not run
by default."""
REFINED = refined_methods(METHODS + NETWORK_METHODS)
"""The refined fits (``+photometric`` or ``+classical``: ``morphable fit --refine photometric``;
``+gar``), also of the network's points."""
CALIBRATION_PEOPLE = 20
"""The first people of the set, whose colours the scheme calibration's renders wore."""


def london_pairs(root: Path, n: int | None = None) -> list:
    """[(person id, neutral photo, smiling photo)] of the London set under ``root/faces``."""
    folder = Path(root) / "faces" / "frl_london"
    pairs = []
    for p in sorted((folder / "neutral_front").glob("*_03.jpg")):
        pid = p.name.split("_")[0]
        s = folder / "smiling_front" / f"{pid}_08.jpg"
        if s.is_file():
            pairs.append((pid, p, s))
    if not pairs:
        raise InputError(f"{folder}: no neutral/smiling photo pairs found")
    return pairs[:n] if n else pairs


def identity_meshes(method: str, paths, model, steps: int = 100,
                    renderer_options: dict | None = None,
                    loss_weights: dict | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """(P, V, 3) mm identity meshes of the photos (NaN where the method failed), (P,) wall ms,
    and {photo: one-line reason} of the failures. A method ``ours-<detector>+<renderer>``
    refines each fit (:func:`evaluation.bench_alignment.refiner`) before taking its identity."""
    from morphable.detection import detect, detect_ibug68
    from morphable.detection.images import read_image
    from morphable.fitting import fit_landmarks
    from morphable.fitting.options import detection_settings

    method, _, renderer = method.partition("+")
    fitter, detector = method.split("-")
    refined = refiner(renderer, steps, renderer_options, loss_weights)
    eos = None
    if fitter == "eos":
        from .peers import EosFitter

        eos = EosFitter()
    out = np.full((len(paths), model.n_vertices, 3), np.nan)
    ms = np.full(len(paths), np.nan)
    errors = {}
    for i, p in enumerate(paths):
        img = read_image(p)
        size = (img.shape[1], img.shape[0])
        t = time.perf_counter()
        try:
            if eos is not None:
                out[i] = eos.fit_with_identity(detect_ibug68(img, landmark_detector=detector), size)[2]
            else:
                found = detect(img, landmark_detector=detector)
                res = fit_landmarks(model, found.points, size,
                                    **detection_settings([found], len(found.points)))
                out[i] = refined(img, res).neutral_vertices()
        except (FitError, InputError) as e:
            errors[str(p)] = str(e)
            continue
        ms[i] = (time.perf_counter() - t) * 1e3
    return out, ms, errors


def consistency(neutral, smiling) -> dict:
    """Within / between distances (mm) and the identification rate of identity meshes of the
    neutral and the smiling photos, (P, V, 3) each (NaN meshes: failures, left out of every
    comparison they would be part of)."""
    P = len(neutral)
    meshes = np.concatenate([neutral, smiling])
    ok = np.isfinite(meshes).all((1, 2))
    D = np.full((2 * P, 2 * P), np.inf)
    for i in range(2 * P):
        for j in range(i + 1, 2 * P):
            if ok[i] and ok[j]:
                D[i, j] = D[j, i] = similarity_error(meshes[i], meshes[j])
    within = np.array([D[i, i + P] for i in range(P) if ok[i] and ok[i + P]])
    between = np.array([D[i, j] for i in range(P) for j in range(i + 1, P) if ok[i] and ok[j]])
    hits = [int(np.argmin(D[i]) == (i + P) % (2 * P)) for i in range(2 * P)
            if ok[i] and ok[(i + P) % (2 * P)]]
    return {"people": P, "pairs_fitted": int(len(within)),
            "within_mm": float(within.mean()) if len(within) else None,
            "within_median_mm": float(np.median(within)) if len(within) else None,
            "between_median_mm": float(np.median(between)) if len(between) else None,
            "identification_rate": float(np.mean(hits)) if hits else None}


@one_line_errors("evaluation.bench_identity")
def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--methods", nargs="+", choices=METHODS + NETWORK_METHODS + REFINED,
                   default=list(METHODS))
    add_refine_arguments(p)
    p.add_argument("--n", type=int, default=None, help="people (default all 102)")
    p.add_argument("--data", type=Path, default=None,
                   help="shared data folder (default: $MORPHABLE_DATA or ../shared/data)")
    p.add_argument("--report", type=Path, default=Path("reports/bench_identity.json"))
    add_verbosity_arguments(p)
    a = p.parse_args(argv)
    configure(verbosity(a))
    from morphable import load_model

    refine = refine_options(a)
    model = load_model("sfm")
    pairs = london_pairs(a.data or data_root(), a.n)
    report = {"people": len(pairs), "model": "sfm", "methods": {}, "steps": a.steps, "gar_weights": a.gar_weights,
              "loss_weights": refine["loss_weights"]}
    lines = ["| method | within (mm) | between (mm) | identification | identification, people 21-102 "
             "| failures | ms |", "|---|---|---|---|---|---|---|"]
    for m in a.methods:
        neu, ms_n, err_n = identity_meshes(m, [q for _, q, _ in pairs], model, **refine)
        smi, ms_s, err_s = identity_meshes(m, [q for _, _, q in pairs], model, **refine)
        row = consistency(neu, smi)
        row["not_in_calibration"] = consistency(neu[CALIBRATION_PEOPLE:], smi[CALIBRATION_PEOPLE:])
        row["failures"] = len(err_n) + len(err_s)
        ms = np.concatenate([ms_n, ms_s])
        row["median_ms"] = float(np.nanmedian(ms)) if np.isfinite(ms).any() else None
        report["methods"][m] = row
        f = lambda x, fmt="{:.2f}": fmt.format(x) if x is not None else "-"     # noqa: E731
        lines.append(f"| {m} | {f(row['within_mm'])} | {f(row['between_median_mm'])} | "
                     f"{f(row['identification_rate'], '{:.1%}')} | "
                     f"{f(row['not_in_calibration']['identification_rate'], '{:.1%}')} | {row['failures']} | "
                     f"{f(row['median_ms'], '{:.0f}')} |")
    write_report(a.report, report, "\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
