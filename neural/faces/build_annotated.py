"""Build the annotated landmark pack: real photos with their own sparse annotations as rows of
the landmark network's 546 points (issue 41, item 4 (c); docs/landmark_packs.md).

``python -m neural.faces.build_annotated --data ../shared/data --out landmark_data/annotated
[--sets aflw,london,300w,aflw2000] [--resolution 192] [--shard-size 256] [--workers 1]``

Sets (:mod:`neural.faces.annotations`): ``aflw`` (AFLW crops, 21 manual points of which 19 map to
rows; research use only), ``london`` (FRL London neutral photos, the 189-point template;
CC BY 4.0), ``300w`` (300-W's 68 points, 2D convention; research use only; **test split**),
``aflw2000`` (AFLW2000-3D's ``pts68_3d``, 3D convention; research use only; **test split**).

Per photo: SFM is fitted to its points (:func:`neural.faces.annotations.fit_item`); the face box is
:func:`neural.faces.points.face_box` of the annotation's own 68 points where they are in the 3D
convention (AFLW2000-3D), else of the fit's 68 points; a failure is no fit or an RMS residual
above :data:`neural.faces.annotations.MAX_RESIDUAL` of the box's side. The crop is the box grown by
1.5, resampled to ``--resolution`` (black outside the photo). Validation: 10 % by
:func:`neural.faces.shards.validation_split` of the person (London) or of the photo (AFLW: no
person ids); 300-W and AFLW2000-3D are split 2 (test), never trained on.

Shard arrays (format ``landmarks-1``): ``image``, ``box``, ``points``, ``labelled``,
``visible``, ``convention``, ``person``, ``split``, ``source``, ``yaw_deg``, ``name``,
``residual_px`` (the fit's RMS residual in crop px), ``failed_name``, ``failed_reason``.
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

__all__ = ["build", "run_pack", "SOURCES", "FORMAT", "pack_report", "annotated_face", "parse_sets", "main"]

log = logging.getLogger("neural.faces.build_annotated")

FORMAT = "landmarks-1"
SOURCES = {
    "aflw": {"licence": "AFLW (Koestinger et al. 2011): research use only", "research_only": True},
    "london": {"licence": "CC BY 4.0 (DeBruine & Jones 2017)", "research_only": False},
    "300w": {"licence": "300-W (Sagonas et al. 2013): research, non-commercial use only",
             "research_only": True},
    "aflw2000": {"licence": "AFLW2000-3D (Zhu et al. 2016): research use only",
                 "research_only": True},
}
SPLIT_NAMES = ("train", "validation", "test")

_STATE: dict = {}   # per worker process: the model, the items and the settings


def _settings(sets, resolution, shard_size, model) -> dict:
    from .annotations import MAX_RESIDUAL

    return {"format": FORMAT, "kind": "annotated", "sets": list(sets), "resolution": int(resolution),
            "shard_size": int(shard_size), "model": str(model), "max_residual": MAX_RESIDUAL}


def parse_sets(text, allowed) -> list:
    """``"a,b"`` -> the named sets in ``allowed``'s order; InputError for an unknown or no set."""
    names = [s.strip() for s in str(text).split(",") if s.strip()]
    bad = [s for s in names if s not in allowed]
    if bad or not names:
        raise InputError(f"--sets: expected some of {','.join(allowed)}, got {text!r}")
    return [s for s in allowed if s in names]


def _init_worker(model, items, settings):
    import morphable

    _STATE.update(model=morphable.load_model(model), items=items, settings=settings)


def annotated_face(model, item: dict, source: int, resolution: int):
    """One annotated photo -> its record (:func:`neural.faces.annotations.face_record` plus the
    per-face fields) or ``(None, reason)`` for a failure (``no fit``, ``residual``)."""
    from morphable.detection.images import read_image
    from morphable.errors import FitError
    from morphable.labels import label_schemes, project_labels

    from .annotations import CROP_SCALE, MAX_RESIDUAL, face_record, fit_item
    from .points import IBUG_ROWS, N_POINTS, face_box
    from .shards import validation_split

    img = read_image(item["path"])
    H, W = img.shape[:2]
    try:
        fit, P, res = fit_item(model, item, (W, H))
    except FitError:
        return None, "no fit"
    box = face_box(item["own68"] if item["own68"] is not None else P[IBUG_ROWS])
    side = float(box[2] - box[0])
    if not (np.isfinite(res) and res <= MAX_RESIDUAL * side):
        return None, "residual"
    points = np.full((N_POINTS, 2), np.nan)
    points[item["rows"]] = item["points"]
    labelled = np.isfinite(points).all(1)
    visible = labelled.copy()
    if item["labels_hidden"]:
        # hidden points are labelled too: which are seen, the fit says
        lab = project_labels(fit.vertices(0, np.float64), model.triangles, fit.cameras[0],
                             label_schemes(model))
        visible &= np.concatenate([lab["visible478"], lab["visible68"]])
    rec = face_record(img, points, labelled, visible, box, resolution)
    yaw = item["yaw_deg"] if np.isfinite(item["yaw_deg"]) else float(fit.euler_deg[0, 0])
    split = 2 if item["test"] else int(validation_split([item["key"]])[0])
    rec.update(convention=item["convention"], person=item["person"], split=split, source=source,
               yaw_deg=yaw, name=item["name"], residual_px=res * resolution / (CROP_SCALE * side))
    return rec, None


def _build_shard(job):
    from .annotations import stack_records
    from .shards import write_shard

    path, first, count = job
    s = _STATE["settings"]
    records, failures = [], []
    for item in _STATE["items"][first:first + count]:
        rec, why = annotated_face(_STATE["model"], item, s["sets"].index(item["set"]), s["resolution"])
        if rec is None:
            failures.append((item["name"], why))
            log.info("%s: %s", item["name"], why)
        else:
            records.append(rec)
    write_shard(path, stack_records(records, s["resolution"], failures))
    return len(records), len(failures)


def pack_report(out, source_names) -> dict:
    """Counts of a pack folder's shards: faces per source and split, failures per source and
    reason."""
    from .shards import shard_paths

    faces = {s: {k: 0 for k in SPLIT_NAMES} for s in source_names}
    failures = {s: {} for s in source_names}
    total = 0
    for p in shard_paths(out):
        with np.load(p, allow_pickle=False) as z:
            src, split, fname, reason = z["source"], z["split"], z["failed_name"], z["failed_reason"]
        total += len(src)
        for s, k in zip(src, split):
            faces[source_names[int(s)]][SPLIT_NAMES[int(k)]] += 1
        for n, r in zip(fname, reason):
            d = failures[str(n).split("/")[0]]
            d[str(r)] = d.get(str(r), 0) + 1
    return {"faces": total, "faces_by_source": faces, "failures_by_source": failures}


def build(data, out, sets=("aflw", "london", "300w", "aflw2000"), resolution: int = 192,
          shard_size: int = 256, workers: int = 1, model: str = "sfm") -> dict:
    """Build (or finish) the annotated pack at ``out``; returns the manifest written to
    ``pack.json`` (``report``: faces per source and split, failures by reason, seconds)."""
    from .annotations import SETS, set_items

    t0 = time.perf_counter()
    data, out = Path(data), Path(out)
    sets = parse_sets(",".join(sets) if not isinstance(sets, str) else sets, SETS)
    if resolution < 16:
        raise InputError(f"--resolution must be at least 16, got {resolution}")
    if shard_size < 1:
        raise InputError(f"--shard-size must be at least 1, got {shard_size}")
    settings = _settings(sets, resolution, shard_size, model)
    items = [it for s in sets for it in set_items(data, s)]
    manifest = {"settings": settings, "kind": "annotated",
                "sources": [{"name": s, **SOURCES[s]} for s in sets], "items": len(items)}
    return run_pack(out, manifest, len(items), _build_shard, workers, _init_worker,
                    (model, items, settings), t0)


def run_pack(out, manifest: dict, n_items: int, build_shard, workers: int, initializer,
             initargs, t0: float) -> dict:
    """Check ``out`` against ``manifest["settings"]``, write the manifest, build the shards of
    ``n_items`` items still missing (:mod:`neural.faces.shards`), then write the manifest again
    with its ``report`` (:func:`pack_report`, what this run built, seconds since ``t0``) ->
    the manifest."""
    from .shards import check_out, pending_shards, run_shards, write_manifest

    out = Path(out)
    check_out(out, manifest["settings"])
    out.mkdir(parents=True, exist_ok=True)
    write_manifest(out, manifest)
    jobs, skipped = pending_shards(out, n_items, manifest["settings"]["shard_size"])
    done = failed = 0
    for k, ((n, f), sec) in enumerate(run_shards(jobs, build_shard, workers, initializer, initargs)):
        done, failed = done + n, failed + f
        log.info("shard %d / %d: %d faces, %d failed, %.1f s", k + 1, len(jobs), n, f, sec)
    names = [s["name"] for s in manifest["sources"]]
    manifest["report"] = {**pack_report(out, names), "faces_built_now": done, "failed_now": failed,
                          "shards_built_now": len(jobs), "shards_skipped": skipped,
                          "seconds": round(time.perf_counter() - t0, 1), "workers": int(workers)}
    write_manifest(out, manifest)
    return manifest


def build_parser() -> argparse.ArgumentParser:
    from morphable.logs import add_verbosity_arguments

    p = argparse.ArgumentParser(prog="python -m neural.faces.build_annotated",
                                description=__doc__.splitlines()[0])
    p.add_argument("--data", default="../shared/data", help="the shared data folder")
    p.add_argument("--out", required=True, help="the pack folder (made; a rerun finishes it)")
    p.add_argument("--sets", default="aflw,london,300w,aflw2000", help="comma-separated sets")
    p.add_argument("--resolution", type=int, default=192, help="crop side, px")
    p.add_argument("--shard-size", type=int, default=256, help="photos per shard file")
    p.add_argument("--workers", type=int, default=1, help="processes building shards")
    add_verbosity_arguments(p)
    return p


@one_line_errors("neural.faces.build_annotated")
def main(argv=None) -> int:
    from morphable.logs import configure, verbosity

    args = build_parser().parse_args(argv)
    configure(verbosity(args))
    m = build(args.data, args.out, args.sets, args.resolution, args.shard_size, args.workers)
    print(json.dumps(m["report"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
