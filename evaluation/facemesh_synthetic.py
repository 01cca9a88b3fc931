"""Detectors on a fixed synthetic validation set: the face mesh (the baseline a landmark network
must beat) and the landmark network (``--methods facemesh network``).

Faces: ``--n`` (300) random SFM faces at ``--resolution`` (256) px drawn by
:class:`neural.faces.synthetic.SyntheticEngine` with its pose (yaw +-90, pitch +-40, roll +-30
degrees), light, occluder and degradation ranges; face ``k`` is drawn from the seed
``[seed, k]`` (``--seed`` 1000: not a seed a training pack built with ``--seed 0`` uses for its
first faces). Textures: :data:`VALIDATION_TEXTURES` London photos (CC BY 4.0) taken from the end
of the sorted list, so that no texture's person is among the 16 first photos a training pack
dresses its faces in (``neural.faces.build_synthetic --textures 16``); backgrounds: 300-W patches
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
Tables by ``|yaw|`` bin [0, 30], (30, 60], (60, 90] and by light kind.

Identity signal (:func:`identity_signal`): how far the detected points move with the face's
identity — the same face with the model's mean identity is projected too (``mean68``), and
the detected points' offsets from it are regressed on the true points' (1: the points carry
the identity in full; 0: they stay where the mean face's are, and a fit to them stays near
the mean face), over each detector's found faces and over the faces every detector found.
Command::

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
           "score", "identity_signal", "main"]

VALIDATION_TEXTURES = 16
"""London photos (the last ones of the sorted list) that dress the validation faces."""
VALIDATION_SEED = 1000
"""Face ``k`` of the validation set is drawn from ``numpy.random.default_rng([seed, k])``."""


def validation_engine(data, model: str = "sfm", resolution: int = 256, textures: int = VALIDATION_TEXTURES,
                      cache=None):
    """The :class:`neural.faces.synthetic.SyntheticEngine` of the validation set: London textures
    from the end of the list, 300-W background patches (seed 0), the engine's default ranges."""
    from neural.faces.synthetic import (SyntheticEngine, background_bank, london_photos,
        texture_bank, w300_photos)

    photos = london_photos(data)
    bg_photos = w300_photos(data)
    if not photos or not bg_photos:
        raise InputError(f"{data}: no London photos (faces/frl_london) or 300-W photos (images/300w)")
    tex = texture_bank(photos[-textures:], model, 256, cache=cache)[0] if textures else ()
    bgs = background_bank(bg_photos, side=resolution, per_photo=1, seed=0)
    return SyntheticEngine(model, resolution, textures=tex, backgrounds=bgs)


def validation_faces(engine, n: int, seed: int = VALIDATION_SEED) -> dict:
    """``n`` faces -> ``images`` (n, R, R, 3) uint8, ``points68`` (n, 68, 2) px,
    ``mean68`` (n, 68, 2) px: the points of the same face with the model's mean identity (same
    expression and camera), ``identity`` (n, K) its coefficients, ``focal_px`` (n,) its
    camera's focal length, ``visible68``, ``defined68`` (n, 68) bool, ``yaw_deg`` (n,),
    ``light`` (n,) str."""
    from morphable.labels import project_labels
    from neural.faces.synthetic import VIEW_OFFSET_MM

    m = engine.model
    faces = [engine.sample(np.random.default_rng([seed, k])) for k in range(n)]
    mean = [project_labels(m.vertices(np.zeros_like(f["params"]["identity"]), f["params"]["expression"]),
                           m.triangles, f["camera"], {"68": engine.schemes["68"]},
                           offset_mm=VIEW_OFFSET_MM)["points68"] for f in faces]
    return {"images": np.stack([f["image"] for f in faces]),
            "points68": np.stack([f["points68"] for f in faces]).astype(np.float64),
            "mean68": np.stack(mean).astype(np.float64),
            "identity": np.stack([f["params"]["identity"] for f in faces]).astype(np.float64),
            "focal_px": np.array([float(f["camera"].focal) for f in faces]),
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


def identity_signal(pred, faces) -> dict:
    """How much of each face's identity a detector's points carry: on the defined points of
    the faces it found, the true points' offsets from the mean identity's (``points68 -
    mean68``, the identity's own effect in the photo) against the detected points' offsets
    from the mean identity's, both in units of the face size (:func:`score`'s normaliser), the
    mean offset of each point over the faces taken away from both (a bias every face shares,
    e.g. a different definition of the point, is no identity).

    pred : (n, 68, 2) px, NaN rows for faces not found; faces : :func:`validation_faces`

    Returns
    -------
    dict: ``faces`` used; ``identity_rms_percent``: RMS of the identity's offsets, % of the face
    size; ``reproduced``: the least-squares slope of the detected offsets on the true ones (1:
    the points move with the identity in full, 0: they stay at the mean face's);
    ``correlation``; ``rest_rms_percent``: RMS of what the slope leaves (error, pose, noise)."""
    norm = score(pred, faces)["norm"]
    found = np.isfinite(pred).any((1, 2))
    truth = (faces["points68"] - faces["mean68"])[found] / norm[found, None, None]
    seen = (pred - faces["mean68"])[found] / norm[found, None, None]
    use = (np.broadcast_to(faces["defined68"][found, :, None], truth.shape) & np.isfinite(truth)
           & np.isfinite(seen))

    def centred(x):
        return x - np.where(use, x, 0.0).sum(0) / np.maximum(use.sum(0), 1)

    t, e = centred(truth)[use], centred(seen)[use]
    slope = float(t @ e / (t @ t))
    return {"faces": int(found.sum()), "identity_rms_percent": float(100 * np.sqrt(np.mean(t ** 2) * 2)),
            "reproduced": slope, "correlation": float(t @ e / np.sqrt((t @ t) * (e @ e))),
            "rest_rms_percent": float(100 * np.sqrt(np.mean((e - slope * t) ** 2) * 2))}


def identity_fit_error(model, pred, faces, resolution: int) -> dict:
    """What the points give a fit: each found face's 68 points (``pred`` (n, 68, 2) px, NaN
    rows: not found) fitted as ``morphable fit`` fits a detector's 68 (3D convention, the
    detector's model error, one estimated noise) with a pinhole camera of the face's focal
    length; the fitted identity's neutral mesh against the true one, mean per-vertex distance
    after the best similarity (mm) -> dict: ``faces``, ``fit_mm`` and ``mean_face_mm`` (the
    model's mean face against the same faces), their means over the found faces."""
    from morphable.fitting import fit_landmarks
    from morphable.fitting.options import detected_settings

    from .bench_fitting import similarity_error

    fit, mean = [], []
    for i in np.flatnonzero(np.isfinite(pred).any((1, 2))):
        res = fit_landmarks(model, pred[i], (resolution, resolution), camera="perspective",
                            focal_px=faces["focal_px"][i], convention="3d",
                            landmark_std_px="auto", **detected_settings([True], 68))
        truth = model.vertices(faces["identity"][i], None)
        fit.append(similarity_error(res.neutral_vertices(), truth))
        mean.append(similarity_error(model.mean.astype(np.float64), truth))
    return {"faces": len(fit), "fit_mm": float(np.mean(fit)) if fit else None,
            "mean_face_mm": float(np.mean(mean)) if mean else None}


def _row(sel, s) -> dict:
    e, ev = s["nme"][sel], s["nme_visible"][sel]
    ok = np.isfinite(e)
    okv = np.isfinite(ev)
    return {"faces": int(sel.sum()), "failures": int((~ok).sum()),
            "no_face_at_all": int(s["no_face"][sel].sum()),
            "nme_percent": float(e[ok].mean()) if ok.any() else None,
            "nme_visible_percent": float(ev[okv].mean()) if okv.any() else None}


def tables(faces, s) -> dict:
    """Rows by ``|yaw|`` bin and by light kind, and over all faces."""
    from neural.faces.synthetic import LIGHTS

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
    found = {}
    for method in args.methods:
        r = run_method(method, list(faces["images"]))
        s = _failures(r["pred"], gt, faces)
        t = tables(faces, s)
        # a face found elsewhere (a background's) is no reading of this face's identity
        found[method] = np.where(np.isfinite(s["nme"])[:, None, None], r["pred"], np.nan)
        ident = identity_signal(found[method], faces)
        report["methods"][method] = {
            "tables": t, "identity_signal": ident, "median_ms_detection":
            float(np.nanmedian(r["ms"])) if np.isfinite(r["ms"]).any() else None}
        print(f"{method}:\n{format_tables(t)}\nidentity signal (faces found: {ident['faces']}): "
              f"the identity moves the points by {ident['identity_rms_percent']:.2f} % RMS of the "
              f"face size; the detected points move {ident['reproduced']:.2f} of it "
              f"(correlation {ident['correlation']:.2f}), the rest {ident['rest_rms_percent']:.2f} % RMS")
    # the faces every detector found (the easier ones), where they compare like for like; the
    # true points as a detector without error
    every = np.logical_and.reduce([np.isfinite(p).all((1, 2)) for p in found.values()])
    found["true points"] = np.where(faces["defined68"][..., None], faces["points68"], np.nan)
    common = report["identity_common_faces"] = {"faces": int(every.sum())}
    for m, p in found.items():
        p = np.where(every[:, None, None], p, np.nan)
        common[m] = {**identity_signal(p, faces),
                     **identity_fit_error(eng.model, p, faces, args.resolution)}
    print(f"\nthe {common['faces']} faces every detector found:\n\n| points | identity reproduced "
          "| correlation | fitted identity, mm | mean face, mm |\n| --- | ---: | ---: | ---: | ---: |")
    for m, r in common.items():
        if m != "faces":
            print(f"| {m} | {r['reproduced']:.2f} | {r['correlation']:.2f} | {r['fit_mm']:.3f} | "
                  f"{r['mean_face_mm']:.3f} |")
    report["seconds"] = round(time.perf_counter() - t0, 1)
    print(f"{args.n} faces drawn in {t_draw:.0f} s, {report['seconds']:.0f} s in all", file=sys.stderr)
    if args.report:
        from morphable.io.atomic import write_json

        write_json(args.report, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
