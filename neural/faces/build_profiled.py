"""Build the profiled landmark pack: real photos turned to new head poses through their fits,
with all 546 points labelled (issue 41, item 4 (b); docs/landmark_packs.md).

``python -m neural.faces.build_profiled --data ../shared/data --out landmark_data/profiled
[--per-photo K] [--aflw N] [--resolution 192] [--shard-size 16] [--seed 0] [--workers 1]``

Photos: the London neutral front photos (CC BY 4.0) and ``--aflw N`` AFLW crops evenly spaced
over the 11,000 (research use only; 0: none) — never 300-W or AFLW2000-3D (test sets). Each
is fitted (SFM) to its own annotation as in :mod:`neural.faces.build_annotated` (London: the FRL
template's points and jaw; AFLW: its 19 mapped points), the same failure rule (no fit, RMS
residual above :data:`neural.faces.annotations.MAX_RESIDUAL` of the face box's side); then turned by
:func:`morphable.profiling.profile_photo` to K poses: target yaws one in each of K equal bins of
[-90, 90] degrees (uniform within the bin), target pitch uniform in [-25, 25] degrees, the turn
being the target minus the fit's pose (clipped to profiling's +-90 and +-60 degrees), drawn
from ``numpy.random.default_rng([seed, photo index])``. A photo whose crop (1.5 x its face box)
is ``f >= 2`` times ``--resolution`` is first shrunk by the whole factor ``f`` (PIL's box
reduce) and refitted: the crop loses nothing and profiling costs less (London: 512 -> 256 px).

Labels: the 478 face-mesh and 68 iBUG points of the fitted surface at the new pose (3D
convention, hidden points where they project) with their visibility; SFM's two inner-mouth
iBUG rows are not labelled. Face box: of the new pose's 68 points. Shard arrays as in
:mod:`neural.faces.build_annotated` (``name`` is ``<photo>#<k>``, ``yaw_deg`` the new pose's yaw in
the fit's convention, ``residual_px`` the photo's fit residual in crop px).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors

__all__ = ["build", "profiled_faces", "pose_targets", "PITCH_RANGE_DEG", "main"]

log = logging.getLogger("neural.faces.build_profiled")

PITCH_RANGE_DEG = 25.0
"""The largest target pitch, degrees, either way (:func:`pose_targets`)."""
SOURCE_NAMES = ("london", "aflw")

_STATE: dict = {}


def _settings(per_photo, aflw, resolution, shard_size, seed, model, texture_size) -> dict:
    from .annotations import MAX_RESIDUAL
    from .build_annotated import FORMAT

    return {"format": FORMAT, "kind": "profiled", "per_photo": int(per_photo), "aflw": int(aflw),
            "resolution": int(resolution), "shard_size": int(shard_size), "seed": int(seed),
            "model": str(model), "texture_size": int(texture_size), "max_residual": MAX_RESIDUAL,
            "pitch_range_deg": PITCH_RANGE_DEG}


def pose_targets(rng, k: int) -> np.ndarray:
    """(k, 2) target (yaw, pitch) degrees: one yaw in each of ``k`` equal bins of [-90, 90],
    uniform within it, pitch uniform in +-:data:`PITCH_RANGE_DEG`, in a random order."""
    edges = np.linspace(-90.0, 90.0, k + 1)
    yaw = rng.uniform(edges[:-1], edges[1:])
    pitch = rng.uniform(-PITCH_RANGE_DEG, PITCH_RANGE_DEG, k)
    return np.stack([yaw, pitch], 1)[rng.permutation(k)]


def _init_worker(model, items, settings):
    import morphable

    _STATE.update(model=morphable.load_model(model), items=items, settings=settings)


def _shrink(img, item, factor: int):
    """The photo reduced by ``factor`` (box filter) and the item's points with it."""
    from PIL import Image

    if factor <= 1:
        return img, item
    small = np.asarray(Image.fromarray(img).reduce(factor))
    # reduced pixel q covers photo pixels f q .. f q + f - 1: its centre is f q + (f - 1) / 2
    move = lambda p: (p - (factor - 1) / 2) / factor            # noqa: E731
    return small, {**item, "points": move(item["points"]), "fit_points": move(item["fit_points"])}


def profiled_faces(model, item: dict, index: int, source: int, settings: dict) -> tuple:
    """One photo -> (records of its profiled faces, failures as ``(name, reason)``)."""
    from morphable.detection.images import read_image
    from morphable.errors import FitError
    from morphable.profiling import MAX_PITCH_DEG, MAX_YAW_DEG, profile_photo
    from morphable.texture import texture_from_views

    from .annotations import CROP_SCALE, MAX_RESIDUAL, face_record, fit_item
    from .points import IBUG_ROWS, face_box
    from .shards import validation_split

    R = settings["resolution"]
    img = read_image(item["path"])
    try:
        fit, P, res = fit_item(model, item, (img.shape[1], img.shape[0]))
        factor = int(CROP_SCALE * np.ptp(face_box(P[IBUG_ROWS])[[0, 2]]) / R)
        if factor >= 2:
            img, item = _shrink(img, item, factor)
            fit, P, res = fit_item(model, item, (img.shape[1], img.shape[0]))
    except FitError:
        return [], [(item["name"], "no fit")]
    side = float(np.ptp(face_box(P[IBUG_ROWS])[[0, 2]]))
    if not (np.isfinite(res) and res <= MAX_RESIDUAL * side):
        return [], [(item["name"], "residual")]
    cam = fit.cameras[0]
    v = fit.vertices(0, np.float64)
    tex = texture_from_views(model, v[None], [cam], [img], size=settings["texture_size"])
    yaw0, pitch0 = cam.euler_deg[:2]
    rng = np.random.default_rng([settings["seed"], index])
    split = int(validation_split([item["key"]])[0])
    records, failures = [], []
    for k, (ty, tp) in enumerate(pose_targets(rng, settings["per_photo"])):
        name = f"{item['name']}#{k}"
        dy = float(np.clip(ty - yaw0, -MAX_YAW_DEG, MAX_YAW_DEG))
        dp = float(np.clip(tp - pitch0, -MAX_PITCH_DEG, MAX_PITCH_DEG))
        try:
            o = profile_photo(img, fit, dy, dp, texture=tex)
        except (FitError, InputError) as e:
            log.info("%s: profiling: %s", name, str(e).splitlines()[0])
            failures.append((name, "profiling"))
            continue
        points = np.concatenate([o["landmarks_px"]["478"], o["landmarks_px"]["68"]])
        visible = np.concatenate([o["visible"]["478"], o["visible"]["68"]])
        labelled = np.isfinite(points).all(1)
        box = face_box(points[IBUG_ROWS])
        rec = face_record(o["image"], points, labelled, visible, box, R)
        rec.update(convention=0, person=item["person"], split=split, source=source,
                   yaw_deg=float(o["camera"].euler_deg[0]), name=name,
                   residual_px=res * R / (CROP_SCALE * float(box[2] - box[0])))
        records.append(rec)
    return records, failures


def _build_shard(job):
    from .annotations import stack_records
    from .shards import write_shard

    path, first, count = job
    s = _STATE["settings"]
    records, failures = [], []
    for i in range(first, first + count):
        item = _STATE["items"][i]
        r, f = profiled_faces(_STATE["model"], item, i, SOURCE_NAMES.index(item["set"]), s)
        records += r
        failures += f
    write_shard(path, stack_records(records, s["resolution"], failures))
    return len(records), len(failures)


def build(data, out, per_photo: int = 6, aflw: int = 300, resolution: int = 192,
          shard_size: int = 16, seed: int = 0, workers: int = 1, model: str = "sfm",
          texture_size: int = 256) -> dict:
    """Build (or finish) the profiled pack at ``out`` (``shard_size`` photos a shard); returns
    the manifest written to ``pack.json``."""
    from .annotations import set_items
    from .build_annotated import SOURCES, run_pack

    t0 = time.perf_counter()
    data, out = Path(data), Path(out)
    for flag, v, lo in (("--per-photo", per_photo, 1), ("--resolution", resolution, 16),
                        ("--shard-size", shard_size, 1), ("--aflw", aflw, 0)):
        if v < lo:
            raise InputError(f"{flag} must be at least {lo}, got {v}")
    settings = _settings(per_photo, aflw, resolution, shard_size, seed, model, texture_size)
    items = set_items(data, "london")
    if aflw:
        a = set_items(data, "aflw")
        items += [a[i] for i in np.linspace(0, len(a) - 1, min(aflw, len(a))).round().astype(int)]
    manifest = {"settings": settings, "kind": "profiled",
                "sources": [{"name": s, **SOURCES[s]} for s in SOURCE_NAMES], "photos": len(items)}
    return run_pack(out, manifest, len(items), _build_shard, workers, _init_worker,
                    (model, items, settings), t0)


def build_parser() -> argparse.ArgumentParser:
    from morphable.logs import add_verbosity_arguments

    p = argparse.ArgumentParser(prog="python -m neural.faces.build_profiled",
                                description=__doc__.splitlines()[0])
    p.add_argument("--data", default="../shared/data", help="the shared data folder")
    p.add_argument("--out", required=True, help="the pack folder (made; a rerun finishes it)")
    p.add_argument("--per-photo", type=int, default=6, help="poses per photo (K)")
    p.add_argument("--aflw", type=int, default=300, help="AFLW crops to use, evenly spaced (0: none)")
    p.add_argument("--resolution", type=int, default=192, help="crop side, px")
    p.add_argument("--shard-size", type=int, default=16, help="photos per shard file")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=1, help="processes building shards")
    add_verbosity_arguments(p)
    return p


@one_line_errors("neural.faces.build_profiled")
def main(argv=None) -> int:
    from morphable.logs import configure, verbosity

    args = build_parser().parse_args(argv)
    configure(verbosity(args))
    m = build(args.data, args.out, args.per_photo, args.aflw, args.resolution, args.shard_size,
              args.seed, args.workers)
    print(json.dumps(m["report"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
