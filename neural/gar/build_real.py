"""Build the real-photo GAR training pack from ``../shared/data``.

``python -m neural.gar.build_real --data ../shared/data --out gar_data/real64.npz [--resolution 64]
[--model sfm] [--sources aflw,300w,london] [--limit N] [--detector auto|facemesh|dlib]``
(``make gar-data``).

Sources (licences: docs/neural.md, "Real training data"):

- ``aflw`` — ``faces/aflw_crops/crops``: 11,000 AFLW face crops, 120 x 120; landmarks
  detected. **Research use only.** Person unknown: one person per photo.
- ``300w`` — ``images/300w``: 667 300-W photos (AFW, HELEN test) with their ground-truth
  68-point ``.pts``. **Research use only.** One person per photo.
- ``london`` — ``faces/frl_london``: the Face Research Lab London Set, 102 people x a neutral
  and a smiling front photo (CC BY 4.0); person = the 3-digit file id; landmarks detected.

AFLW2000-3D is *not* a source: it is an evaluation set only, never trained on.

Per photo (steps, each a function here):

1. landmarks: the ground truth where given, else detected (:mod:`morphable.detection`; the
   face mesh gives 478 points, dlib 68);
2. :func:`fit_photo`: one fit with our fitter (:func:`morphable.fitting.fit_landmarks`; the
   478-point scheme for the face mesh's points, iBUG-68 for 68 points), cached per source in
   ``fits_<source>.npz`` beside the pack (identity, expression, camera, detector, residual),
   so that a rebuild at another resolution refits nothing;
3. :func:`bake_photo`: the FFHQ-style alignment of :func:`neural.gar.data.alignment` from the 68
   landmarks (the face mesh's through ``FACEMESH_TO_IBUG68``) — the framing of the synthetic
   faces and of :mod:`morphable.refinement` — the photo warped to R x R, and the fit's
   camera-frame normal map and coverage mask rendered by the fit camera composed with that
   similarity (:func:`neural.gar.data.aligned_camera`), the landmarks moved into the crop;
4. pass rule: a face found and the fit's landmark RMS residual, in pixels of a 64-px crop,
   at most ``--max-residual`` (:data:`MAX_RESIDUAL_PX64`);
5. held out: the person key's crc32 % 20 == 0 (about 5 %, by person; fixed);
6. :func:`neural.gar.real_faces.save_pack`, and a JSON report beside the pack (counts per source,
   the bound, timings, the pack's size, the normal quantisation and JPEG errors).

Horizontal flips are not stored: :class:`neural.gar.real_faces.RealFaces` mirrors at load time.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
import zlib
from pathlib import Path

import numpy as np

from morphable.errors import FitError, InputError, MorphableError

__all__ = ["SOURCES", "MAX_RESIDUAL_PX64", "list_photos", "fit_photo", "fit_source",
           "bake_photo", "held_out", "build", "contact_sheet", "main"]

log = logging.getLogger("neural.gar.build_real")

SOURCES = ("aflw", "300w", "london")
MAX_RESIDUAL_PX64 = 1.5
"""Pass bound on a fit's landmark RMS residual in pixels of a 64-px aligned crop (the
photo's pixels times the alignment's scale, times 64 / R): about 1/10 of the inter-ocular
distance (16 px at 64). Chosen from the residual distribution of the full build (docs/neural.md)."""

DARK_LEVEL = 13
"""A crop pixel darker than this in every channel (0.05 of 255) counts towards a source's
``dark_share`` in the report: black padding where a crop leaves its photo would show there
(:func:`morphable.refinement.pad_like_ffhq` fills it), as do dark hair and shadows."""

_CACHE_FORMAT = 1


# --- photos --------------------------------------------------------------------------------
def list_photos(data, source: str, limit=None) -> list:
    """The photos of ``source`` under the data folder, sorted -> list of dicts ``name``
    (relative to ``data``), ``path``, ``pts`` (ground-truth file or None), ``person_key``
    (str) and ``person`` (int, unique across sources)."""
    data = Path(data)
    if source == "aflw":
        paths = sorted((data / "faces" / "aflw_crops" / "crops").glob("*.jpg"))
        items = [(p, None, f"aflw/{p.name}") for p in paths]
    elif source == "300w":
        paths = sorted((data / "images" / "300w").rglob("*.jpg"))
        items = [(p, p.with_suffix(".pts"), f"300w/{p.relative_to(data / 'images' / '300w')}")
                 for p in paths if p.with_suffix(".pts").is_file()]
    elif source == "london":
        root = data / "faces" / "frl_london"
        paths = sorted([*(root / "neutral_front").glob("*.jpg"), *(root / "smiling_front").glob("*.jpg")])
        items = [(p, None, f"london/{p.name[:3]}") for p in paths if p.name[:3].isdigit()]
    else:
        raise InputError(f"--sources: unknown source {source!r} (choose from {', '.join(SOURCES)})")
    if limit is not None:
        items = items[:int(limit)]
    base = {"london": 0, "300w": 1_000_000, "aflw": 2_000_000}[source]
    out = []
    for i, (p, pts, key) in enumerate(items):
        person = base + int(key.split("/")[1]) if source == "london" else base + i
        out.append({"name": str(p.relative_to(data)), "path": str(p),
                    "pts": None if pts is None else str(pts), "person_key": key, "person": person})
    return out


def held_out(person_key: str) -> bool:
    """The fixed held-out split: crc32 of the person key % 20 == 0 (about 5 %)."""
    return zlib.crc32(person_key.encode()) % 20 == 0


# --- fits ----------------------------------------------------------------------------------
def fit_photo(item: dict, model: str = "sfm", detector: str = "auto") -> dict:
    """One photo's fit -> dict: ``found`` (bool), ``reason`` (str, why not), and when found
    ``identity`` (K,), ``expression`` (E,), ``rotation`` (3, 3), ``translation`` (3,) mm,
    ``scale`` (px/mm), ``focal`` (px), ``principal`` (2,), ``image_size`` (2,), ``landmarks68``
    (68, 2) photo px (the ground truth, or the detection as iBUG-68), ``residual_px`` (RMS
    landmark residual, photo px), ``detector`` (str), ``n_points`` (68 or 478), ``fit_ms``."""
    from morphable import load_model
    from morphable.detection import describe, detect_landmarks, read_image
    from morphable.detection.facemesh import to_ibug68
    from morphable.fitting import fit_landmarks
    from morphable.pipeline import read_landmark_file
    from morphable.fitting.noise import DETECTED_MODEL_STD_MM, MODEL_STD_MM

    t0 = time.perf_counter()
    try:
        img = read_image(item["path"])
        size = (img.shape[1], img.shape[0])
        if item["pts"]:
            pts, source = read_landmark_file(item["pts"], size), "ground truth"
        else:
            pts, source = detect_landmarks(img, landmark_detector=detector), describe(detector)
        res = fit_landmarks(load_model(model), pts, size,
                            model_std_mm=MODEL_STD_MM if item["pts"] else DETECTED_MODEL_STD_MM)
    except (FitError, InputError) as e:
        return {"found": False, "reason": str(e).splitlines()[0]}
    cam = res.cameras[0]
    return {"found": True, "reason": "", "identity": res.identity, "expression": res.expression[0],
            "rotation": cam.rotation, "translation": cam.translation, "scale": float(cam.scale),
            "focal": float(cam.focal), "principal": cam.principal,
            "image_size": np.array(size, np.float64),
            "landmarks68": pts if len(pts) == 68 else to_ibug68(pts),
            "residual_px": float(res.landmark_rmse_px[0]), "detector": source,
            "n_points": len(pts), "fit_ms": (time.perf_counter() - t0) * 1e3}


_FIT_ARRAYS = {"identity": None, "expression": None, "rotation": (3, 3), "translation": (3,),
               "scale": (), "focal": (), "principal": (2,), "image_size": (2,),
               "landmarks68": (68, 2), "residual_px": (), "n_points": (), "fit_ms": ()}


def _read_cache(path: Path, model: str, detector: str) -> dict:
    """{name: fit record} of a cache written for the same model and detector, else {}."""
    if not path.is_file():
        return {}
    try:
        with np.load(path, allow_pickle=False) as z:
            c = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError):
        log.warning("%s: unreadable fit cache, refitting", path)
        return {}
    if (int(c.get("format", -1)) != _CACHE_FORMAT or str(c["model"]) != model
            or str(c["detector_choice"]) != detector):
        log.info("%s: fits of another model or detector, refitting", path)
        return {}
    out = {}
    for i, name in enumerate(c["name"]):
        r = {"found": bool(c["found"][i]), "reason": str(c["reason"][i]), "detector": str(c["detector"][i])}
        if r["found"]:
            r.update({k: c[k][i] for k in _FIT_ARRAYS})
            r["n_points"] = int(r["n_points"])
        out[str(name)] = r
    return out


def _write_cache(path: Path, fits: dict, model: str, detector: str, K: int, E: int) -> None:
    from morphable.io.atomic import atomic_path

    names = sorted(fits)
    arrays = {"format": np.int64(_CACHE_FORMAT), "model": np.array(model),
              "detector_choice": np.array(detector), "name": np.array(names),
              "found": np.array([fits[n]["found"] for n in names], bool),
              "reason": np.array([fits[n]["reason"] for n in names]),
              "detector": np.array([fits[n].get("detector", "") for n in names])}
    shapes = dict(_FIT_ARRAYS, identity=(K,), expression=(E,))
    for key, shape in shapes.items():
        rows = [np.asarray(fits[n][key], np.float64) if fits[n]["found"] else np.full(shape, np.nan)
                for n in names]
        arrays[key] = np.stack(rows) if rows else np.zeros((0, *shape))
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)


def _pool_map(fn, items, workers: int):
    if workers <= 1:
        yield from map(fn, items)
        return
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers) as pool:
        yield from pool.map(fn, items, chunksize=8)


def _fit_one(args):
    return fit_photo(*args)


def fit_source(items: list, cache: Path, model: str = "sfm", detector: str = "auto",
               workers: int = 1) -> tuple:
    """Fits of ``items`` (:func:`list_photos`), reusing and updating the cache file ->
    ({name: record}, seconds spent fitting, number fitted now)."""
    from morphable import load_model

    m = load_model(model)
    fits = _read_cache(cache, model, detector)
    todo = [it for it in items if it["name"] not in fits]
    t0 = time.perf_counter()
    recs = _pool_map(_fit_one, [(it, model, detector) for it in todo], workers)
    for k, (it, rec) in enumerate(zip(todo, recs)):
        fits[it["name"]] = rec
        if (k + 1) % 500 == 0:
            log.info("  fitted %d / %d (%.0f s)", k + 1, len(todo), time.perf_counter() - t0)
            _write_cache(cache, fits, model, detector, m.n_identity, m.n_expression)
    if todo or not cache.is_file():
        _write_cache(cache, fits, model, detector, m.n_identity, m.n_expression)
    return fits, time.perf_counter() - t0, len(todo)


# --- baking --------------------------------------------------------------------------------
def bake_photo(item: dict, fit: dict, resolution: int = 64, model: str = "sfm",
               supersample: int = 2) -> dict:
    """The aligned crop of a fitted photo -> dict ``image`` (R, R, 3) uint8, ``normals``
    (R, R, 3) float32 camera frame, ``mask`` (R, R) float32 coverage, ``landmarks`` (68, 2)
    crop px, ``pose`` (3,) yaw, pitch, roll of the fit in the crop's frame (degrees),
    ``residual_px64`` (the fit's RMS residual in px of a 64-px crop)."""
    from morphable import load_model
    from morphable.camera import Camera
    from morphable.detection import read_image
    from morphable.raster import normal_map, visibility

    from .data import aligned_camera, alignment, warp_image

    m = load_model(model)
    lm = np.asarray(fit["landmarks68"], np.float64)
    A = alignment(lm, resolution, model)
    img = warp_image(read_image(item["path"]), A, resolution)
    cam = Camera(kind="affine", rotation=fit["rotation"], translation=fit["translation"],
                 scale=float(fit["scale"]), focal=float(fit["focal"]),
                 image_size=tuple(int(v) for v in fit["image_size"]), principal=fit["principal"])
    crop_cam = aligned_camera(cam, A, resolution)
    verts = m.vertices(fit["identity"], fit["expression"])
    vis = visibility(verts, m.triangles, crop_cam, supersample=supersample)
    s = float(np.sqrt(abs(np.linalg.det(A[:, :2]))))
    return {"image": img, "normals": normal_map(verts, m.triangles, vis=vis).astype(np.float32),
            "mask": vis.coverage().astype(np.float32),
            "landmarks": (lm @ A[:, :2].T + A[:, 2]).astype(np.float32),
            "pose": crop_cam.euler_deg.astype(np.float32),
            "residual_px64": float(fit["residual_px"]) * s * 64.0 / resolution}


def _bake_one(args):
    item, fit, resolution, model = args
    try:
        return bake_photo(item, fit, resolution, model)
    except (FitError, InputError) as e:
        return {"error": str(e).splitlines()[0]}


# --- the pack --------------------------------------------------------------------------------
def _check_paths(data: Path, out: Path, sources, limit) -> dict:
    """Everything that can fail before any work: the data folder, the photos, the output."""
    if not data.is_dir():
        raise InputError(f"{data}: data folder not found")
    photos = {s: list_photos(data, s, limit) for s in sources}
    if not any(photos.values()):
        raise InputError(f"{data}: no photos of {', '.join(sources)} under it")
    if out.suffix != ".npz":
        raise InputError(f"{out}: the pack must be a .npz file")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"{out}: cannot create the output folder {out.parent} ({e.strerror or e})") from None
    return photos


def _quantisation(path: Path, arrays: dict) -> dict:
    """Angles (degrees) between the baked and the stored-then-decoded normals, and the
    JPEG error of the images (0-255 levels)."""
    from .real_faces import load_pack

    back = load_pack(path)
    angles, abs_sum, sq_sum, count = [], 0.0, 0.0, 0
    for i in range(0, len(back["image"]), 512):     # chunks: a 128-px pack is ~10 GB in float64
        n, b = arrays["normals"][i:i + 512], back["normals"][i:i + 512]
        on = (np.abs(n).sum(-1) > 0) & (arrays["mask"][i:i + 512] > 0)
        angles.append(np.degrees(np.arccos(np.clip((n[on] * b[on]).sum(-1), -1, 1))).astype(np.float32))
        err = np.abs(arrays["image"][i:i + 512].astype(np.float64) - back["image"][i:i + 512])
        abs_sum, sq_sum, count = abs_sum + err.sum(), sq_sum + (err ** 2).sum(), count + err.size
    ang = np.concatenate(angles)
    mse = sq_sum / max(count, 1)
    return {"normal_error_deg_mean": float(ang.mean()), "normal_error_deg_p99": float(np.percentile(ang, 99)),
            "normal_error_deg_max": float(ang.max()), "jpeg_abs_error_mean": float(abs_sum / max(count, 1)),
            "jpeg_psnr_db": float(10 * np.log10(255 ** 2 / max(mse, 1e-12)))}


def build(data, out, resolution: int = 64, model: str = "sfm", sources=SOURCES, limit=None,
          detector: str = "auto", max_residual: float = MAX_RESIDUAL_PX64, workers: int = 1,
          jpeg_quality: int = 85, normal_scale: int = 64, max_mib: float = 50.0,
          normal_resolution: int | None = None) -> dict:
    """Fit, bake and pack the photos of ``sources`` -> the report (also written as JSON
    beside ``out``). Where the pack is larger than ``max_mib`` (0: no limit), the JPEG
    quality is lowered in steps of 5 (to 50 at least) until it fits. InputError before any
    work for a missing data folder, no photos or an output that cannot be written; after the
    fits, when no photo passes. ``normal_resolution``: normals and masks stored at that side
    (:func:`neural.gar.real_faces.save_pack`; the report's normal errors then include the
    enlargement back to ``resolution``)."""
    from morphable.detection import resolve_detectors
    from morphable.io.atomic import atomic_path

    from .real_faces import save_pack

    t_start = time.perf_counter()
    data, out = Path(data), Path(out)
    resolve_detectors(detector)                           # a bad name fails before any work
    photos = _check_paths(data, out, sources, limit)
    rows, counts, timings = [], {}, {}
    for source, items in photos.items():
        log.info("%s: %d photos", source, len(items))
        fits, fit_s, n_new = fit_source(items, out.parent / f"fits_{source}.npz", model, detector, workers)
        t0 = time.perf_counter()
        jobs = [(it, fits[it["name"]], resolution, model) for it in items if fits[it["name"]]["found"]]
        found = len(jobs)
        passed, baked_all = 0, []
        for j, ((it, fit, _, _), baked) in enumerate(zip(jobs, _pool_map(_bake_one, jobs, workers))):
            if (j + 1) % 2000 == 0:
                log.info("  baked %d / %d (%.0f s)", j + 1, len(jobs), time.perf_counter() - t0)
            baked_all.append({k: v for k, v in baked.items() if k in ("error", "residual_px64")})
            if "error" in baked or baked["residual_px64"] > max_residual:
                continue
            passed += 1
            rows.append((source, it, fit, baked))
        bake_s = time.perf_counter() - t0
        ok = [r for r in rows if r[0] == source]
        r64 = np.array([b["residual_px64"] for b in baked_all if "error" not in b])
        dark = [float((r[3]["image"] < DARK_LEVEL).all(-1).mean()) for r in ok]
        counts[source] = {"photos": len(items), "face_found": found, "passed": passed,
                          "residual_px64_found": {f"p{q}": round(float(np.percentile(r64, q)), 3)
                                                  for q in (50, 90, 95, 99)} if len(r64) else None,
                          "dark_share": round(float(np.mean(dark)), 4) if dark else None,
                          "held_out": int(sum(held_out(r[1]["person_key"]) for r in ok)),
                          "people": len({r[1]["person"] for r in ok})}
        timings[source] = {"fit_s": round(fit_s, 1), "fitted_now": n_new, "bake_s": round(bake_s, 1)}
        log.info("%s: %d found, %d passed (%.0f s fitting %d, %.0f s baking)", source, found, passed,
                 fit_s, n_new, bake_s)
    if not rows:
        raise InputError(f"{data}: no photo passed (face found, residual <= {max_residual} px at 64)")
    t0 = time.perf_counter()
    b = [r[3] for r in rows]
    arrays = {"image": np.stack([x["image"] for x in b]), "normals": np.stack([x["normals"] for x in b]),
              "mask": np.stack([x["mask"] for x in b]), "landmarks": np.stack([x["landmarks"] for x in b]),
              "person": np.array([r[1]["person"] for r in rows], np.int64),
              "held_out": np.array([held_out(r[1]["person_key"]) for r in rows]),
              "source": np.array([r[0] for r in rows]), "name": np.array([r[1]["name"] for r in rows]),
              "fit_pose": np.stack([x["pose"] for x in b]),
              # float16: 1e-3 of a standard deviation is plenty, and it halves their share
              "fit_identity": np.stack([r[2]["identity"] for r in rows]).astype(np.float16),
              "fit_expression": np.stack([r[2]["expression"] for r in rows]).astype(np.float16),
              "fit_residual_px64": np.array([x["residual_px64"] for x in b], np.float32),
              "fit_detector": np.array([r[2]["detector"] for r in rows]),
              "fit_model": np.array(model)}
    while True:
        save_pack(out, arrays, jpeg_quality=jpeg_quality, normal_scale=normal_scale,
                  normal_resolution=normal_resolution)
        mib = out.stat().st_size / 2 ** 20
        if not max_mib or mib <= max_mib or jpeg_quality <= 50:
            break
        log.info("%s: %.1f MiB > %g MiB at JPEG quality %d, trying %d", out, mib, max_mib,
                 jpeg_quality, jpeg_quality - 5)
        jpeg_quality -= 5
    pack_s = time.perf_counter() - t0
    residuals = arrays["fit_residual_px64"]
    report = {"pack": str(out), "resolution": int(resolution), "model": model, "detector": detector,
              "sources": counts, "total": {k: int(sum(c[k] for c in counts.values()))
                                           for k in ("photos", "face_found", "passed", "held_out")},
              "pass_rule": {"face_found": True, "max_residual_px64": float(max_residual)},
              "passed_residual_px64": {"median": float(np.median(residuals)),
                                       "p90": float(np.percentile(residuals, 90))},
              "jpeg_quality": int(jpeg_quality), "normal_scale": int(normal_scale),
              "normal_resolution": int(normal_resolution or resolution),
              "max_mib": float(max_mib),
              "pack_bytes": out.stat().st_size, "pack_mib": round(out.stat().st_size / 2 ** 20, 2),
              **_quantisation(out, arrays),
              "timings_s": {**timings, "pack_s": round(pack_s, 1),
                            "total_s": round(time.perf_counter() - t_start, 1)},
              "workers": int(workers)}
    with atomic_path(out.with_suffix(".json")) as tmp:
        tmp.write_text(json.dumps(report, indent=1) + "\n")
    return report


def contact_sheet(pack, out, n: int = 16, seed: int = 0) -> Path:
    """A PNG of ``n`` random crops of a pack, each beside its normal map (RGB = (n + 1) / 2,
    background black; 256 colours), 4 pairs a row -> the path."""
    from PIL import Image

    from morphable.io.atomic import atomic_path

    from .real_faces import load_pack

    a = load_pack(pack)
    idx = np.sort(np.random.default_rng(seed).choice(len(a["image"]), min(n, len(a["image"])), replace=False))
    tiles = []
    for i in idx:
        nm = np.where(a["mask"][i][..., None] > 0, (a["normals"][i] + 1) / 2, 0)
        tiles.append(np.concatenate([a["image"][i], np.round(nm * 255).astype(np.uint8)], 1))
    cols = 4
    rows = [np.concatenate(tiles[r:r + cols] + [np.zeros_like(tiles[0])] * (cols - len(tiles[r:r + cols])), 1)
            for r in range(0, len(tiles), cols)]
    out = Path(out)
    with atomic_path(out) as tmp:
        # 256 colours keep the sheet small enough for the docs (~1/3 of the RGB file)
        Image.fromarray(np.concatenate(rows, 0)).quantize(256).save(tmp, optimize=True)
    return out


# --- command line ----------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    from morphable.detection import LANDMARK_DETECTORS
    from morphable.logs import add_verbosity_arguments

    p = argparse.ArgumentParser(prog="python -m neural.gar.build_real", description=__doc__.splitlines()[0])
    p.add_argument("--data", default="../shared/data", help="the shared data folder")
    p.add_argument("--out", default="gar_data/real64.npz", help="the pack (.npz); fits and report beside it")
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--model", default="sfm")
    p.add_argument("--sources", default=",".join(SOURCES), help="comma-separated: " + ", ".join(SOURCES))
    p.add_argument("--limit", type=int, help="at most this many photos per source")
    p.add_argument("--detector", default="auto", choices=LANDMARK_DETECTORS)
    p.add_argument("--max-residual", type=float, default=MAX_RESIDUAL_PX64,
                   help="pass bound: RMS landmark residual in px of a 64-px crop")
    p.add_argument("--workers", type=int, default=1, help="processes for fitting and baking")
    p.add_argument("--jpeg-quality", type=int, default=85, help="JPEG quality of the crops")
    p.add_argument("--normal-scale", type=int, default=64,
                   help="normals' x, y stored in steps of 1/NORMAL_SCALE (1..127)")
    p.add_argument("--normal-resolution", type=int,
                   help="store normals and masks at this side (RESOLUTION / an integer), "
                        "enlarged back on load: the images of a 128-px pack within 64 MiB")
    p.add_argument("--max-mib", type=float, default=50.0,
                   help="lower the JPEG quality until the pack is at most this size (0: no limit)")
    p.add_argument("--sheet", help="also write a contact sheet PNG of 16 crops and normal maps")
    add_verbosity_arguments(p)
    return p


def main(argv=None) -> int:
    from morphable.logs import configure, verbosity

    args = build_parser().parse_args(argv)
    configure(verbosity(args))
    try:
        sources = tuple(s.strip() for s in args.sources.split(",") if s.strip())
        if not sources:
            raise InputError("--sources: no source given")
        if args.resolution < 16:
            raise InputError(f"--resolution must be at least 16, got {args.resolution}")
        nr = args.normal_resolution
        if nr is not None and (nr < 8 or args.resolution % nr):
            raise InputError(f"--normal-resolution must divide --resolution {args.resolution} "
                             f"and be at least 8, got {nr}")
        report = build(args.data, args.out, args.resolution, args.model, sources, args.limit,
                       args.detector, args.max_residual, args.workers, args.jpeg_quality,
                       args.normal_scale, args.max_mib, args.normal_resolution)
        if args.sheet:
            contact_sheet(args.out, args.sheet)
        log.info("wrote %s (%d crops, %.1f MiB) and its report", args.out, report["total"]["passed"],
                 report["pack_mib"])
        return 0
    except MorphableError as e:
        print(f"neural.gar.build_real: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
