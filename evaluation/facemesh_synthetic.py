"""Detectors on a fixed synthetic validation set: the face mesh (the baseline a landmark network
must beat) and the landmark network (``--methods facemesh network``).

Faces: ``--n`` (300) random SFM faces at ``--resolution`` (256) px drawn by
:class:`neural.synthetic.SyntheticEngine` with its pose (yaw +-90, pitch +-40, roll +-30
degrees), light, occluder and degradation ranges; face ``k`` is drawn from the seed
``[seed, k]`` (``--seed`` 1000: not a seed a training pack built with ``--seed 0`` uses for its
first faces). Textures: :data:`VALIDATION_TEXTURES` London photos (CC BY 4.0) taken from the end
of the sorted list, so that no texture's person is among the 16 first photos a training pack
dresses its faces in (``neural.build_synthetic --textures 16``); backgrounds: 300-W patches
(research use only), as a training pack's.

Detector: mediapipe's face mesh mapped to iBUG-68 as :mod:`evaluation.bench_alignment` runs it
(:func:`evaluation.bench_alignment.run_method` ``"facemesh"``), on the detected face that
overlaps the box of the face's 68 true points most (IoU >= 0.3; a background patch may show
another face); no such face is a failure, counted in its bin.

Score: 68-point NME against the labels' ``points68`` (the 3D convention: hidden points where
they project, as AFLW2000-3D's ``pts68_3d``), normalised by sqrt(w h) of the box of the 68
true points (AFLW2000-3D's protocol, so that the figures compare with the issue's AFLW2000-3D
ones); SFM has no point for two inner-mouth rows (``defined68``), so 66 points are scored.
``nme_visible_percent``: the same over each face's visible points only (same normaliser).
Tables by |yaw| bin [0, 30], (30, 60], (60, 90] and by light kind. Command::

    python -m evaluation.facemesh_synthetic --n 300 --resolution 256 --report reports/facemesh_synthetic.json
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors

__all__ = ["VALIDATION_TEXTURES", "VALIDATION_SEED", "validation_engine", "validation_faces",
           "score", "main"]

VALIDATION_TEXTURES = 16
"""London photos (the last ones of the sorted list) that dress the validation faces."""
VALIDATION_SEED = 1000
"""Face ``k`` of the validation set is drawn from ``numpy.random.default_rng([seed, k])``."""


def validation_engine(data, model: str = "sfm", resolution: int = 256, textures: int = VALIDATION_TEXTURES,
                      cache=None):
    """The :class:`neural.synthetic.SyntheticEngine` of the validation set: London textures
    from the end of the list, 300-W background patches (seed 0), the engine's default ranges."""
    from neural.synthetic import (SyntheticEngine, background_bank, london_photos, texture_bank,
                                  w300_photos)

    photos = london_photos(data)
    bg_photos = w300_photos(data)
    if not photos or not bg_photos:
        raise InputError(f"{data}: no London photos (faces/frl_london) or 300-W photos (images/300w)")
    tex = texture_bank(photos[-textures:], model, 256, cache=cache)[0] if textures else ()
    bgs = background_bank(bg_photos, side=resolution, per_photo=1, seed=0)
    return SyntheticEngine(model, resolution, textures=tex, backgrounds=bgs)


def validation_faces(engine, n: int, seed: int = VALIDATION_SEED) -> dict:
    """``n`` faces -> ``images`` (n, R, R, 3) uint8, ``points68`` (n, 68, 2) px,
    ``visible68``, ``defined68`` (n, 68) bool, ``yaw_deg`` (n,), ``light`` (n,) str."""
    faces = [engine.sample(np.random.default_rng([seed, k])) for k in range(n)]
    return {"images": np.stack([f["image"] for f in faces]),
            "points68": np.stack([f["points68"] for f in faces]).astype(np.float64),
            "visible68": np.stack([f["visible68"] for f in faces]),
            "defined68": np.stack([f["defined68"] for f in faces]),
            "yaw_deg": np.array([f["params"]["pose"][0] for f in faces]),
            "light": np.array([f["params"]["light"] for f in faces])}


def score(pred, faces) -> dict:
    """NME of ``pred`` (n, 68, 2) px (NaN rows: no face) against ``faces``
    (:func:`validation_faces`) -> ``nme`` (n,) percent over the defined points,
    ``nme_visible`` (n,) over the visible ones (NaN: a failure or no visible point), ``norm``
    (n,) px: sqrt(w h) of the box of the defined true points."""
    gt = faces["points68"]
    defined = faces["defined68"] & np.isfinite(gt).all(-1)
    lo = np.where(defined[..., None], gt, np.inf).min(1)
    hi = np.where(defined[..., None], gt, -np.inf).max(1)
    wh = hi - lo
    norm = np.sqrt(wh[:, 0] * wh[:, 1])
    d = np.linalg.norm(pred - np.where(defined[..., None], gt, 0.0), axis=-1)
    out = {"norm": norm}
    for key, sel in (("nme", defined), ("nme_visible", defined & faces["visible68"])):
        use = sel & np.isfinite(d)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(use, d, 0.0).sum(1) / use.sum(1)
        out[key] = np.where(use.sum(1) > 0, 100.0 * mean / norm, np.nan)
    return out


def _row(sel, s) -> dict:
    e, ev = s["nme"][sel], s["nme_visible"][sel]
    ok = np.isfinite(e)
    okv = np.isfinite(ev)
    return {"faces": int(sel.sum()), "failures": int((~ok).sum()),
            "no_face_at_all": int(s["no_face"][sel].sum()),
            "nme_percent": float(e[ok].mean()) if ok.any() else None,
            "nme_visible_percent": float(ev[okv].mean()) if okv.any() else None}


def tables(faces, s) -> dict:
    """Rows by |yaw| bin and by light kind, and over all faces."""
    from neural.synthetic import LIGHTS

    a = np.abs(faces["yaw_deg"])
    by_yaw = {f"{lo}-{hi}": _row((a <= hi) & ((a > lo) if lo > 0 else True), s)
              for lo, hi in ((0, 30), (30, 60), (60, 90))}
    by_light = {k: _row(faces["light"] == k, s) for k in LIGHTS}
    return {"by_yaw": by_yaw, "by_light": by_light, "all": _row(np.ones(len(a), bool), s)}


def format_tables(t) -> str:
    lines = ["| faces | n | failures | of which no face at all | NME % (66 points) | NME % (visible points) |",
             "| --- | --- | --- | --- | --- | --- |"]

    def f(x):
        return "-" if x is None else f"{x:.2f}"

    for group, name in (("by_yaw", "\\|yaw\\| {}°"), ("by_light", "light {}")):
        for k, r in t[group].items():
            lines.append(f"| {name.format(k)} | {r['faces']} | {r['failures']} | {r['no_face_at_all']} | "
                         f"{f(r['nme_percent'])} | {f(r['nme_visible_percent'])} |")
    r = t["all"]
    lines.append(f"| all | {r['faces']} | {r['failures']} | {r['no_face_at_all']} | {f(r['nme_percent'])} | "
                 f"{f(r['nme_visible_percent'])} |")
    return "\n".join(lines)


def _failures(pred, gt, faces) -> dict:
    """:func:`score` of a method's ``pred`` (n, 68, 2) px, a face found elsewhere (its points'
    box overlapping the true one by IoU < 0.3: a background photo's face) a failure too."""
    from morphable.detection.boxes import iou

    pred = pred.copy()
    no_face = ~np.isfinite(pred).any((1, 2))
    truth = np.concatenate([np.nanmin(gt, 1), np.nanmax(gt, 1)], 1)
    found = np.zeros((len(pred), 4))
    found[~no_face] = np.concatenate([np.nanmin(pred[~no_face], 1), np.nanmax(pred[~no_face], 1)], 1)
    wrong = np.array([not nf and float(iou(found[i:i + 1], truth[i])[0]) < 0.3
                      for i, nf in enumerate(no_face)])
    pred[wrong] = np.nan
    s = score(pred, faces)
    s["no_face"] = no_face
    return s


@one_line_errors("python -m evaluation.facemesh_synthetic")
def main(argv=None) -> int:
    from .bench_alignment import data_root, run_method

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=300, help="faces (default 300)")
    p.add_argument("--resolution", type=int, default=256, help="image side, px (default 256)")
    p.add_argument("--seed", type=int, default=VALIDATION_SEED)
    p.add_argument("--model", default="sfm")
    p.add_argument("--textures", type=int, default=VALIDATION_TEXTURES,
                   help="London textures from the end of the list (0: procedural albedo)")
    p.add_argument("--data", default=None, help="shared data folder (default ../shared/data)")
    p.add_argument("--texture-cache", help="npz keeping the extracted textures between runs")
    p.add_argument("--methods", nargs="+", default=["facemesh"],
                   help="detectors as evaluation.bench_alignment names them (facemesh, dlib, "
                        "network; default facemesh)")
    p.add_argument("--report", help="output JSON")
    args = p.parse_args(argv)
    if args.n < 1 or args.resolution < 32:
        raise InputError("--n must be >= 1 and --resolution >= 32")
    data = Path(args.data) if args.data else data_root()
    t0 = time.perf_counter()
    eng = validation_engine(data, args.model, args.resolution, args.textures, args.texture_cache)
    faces = validation_faces(eng, args.n, args.seed)
    t_draw = time.perf_counter() - t0
    gt = np.where(faces["defined68"][..., None], faces["points68"], np.nan)
    report = {"faces": args.n, "resolution": args.resolution, "seed": args.seed, "model": args.model,
              "textures": args.textures, "normaliser": "sqrt(w h) of the box of the defined true points",
              "seconds_drawing": round(t_draw, 1), "methods": {}}
    for method in args.methods:
        r = run_method(method, list(faces["images"]))
        t = tables(faces, _failures(r["pred"], gt, faces))
        report["methods"][method] = {
            "tables": t, "median_ms_detection":
            float(np.nanmedian(r["ms"])) if np.isfinite(r["ms"]).any() else None}
        print(f"{method}:\n{format_tables(t)}")
    report["seconds"] = round(time.perf_counter() - t0, 1)
    print(f"{args.n} faces drawn in {t_draw:.0f} s, {report['seconds']:.0f} s in all", file=sys.stderr)
    if args.report:
        from morphable.io.atomic import write_json

        write_json(args.report, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
