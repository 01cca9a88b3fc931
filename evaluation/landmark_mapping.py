"""Checks behind the landmark packs' mappings and failure bound (docs/landmark_packs.md).

``rows``: SFM fitted to the 10 unambiguous AFLW points (brow and eye corners, mouth corners) of
crops with ``|yaw|`` < 25 deg that have all 10; each other AFLW point compared with all 546
projected rows (mean distance over the outer brow corners' distance): the nearest rows, and
for the nose's sides and the mouth's centre the iBUG row of that name last.

``residuals``: ``--n`` random photos per set fitted as the packs fit them
(:func:`neural.faces.annotations.fit_item`): the RMS residual over the face box's side (percentiles)
and, where the set gives a yaw, its correlation with the fit's.

    python -m evaluation.landmark_mapping rows --n 300
    python -m evaluation.landmark_mapping residuals --n 150
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from morphable.errors import FitError, one_line_errors

__all__ = ["nearest_rows", "residuals", "main"]

_BASE = (0, 2, 3, 5, 6, 8, 9, 11, 17, 19)      # AFLW: brow and eye corners, mouth corners
_ASKED = (1, 4, 7, 10, 13, 14, 15, 18, 20)
_ALSO = {13: 478 + 31, 15: 478 + 35, 18: 478 + 66}   # the iBUG rows of the same name


def nearest_rows(data, n: int = 300, top: int = 4) -> dict:
    """AFLW point -> its ``top`` nearest rows ``[row, mean normalised distance]`` over the
    first ``n`` frontal crops with all base points (see the module's notes)."""
    import morphable
    from neural.faces.annotations import AFLW21_ROWS, model_points, row_scheme, set_items
    from morphable.fitting import fit_landmarks

    model = morphable.load_model("sfm")
    items = set_items(data, "aflw")
    keep = np.flatnonzero(AFLW21_ROWS >= 0)
    # the items hold the 19 mapped points; put them back at their AFLW index
    full = np.full((len(items), 21, 2), np.nan)
    for i, it in enumerate(items):
        full[i, keep] = it["points"]
    scheme = row_scheme(model, AFLW21_ROWS[list(_BASE)], "aflw-base")
    frontal = [i for i, it in enumerate(items[:n]) if abs(it["yaw_deg"]) < 25
               and np.isfinite(full[i, list(_BASE)]).all()]
    D = []
    for i in frontal:
        y = full[i, list(_BASE)]
        fit = fit_landmarks(model, y, (120, 120), scheme=scheme)
        P = fit.cameras[0].project(model_points(model, fit.vertices(0, np.float64)))
        D.append(np.linalg.norm(P[None] - full[i][:, None], axis=-1) / np.linalg.norm(y[3] - y[0]))
    D = np.array(D)                                              # (crops, 21, 546)
    out = {"crops": len(D)}
    with np.errstate(invalid="ignore"):
        for a in _ASKED:
            ok = np.isfinite(D[:, a, 0])
            d = D[ok, a].mean(0)
            order = np.argsort(d)[:top]
            out[str(a)] = [[int(r), round(float(d[r]), 3)] for r in order]
            if a in _ALSO:
                out[str(a)].append([_ALSO[a], round(float(d[_ALSO[a]]), 3)])
    return out


def residuals(data, n: int = 150, seed: int = 0) -> dict:
    """Per set: percentiles 50/90/95/99 of the fit's RMS residual over its face box's side (%),
    the share above the bound, the yaw correlation where the set has a yaw."""
    import morphable
    from morphable.detection.images import read_image
    from neural.faces.annotations import MAX_RESIDUAL, SETS, fit_item, set_items
    from neural.faces.points import IBUG_ROWS, face_box

    model = morphable.load_model("sfm")
    out = {}
    for s in SETS:
        items = set_items(data, s)
        pick = np.random.default_rng(seed).choice(len(items), min(n, len(items)), replace=False)
        rel, yaws = [], []
        for k in pick:
            img = read_image(items[k]["path"])
            try:
                fit, P, res = fit_item(model, items[k], (img.shape[1], img.shape[0]))
            except FitError:
                rel.append(np.inf)
                continue
            b = face_box(P[IBUG_ROWS])
            rel.append(res / (b[2] - b[0]))
            yaws.append((items[k]["yaw_deg"], fit.euler_deg[0, 0]))
        rel, yaws = np.array(rel), np.array(yaws)
        row = {"photos": len(pick),
               "percentiles_50_90_95_99": [round(100 * float(q), 2)
                                           for q in np.percentile(rel, [50, 90, 95, 99])],
               "above_bound": round(float(np.mean(rel > MAX_RESIDUAL)), 3)}
        if len(yaws) and np.isfinite(yaws[:, 0]).all():
            row["yaw_correlation"] = round(float(np.corrcoef(yaws.T)[0, 1]), 3)
        out[s] = row
    return out


@one_line_errors("python -m evaluation.landmark_mapping")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("rows", "residuals"))
    p.add_argument("--data", default="../shared/data")
    p.add_argument("--n", type=int, default=None)
    a = p.parse_args(argv)
    if a.what == "rows":
        print(json.dumps(nearest_rows(a.data, a.n or 300)))
    else:
        print(json.dumps(residuals(a.data, a.n or 150)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
