"""Batch fitting throughput: images per second of ``morphable fit-batch``'s engine with 1 and
2 workers, a local process pool against a Dask ``LocalCluster``.

Two workloads:

- *synthetic landmarks* (no detection): tiny grey PNGs, each with the ``.pts`` of a random
  SFM face in a random pose (``morphable.fitting.simulate_landmarks`` plus 0.5 px noise);
- *images with detection*: the photos of ``shared/data/images`` (dlib HOG detection and the
  68-point predictor, ``landmark_detector="dlib"`` as when the table was measured, then the fit), repeated to the requested count.

Every configuration runs :func:`morphable.batch.run_batch` with the real work function
(:func:`morphable.pipeline.fit_item`: fit, then write ``fit.obj`` and ``fit.json``) into
a fresh output folder; the time includes starting the pool or cluster and each worker's first
model load, as a user of the command would see it (after one warm-up fit in the main
process, which forked pool workers inherit and Dask's spawned workers do not). "1 worker" of the local pool is the
in-process loop that ``fit-batch --workers 1`` uses. Ratios are against that serial run of
the same workload in the same process. Nothing sets thread counts through the environment:
pool workers hold their numeric libraries at one thread themselves
(:func:`morphable.batch.one_thread_per_worker`; Dask's nanny does the same for its workers).

Run::

    python -m evaluation.bench_batch --synthetic 40 --detect 8 --report reports/bench_batch.json
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from morphable.logs import add_verbosity_arguments, configure, verbosity

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
PHOTOS = ("image_0010.png", "takeo.ppm", "einstein.jpg", "breakingbad.jpg")
CONFIGS = (("local", 1), ("local", 2), ("dask", 1), ("dask", 2))


def make_synthetic_items(folder, model, n: int, size=(320, 320), seed: int = 0,
                         noise_px: float = 0.5) -> Path:
    """``n`` grey PNGs (hard links of one file) with the ``.pts`` of a random face each, and
    their truth in ``truth.json``: per item id, ``identity`` (K,) coefficients (std units) and
    ``pose_deg`` [yaw, pitch, roll] degrees.

    Faces: identity ~ N(0, 1), yaw in [-40, 40], pitch in [-15, 15], roll in [-10, 10]
    degrees, Gaussian landmark noise ``noise_px``. Returns ``folder``.
    """
    from PIL import Image

    from morphable.camera import Camera
    from morphable.fitting import simulate_landmarks
    from morphable.io.landmark_files import write_pts

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    blank = folder / ".blank.png"
    Image.new("L", size, 128).save(blank)
    truth = {}
    for i in range(n):
        pose = [rng.uniform(-40, 40), rng.uniform(-15, 15), rng.uniform(-10, 10)]
        identity = rng.normal(size=model.n_identity)
        cam = Camera.looking_at_face(image_size=size, yaw=pose[0], pitch=pose[1], roll=pose[2])
        lms = simulate_landmarks(model, cam, identity=identity)
        lms += rng.normal(scale=noise_px, size=lms.shape)
        # .pts has no missing points: the rows a model does not define (SFM: inner mouth
        # corners) get a finite stand-in, which the fit ignores
        lms = np.where(np.isfinite(lms), lms, lms[48])
        os.link(blank, folder / f"face{i:03d}.png")
        write_pts(folder / f"face{i:03d}.pts", lms)
        truth[f"face{i:03d}"] = {"identity": identity.tolist(), "pose_deg": pose}
    blank.unlink()
    (folder / "truth.json").write_text(json.dumps(truth))
    return folder


def make_photo_items(folder, n: int) -> Path:
    """``n`` links to the shared photos, without landmark files (so they are detected)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        src = DATA / "images" / PHOTOS[i % len(PHOTOS)]
        (folder / f"photo{i:03d}{src.suffix}").symlink_to(src)
    return folder


def run_config(items, out, executor: str, workers: int, options: dict) -> dict:
    from morphable.batch import read_results, run_batch
    from morphable.pipeline import fit_item

    t0, c0 = time.perf_counter(), time.process_time()
    counts = run_batch(items, out, fit_item, options, workers=workers,
                       scheduler="local" if executor == "dask" else None, progress=False)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    recs = read_results(out).values()
    rmse = [r["landmark_rmse_px"] for r in recs if r["status"] == "ok"]
    return {"executor": executor, "workers": workers, "items": len(items), "ok": counts["ok"],
            "error": counts["error"], "wall_s": wall, "main_cpu_s": cpu,
            "images_per_s": len(items) / wall,
            "mean_landmark_rmse_px": float(np.mean(rmse)) if rmse else None}


def markdown(rows) -> str:
    lines = ["| workload | executor | workers | items | failed | wall s | images/s | vs serial |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['workload']} | {'local pool' if r['executor'] == 'local' else 'Dask LocalCluster'}"
                     f" | {r['workers']} | {r['items']} | {r['error']} | {r['wall_s']:.1f} | "
                     f"{r['images_per_s']:.2f} | {r['speedup']:.2f}x |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--synthetic", type=int, default=40, help="synthetic landmark items (0: skip)")
    p.add_argument("--detect", type=int, default=8, help="photos with detection (0: skip)")
    p.add_argument("--report", help="JSON report")
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))

    from morphable import load_model
    from morphable.batch import read_manifest

    model = load_model("sfm")
    work = Path(tempfile.mkdtemp(prefix="bench_batch."))
    # one fit first: the serial baseline should not pay the once-per-process preparation
    # alone (forked pool workers inherit it; Dask's spawned workers pay it, as in real use)
    from morphable.fitting import fit_landmarks
    from morphable.camera import Camera

    fit_landmarks(model, Camera.looking_at_face().project(model.landmark_positions()), (512, 512))
    rows = []
    try:
        workloads = []
        if args.synthetic:
            workloads.append(("synthetic landmarks", make_synthetic_items(work / "synthetic", model, args.synthetic)))
        if args.detect:
            workloads.append(("images with detection", make_photo_items(work / "photos", args.detect)))
        for name, folder in workloads:
            items = read_manifest(folder)
            serial = None
            for executor, workers in CONFIGS:
                out = work / f"out-{folder.name}-{executor}-{workers}"
                r = run_config(items, out, executor, workers,
                               {"model": "sfm", "landmark_detector": "dlib"})
                serial = serial or r["wall_s"]
                r.update(workload=name, speedup=serial / r["wall_s"])
                rows.append(r)
                print(f"{name:22s} {executor:5s} x{workers}: {r['images_per_s']:.2f} images/s "
                      f"({r['ok']} ok, {r['error']} failed, {r['wall_s']:.1f} s)", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    table = markdown(rows)
    print()
    print(table)
    load = os.getloadavg()
    print(f"\n{os.cpu_count()} CPUs, load average {load[0]:.1f} at the end")
    if args.report:
        from morphable.io.atomic import atomic_path

        with atomic_path(args.report) as tmp:
            tmp.write_text(json.dumps({"rows": rows, "markdown": table, "cpus": os.cpu_count(),
                                       "load_average": load}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
