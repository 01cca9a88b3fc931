"""Face profiling checks: a picture of profiled photos over yaw, and the profiled labels
against a second fit run on the profiled picture.

``grid``: image_0010 (its 68 ground-truth points) and London neutral front photos (CC BY 4.0,
landmarks detected by the face mesh), each fitted (SFM) and turned by each ``--yaws`` step;
visible 68-point labels green, hidden ones red.

``refit``: the first ``--n`` London photos, each fitted with face-mesh landmarks and turned by
each of ``--yaws``; the profiled picture is fitted again from the face mesh's points detected
in it (SFM, ``DETECTED_MODEL_STD_MM``) and that fit's projected iBUG-68 points
(``FitResult.landmarks_68_px("3d")``: the labels' convention, hidden points where they
project) are compared with the profiling labels over the 66 points SFM defines: mean px error
and NME by sqrt(w h) of the labels' box; a profiled picture where the face mesh finds no face
is a failure.

``pack``: ``--n`` random faces of a profiled landmark pack (:mod:`neural.faces.build_profiled`),
the same second fit on each crop against its labels' 68 iBUG rows, by ``|yaw|`` bin of the
labels' pose. Commands::

    python -m evaluation.profiling_check grid --out docs/img/profiling_yaw.png
    python -m evaluation.profiling_check refit --n 5 --report reports/profiling_refit.json
    python -m evaluation.profiling_check pack --pack landmark_data/profiled --n 120
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from morphable.errors import FitError, InputError, one_line_errors

__all__ = ["profiled", "grid", "refit", "second_fit_error", "pack_refit", "main"]


def profiled(path, landmarks=None, yaws=(0.0,), texture_size=256):
    """Fit ``path`` (SFM; ``landmarks`` file or the face mesh) and turn it by each of ``yaws``
    -> (fit, list of :func:`morphable.profiling.profile_photo` results)."""
    from morphable.detection import read_image
    from morphable.pipeline import fit_images
    from morphable.profiling import profile_photo
    from morphable.texture import extract_texture

    fit = fit_images(path, landmarks, landmark_detector="facemesh").fit
    photo = read_image(path)
    tex = extract_texture(fit, [photo], size=texture_size)
    return fit, [profile_photo(photo, fit, y, texture=tex) for y in yaws]


def _dots(img, xy, visible):
    img = img.copy()
    H, W = img.shape[:2]
    for (x, y), v in zip(xy, visible):
        if np.isfinite([x, y]).all():
            i, j = int(round(y)), int(round(x))
            img[max(i - 1, 0):min(i + 2, H), max(j - 1, 0):min(j + 2, W)] = (0, 255, 0) if v else (255, 0, 0)
    return img


def grid(photos, yaws, cell=192):
    """(rows * cell, len(yaws) * cell, 3) uint8: each photo (path, landmarks or None) turned
    by each yaw, cut to a square around the face and resized to ``cell``."""
    from PIL import Image

    rows = []
    for path, lm in photos:
        _, outs = profiled(path, lm, yaws)
        box = np.concatenate([outs[len(yaws) // 2]["landmarks_px"]["68"]])
        c = np.nanmean(box, 0)
        half = 1.1 * np.nanmax(np.nanmax(box, 0) - np.nanmin(box, 0))
        row = []
        for o in outs:
            img = _dots(o["image"], o["landmarks_px"]["68"], o["visible"]["68"])
            x0, y0 = int(c[0] - half), int(c[1] - half)
            crop = Image.fromarray(img).crop((x0, y0, x0 + int(2 * half), y0 + int(2 * half)))
            row.append(np.asarray(crop.resize((cell, cell), Image.Resampling.BILINEAR)))
        rows.append(np.concatenate(row, 1))
    return np.concatenate(rows, 0)


def second_fit_error(model, image, labels68):
    """The face mesh run on ``image`` (H, W, 3) uint8, ``model`` fitted to its points and the
    fit's 68 points (``landmarks_68_px("3d")``) compared with ``labels68`` (68, 2) px over the
    rows both define -> (mean px error, NME % by sqrt(w h) of the labels' box), None when the
    face mesh finds no face."""
    from morphable.detection import detect_landmarks
    from morphable.fitting import fit_landmarks
    from morphable.fitting.noise import DETECTED_MODEL_STD_MM

    try:
        pts = detect_landmarks(image, landmark_detector="facemesh")
    except FitError:
        return None
    res = fit_landmarks(model, pts, (image.shape[1], image.shape[0]), model_std_mm=DETECTED_MODEL_STD_MM)
    pred = res.landmarks_68_px("3d")[0]
    gt = np.asarray(labels68, dtype=np.float64)
    ok = np.isfinite(pred).all(1) & np.isfinite(gt).all(1)
    d = np.linalg.norm(pred[ok] - gt[ok], axis=1).mean()
    wh = gt[ok].max(0) - gt[ok].min(0)
    return float(d), float(100 * d / np.sqrt(wh[0] * wh[1]))


def pack_refit(pack, n: int = 60, seed: int = 0, bins=(0, 30, 60, 90)) -> dict:
    """The check of a profiled landmark pack: ``n`` random faces of ``pack`` (its crops), each
    through :func:`second_fit_error` against its labels' 68 iBUG rows; per ``|yaw|`` bin of the
    labels' pose (the last bin open-ended): faces, no face found, mean px error (crop px) and
    NME %."""
    import morphable
    from neural.faces.packs import load_pack
    from neural.faces.points import IBUG_ROWS

    d = load_pack(pack)
    pick = np.sort(np.random.default_rng(seed).choice(len(d["split"]), min(n, len(d["split"])),
                                                      replace=False))
    model = morphable.load_model("sfm")
    yaw, errs = np.abs(d["yaw_deg"][pick]), []
    for i in pick:
        errs.append(second_fit_error(model, d["image"][i], d["points"][i][IBUG_ROWS]))
    rows = []
    for lo, hi in zip(bins[:-1], bins[1:]):
        # the last bin takes the turns past its end too (the fit's pose plus a clipped turn)
        k = [j for j in range(len(pick)) if lo <= yaw[j] and (yaw[j] < hi or hi == bins[-1])]
        got = [errs[j] for j in k if errs[j] is not None]
        rows.append({"abs_yaw_deg": f"{lo}-{hi}", "faces": len(k), "no_face": len(k) - len(got),
                     "px_mean": float(np.mean([g[0] for g in got])) if got else None,
                     "nme_percent": float(np.mean([g[1] for g in got])) if got else None})
    return {"pack": str(pack), "faces": len(pick), "rows": rows}


def refit(photos, yaws) -> dict:
    """Per yaw: profiled pictures, failures (no face found in them), mean px error and NME %
    of the second fit's 68 points against the profiling labels."""
    err = {y: [] for y in yaws}
    nme = {y: [] for y in yaws}
    fail = {y: 0 for y in yaws}
    fit_failed = []
    for p in photos:
        try:
            fit, outs = profiled(p, None, yaws)
        except FitError as e:
            fit_failed.append(f"{Path(p).name}: {e}")
            continue
        for y, o in zip(yaws, outs):
            e = second_fit_error(fit.model, o["image"], o["landmarks_px"]["68"])
            if e is None:
                fail[y] += 1
                continue
            err[y].append(e[0])
            nme[y].append(e[1])
    rows = [{"delta_yaw_deg": y, "pictures": len(photos) - len(fit_failed), "failures": fail[y],
             "px_mean": float(np.mean(err[y])) if err[y] else None,
             "nme_percent": float(np.mean(nme[y])) if nme[y] else None} for y in yaws]
    return {"rows": rows, "photos_not_fitted": fit_failed}


@one_line_errors("python -m evaluation.profiling_check")
def main(argv=None) -> int:
    from .bench_alignment import data_root

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("what", choices=("grid", "refit", "pack"))
    p.add_argument("--pack", help="pack: a profiled landmark pack (neural.faces.build_profiled)")
    p.add_argument("--data", default=None, help="shared data folder (default ../shared/data)")
    p.add_argument("--n", type=int, default=5, help="London photos (refit; grid: 2 with image_0010)")
    p.add_argument("--yaws", type=float, nargs="+", help="turns, degrees (grid default -90 ... 90 "
                   "by 30; refit default 0 15 30 45 60 75 90)")
    p.add_argument("--out", help="grid: output .png")
    p.add_argument("--report", help="refit: output .json")
    a = p.parse_args(argv)
    if a.what == "pack":
        if not a.pack:
            raise InputError("pack: --pack FOLDER is required")
        t0 = time.perf_counter()
        report = pack_refit(a.pack, a.n)
        report["seconds"] = round(time.perf_counter() - t0, 1)
        f = (lambda x: "-" if x is None else f"{x:.2f}")
        print("| \\|yaw\\| ° | faces | no face found | px error | NME % |\n| --- | --- | --- | --- | --- |")
        for r in report["rows"]:
            print(f"| {r['abs_yaw_deg']} | {r['faces']} | {r['no_face']} | {f(r['px_mean'])} | "
                  f"{f(r['nme_percent'])} |")
        if a.report:
            from morphable.io.atomic import write_json

            write_json(a.report, report)
        return 0
    data = Path(a.data) if a.data else data_root()
    london = sorted((data / "faces" / "frl_london" / "neutral_front").glob("*.jpg"))
    if not london:
        raise InputError(f"{data}: no London photos (faces/frl_london/neutral_front)")
    from morphable.io.atomic import atomic_path

    t0 = time.perf_counter()
    if a.what == "grid":
        if not a.out:
            raise InputError("grid: --out PNG is required")
        from PIL import Image

        yaws = a.yaws or [-90.0, -60.0, -30.0, 0.0, 30.0, 60.0, 90.0]
        img = data / "images" / "image_0010"
        photos = [(img.with_suffix(".png"), img.with_suffix(".pts"))] + [(q, None) for q in london[:2]]
        pic = grid(photos, yaws)
        with atomic_path(a.out) as tmp:
            Image.fromarray(pic).save(tmp, format="PNG")
        print(f"{a.out}: {len(photos)} photos x {len(yaws)} turns in {time.perf_counter() - t0:.0f} s")
        return 0
    yaws = a.yaws or [0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0]
    report = refit(london[:a.n], yaws)
    report["seconds"] = round(time.perf_counter() - t0, 1)
    print("| Δyaw ° | pictures | no face found | px error | NME % |\n| --- | --- | --- | --- | --- |")
    for r in report["rows"]:
        f = (lambda x: "-" if x is None else f"{x:.2f}")
        print(f"| {r['delta_yaw_deg']:g} | {r['pictures']} | {r['failures']} | {f(r['px_mean'])} | "
              f"{f(r['nme_percent'])} |")
    if a.report:
        from morphable.io.atomic import write_json

        write_json(a.report, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
