"""Resumable batch fitting: manifests, an append-only results log, local or Dask execution.

Each item (one image, or all frames of one subject) gets its own output folder, written
atomically (a temporary folder renamed into place), and then one line in
``OUT/results.jsonl``. A re-run reads that log and skips every item already recorded, so a
killed run resumes where it stopped with no item lost or duplicated. A failed item is
recorded with its error and the batch goes on.
"""
from __future__ import annotations

import csv
import glob
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from .errors import InputError, MorphableError

__all__ = ["BatchItem", "read_manifest", "run_batch", "read_results", "RESULTS"]

log = logging.getLogger(__name__)

RESULTS = "results.jsonl"
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".ppm", ".bmp", ".tif", ".tiff"}


@dataclass
class BatchItem:
    """One unit of work: frames of one subject (a single image is a subject of one frame).

    Attributes
    ----------
    id : str
        Unique, file-system safe; names the output folder.
    images : list of str
    landmarks : list of str or None
        One landmark file per image (None entries: detect).
    """

    id: str
    images: list
    landmarks: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"id": self.id, "images": self.images, "landmarks": self.landmarks}


def _safe_id(text: str) -> str:
    keep = "".join(c if c.isalnum() or c in "-_." else "_" for c in text)
    return keep.strip("._") or "item"


def _sibling_landmarks(image: Path) -> str | None:
    for suffix in (".pts", ".ljson"):
        p = image.with_suffix(suffix)
        if p.is_file():
            return str(p)
    return None


def _group(rows: list[dict], source: str) -> list[BatchItem]:
    """Rows {image, landmarks?, subject?} -> items; rows of one subject form one item."""
    items: dict[str, BatchItem] = {}
    for i, row in enumerate(rows):
        image = row.get("image")
        if not image:
            raise InputError(f"{source}: row {i + 1} has no 'image'")
        lmk = row.get("landmarks") or _sibling_landmarks(Path(image))
        key = _safe_id(row.get("subject") or row.get("id") or Path(image).stem)
        item = items.setdefault(key, BatchItem(key, [], []))
        item.images.append(str(image))
        item.landmarks.append(lmk)
    return list(items.values())


def read_manifest(spec) -> list[BatchItem]:
    """Items from a folder of images, a glob, or a CSV/JSONL manifest.

    Folder and glob: one item per image, with a sibling ``.pts``/``.ljson`` used when present.
    CSV (header ``image,landmarks,subject``) or JSONL (objects with those keys): paths are
    relative to the manifest; rows that share a ``subject`` are fitted together (multi-frame).
    """
    p = Path(spec)
    if p.is_dir():
        images = sorted(q for q in p.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)
        rows = [{"image": str(q)} for q in images]
        source = str(p)
    elif p.suffix.lower() in (".csv", ".jsonl") and p.is_file():
        rows = _read_rows(p)
        for row in rows:
            for key in ("image", "landmarks"):
                if row.get(key) and not Path(row[key]).is_absolute():
                    row[key] = str(p.parent / row[key])
        source = str(p)
    else:
        rows = [{"image": q} for q in sorted(glob.glob(str(spec)))
                if Path(q).suffix.lower() in IMAGE_SUFFIXES]
        source = str(spec)
    if not rows:
        raise InputError(f"{source}: no images found")
    items = _group(rows, source)
    seen = set()
    for item in items:
        if item.id in seen:
            raise InputError(f"{source}: two items would share the output folder {item.id!r}")
        seen.add(item.id)
    return items


def _read_rows(path: Path) -> list[dict]:
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    if path.suffix.lower() == ".csv":
        reader = csv.DictReader(text.splitlines())
        if not reader.fieldnames or "image" not in reader.fieldnames:
            raise InputError(f"{path}: CSV needs a header with an 'image' column")
        return [dict(r) for r in reader]
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as e:
            raise InputError(f"{path}: line {n} is not JSON ({e.msg})") from None
        if not isinstance(row, dict):
            raise InputError(f"{path}: line {n} is not a JSON object")
        rows.append(row)
    return rows


def read_results(out_dir) -> dict:
    """id -> last record of ``OUT/results.jsonl``; a torn last line (killed mid-write) is dropped
    from the file so that appending goes on cleanly."""
    path = Path(out_dir) / RESULTS
    if not path.exists():
        return {}
    raw = path.read_bytes()
    end = raw.rfind(b"\n") + 1
    if end < len(raw):
        with open(path, "r+b") as f:
            f.truncate(end)
    records = {}
    for line in raw[:end].splitlines():
        try:
            rec = json.loads(line)
            records[rec["id"]] = rec
        except (json.JSONDecodeError, KeyError, TypeError):
            log.warning("%s: skipping a malformed line", path)
    return records


def _append(path: Path, record: dict) -> None:
    with open(path, "a") as f:
        f.write(json.dumps(record) + "\n")
        f.flush()
        os.fsync(f.fileno())


def _run_item(item: BatchItem, out_dir: str, work, options: dict) -> dict:
    """Run ``work(item, folder, options)`` into a temporary folder, then move it into place."""
    out = Path(out_dir)
    final = out / "items" / item.id
    start = time.perf_counter()
    tmp = Path(tempfile.mkdtemp(dir=out / "items", prefix=f".{item.id}."))
    try:
        summary = work(item, tmp, options) or {}
        if final.exists():
            shutil.rmtree(final)
        tmp.rename(final)
        status, error = "ok", None
    except MorphableError as e:
        status, error, summary = "error", str(e), {}
    except Exception as e:  # one bad item must not stop the batch; the record says what happened
        status, error, summary = "error", f"{type(e).__name__}: {e}", {}
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return {"id": item.id, "status": status, "error": error, "images": item.images,
            "runtime_ms": round(1000 * (time.perf_counter() - start), 2), **summary}


def _executor(workers: int, scheduler: str | None):
    """A concurrent.futures-like executor: a process pool, or a Dask client."""
    if scheduler:
        from dask.distributed import Client, LocalCluster

        if scheduler == "local":
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None)
            return Client(cluster), cluster
        try:
            return Client(scheduler, timeout="10s"), None
        except (OSError, TimeoutError) as e:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({e})") from None
    if workers <= 1:
        return None, None
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(max_workers=workers, initializer=one_thread_per_worker), None


def one_thread_per_worker() -> None:
    """Initializer of pool workers: as many workers as cores, so each runs its numeric
    libraries on one thread (BLAS, OpenMP, torch); their default thread pools, a thread per
    core in every worker, would oversubscribe the cores and spin against each other. Dask's
    nanny starts its workers with the same limits (``distributed.nanny.pre-spawn-environ``)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"              # for libraries the worker loads later
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)


def run_batch(items, out_dir, work, options: dict | None = None, workers: int = 1,
              scheduler: str | None = None, progress: bool = True) -> dict:
    """Run ``work`` over ``items``, skipping those already in ``OUT/results.jsonl``.

    Parameters
    ----------
    items : list of BatchItem
    out_dir : path
    work : callable(item, folder, options) -> dict
        Writes the item's outputs into ``folder`` and returns a JSON-ready summary; must be
        importable (a module-level function) for process pools and Dask.
    workers : int
        Local processes (1 = in this process), or Dask workers with ``scheduler="local"``.
    scheduler : None, "local" or "tcp://host:port"

    Returns
    -------
    dict with counts: ``{"done", "skipped", "ok", "error"}``.
    """
    from tqdm import tqdm

    out = Path(out_dir)
    done = read_results(out)
    todo = [it for it in items if it.id not in done]
    counts = {"done": 0, "skipped": len(items) - len(todo), "ok": 0, "error": 0}
    options = options or {}
    results = out / RESULTS
    # connect first: an unreachable scheduler fails before anything is written
    executor, cluster = _executor(workers, scheduler) if todo else (None, None)
    try:
        (out / "items").mkdir(parents=True, exist_ok=True)
    except OSError as e:
        if cluster is not None:
            cluster.close()
        raise InputError(f"{out}: cannot create the output folder ({e.strerror or e})") from None
    for stale in (out / "items").glob(".*"):
        # temporary folders of a killed run: their items are not in the log and run again
        shutil.rmtree(stale, ignore_errors=True)
    bar = tqdm(total=len(todo), disable=not progress, desc="fit-batch", unit="item")

    def record(rec):
        _append(results, rec)
        counts["done"] += 1
        counts[rec["status"]] += 1
        if rec["status"] == "error":
            log.warning("%s: %s", rec["id"], rec["error"])
        bar.update(1)

    try:
        if executor is None:
            for it in todo:
                record(_run_item(it, str(out), work, options))
        elif scheduler:
            from dask.distributed import as_completed

            futures = [executor.submit(_run_item, it, str(out), work, options, pure=False)
                       for it in todo]
            for fut in as_completed(futures):
                record(fut.result())
        else:
            from concurrent.futures import as_completed

            futures = [executor.submit(_run_item, it, str(out), work, options) for it in todo]
            for fut in as_completed(futures):
                record(fut.result())
    finally:
        bar.close()
        if executor is not None:
            executor.close() if scheduler else executor.shutdown(cancel_futures=True)
        if cluster is not None:
            cluster.close()
    return counts
