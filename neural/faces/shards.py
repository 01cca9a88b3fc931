"""Resumable packs of shards, shared by the pack builders (:mod:`neural.faces.build_synthetic`,
:mod:`neural.faces.build_annotated`, :mod:`neural.faces.build_profiled`).

A pack is a folder: ``pack.json`` (the settings, a rerun with other settings is refused; after
each run the builder's report) and ``shard_NNNNN.npz``, each written atomically
(:mod:`morphable.io.atomic`). Shard ``i`` holds the items ``i * shard_size`` ..; a rerun
builds only the shards that are not there, so a killed build loses only the shards in
progress and a finished one is not rebuilt.

>>> validation_split(["london/001", "london/002", "london/002"]).tolist()
[False, True, True]
"""
from __future__ import annotations

import json
import logging
import time
import zlib
from pathlib import Path

import numpy as np

from morphable.errors import InputError

__all__ = ["check_out", "write_manifest", "read_settings", "pending_shards", "write_shard",
           "run_shards", "shard_paths", "validation_split", "VALIDATION_FRACTION"]

log = logging.getLogger("neural.faces.shards")

VALIDATION_FRACTION = 0.1


def read_settings(out) -> dict | None:
    """The settings in ``out/pack.json``, None when there is none; InputError when unreadable."""
    manifest = Path(out) / "pack.json"
    if not manifest.is_file():
        return None
    try:
        return json.loads(manifest.read_text())["settings"]
    except (OSError, ValueError, KeyError, TypeError):
        raise InputError(f"{manifest}: unreadable pack manifest") from None


def check_out(out, settings: dict) -> None:
    """InputError unless ``out`` can be (or is) a pack folder built with ``settings``: a file
    in its place, a parent that is not a folder, or a ``pack.json`` of other settings."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: not a folder (the pack is a folder of shards)")
    parent = next((p for p in out.parents if p.exists()), Path("."))
    if not parent.is_dir():
        raise InputError(f"{out}: cannot create the pack folder ({parent} is not a folder)")
    old = read_settings(out)
    if old is not None and old != settings:
        diff = ", ".join(f"{k} {old.get(k)} != {v}" for k, v in settings.items() if old.get(k) != v)
        extra = [k for k in old if k not in settings]
        diff = ", ".join([diff] * bool(diff) + [f"{k} {old[k]} not set" for k in extra])
        raise InputError(f"{out}: a pack built with other settings ({diff}); use another --out")


def write_manifest(out, manifest: dict) -> None:
    """``out/pack.json`` written atomically."""
    from morphable.io.atomic import write_json

    write_json(Path(out) / "pack.json", manifest)


def shard_paths(out) -> list:
    """The shard files of a pack folder, sorted."""
    return sorted(Path(out).glob("shard_*.npz"))


def pending_shards(out, n: int, shard_size: int) -> tuple:
    """The shards of ``n`` items still to build -> (jobs, skipped): jobs a list of
    ``(path, first, count)``, skipped the number of shards already written."""
    jobs, skipped = [], 0
    for i, first in enumerate(range(0, n, shard_size)):
        path = Path(out) / f"shard_{i:05d}.npz"
        if path.is_file():
            skipped += 1
            continue
        jobs.append((str(path), first, min(shard_size, n - first)))
    return jobs, skipped


def write_shard(path, arrays: dict, compressed: bool = False) -> None:
    """One shard file, atomically: a killed build leaves no partial shard."""
    from morphable.io.atomic import atomic_path

    with atomic_path(Path(path)) as tmp:
        with open(tmp, "wb") as f:
            (np.savez_compressed if compressed else np.savez)(f, **arrays)


def run_shards(jobs, build_shard, workers: int = 1, initializer=None, initargs=()):
    """Run ``build_shard(job)`` for each job (``workers`` processes, each started with
    ``initializer(*initargs)``; in this process for one worker or one job) and yield the
    results in the jobs' order, each with its seconds: ``(result, seconds)``."""
    timed = _Timed(build_shard)
    if workers <= 1 or len(jobs) <= 1:
        if initializer is not None:
            initializer(*initargs)
        yield from map(timed, jobs)
        return
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers, initializer=initializer, initargs=initargs) as pool:
        yield from pool.map(timed, jobs)


class _Timed:
    """A picklable ``job -> (fn(job), seconds)``."""

    def __init__(self, fn):
        self.fn = fn

    def __call__(self, job):
        t0 = time.perf_counter()
        return self.fn(job), time.perf_counter() - t0


def validation_split(keys, fraction: float = VALIDATION_FRACTION) -> np.ndarray:
    """(N,) bool: True for the keys in the fixed validation split: ``crc32(key) / 2**32 <
    fraction`` (zlib's CRC-32 of the key's UTF-8 text, the same in every process and run, never
    Python's ``hash()``). A key names a person where persons are known (``"london/001"``: the
    same person is in the same split in every pack), else one photo (``"aflw/2000"``)."""
    keys = [str(k) for k in keys]
    return np.array([zlib.crc32(k.encode()) / 2.0 ** 32 < fraction for k in keys], dtype=bool)
