"""Landmark fitting benchmark: morphable's ``fit_landmarks`` against eos' ``fit_shape_and_pose``.

Synthetic ground truth with the Surrey Face Model: random identities (alpha ~ N(0, 1)),
random blendshape expressions, poses with yaw in [-80, 80], pitch and roll in [-30, 30]
degrees, a scaled orthographic camera on a 512 px image, landmark noise sigma in {0, 1, 3} px.
Jaw landmarks are placed as a detector would (``morphable.fitting.simulate_landmarks``):
along the model's jaw line (between its contour vertices, not on them), and where that line
is self-occluded (back-facing) marched along a horizontal line of vertices to the cheek's
silhouette (3DDFA-style landmark marching, with the true mesh's normals).

Both tools get the same landmarks; their meshes are compared with the ground truth after a
similarity alignment over all vertices. Landmark RMSE is computed the same way for both
(fixed landmarks to their vertices, jaw points to the nearest point of the projected jaw line).

Run::

    python -m evaluation.bench_fitting --n 300 --report reports/bench_fitting.json

It also sweeps our iteration count and number of identity modes
(``fitting_error_vs_runtime.json`` and ``.png`` next to the report) and fits ``image_0010``
with both tools. Times are wall and CPU milliseconds.

**Partial landmarks and load** (``report["load"]``): the common case of the fitter's users,
run with ``--load N`` busy processes beside the benchmark (each spins one core for the whole
measurement and is stopped at its end) and with ``--landmarks 68`` (the jaw's 17 points
slide along the outline), ``inner51`` (the 17 jaw points missing as NaN: 51-point
annotations, detectors that drop the jaw) or ``facemesh478`` (the face mesh's 478 points,
placed by the model's ``facemesh478`` sidecar, the oval sliding; eos fits the same faces'
68 points). Faces with ``|yaw|`` <= 45, pitch and roll <= 20
degrees, 1 px noise on 512 px; per setting the median wall ms per fit and the mean 3D error
of ours and eos side by side, fit-batch images/s with 1 and 2 local workers, and two other
paths users run in parallel: open3d ray casting of a 512 px visibility map (with Embree's
default threads and with one) and 10 torch steps of the classical refinement. Nothing here sets
thread counts through the environment: the library limits BLAS itself
(:mod:`morphable.threads`), and what a user would see is what is measured::

    python -m evaluation.bench_fitting --n 100 --sweep-n 0 --no-noise-table \
        --landmarks 68 inner51 --load 0 1 2 --report reports/bench_load.json
"""
from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from morphable import InputError, load_model
from morphable.camera import Camera, euler_to_matrix
from morphable.cli.common import landmark_std_arg
from morphable.fitting import fit_landmarks, landmark_bank, simulate_landmarks
from morphable.fitting.correspondences import (Correspondences, across_outline, outline_points,
                                               slide_contours)
from morphable.fitting.schemes import load_scheme
from morphable.io.atomic import write_json
from morphable.ibug68 import JAW
from morphable.logs import add_verbosity_arguments, configure, verbosity
from morphable.metrics import umeyama

from .peers import EosFitter, eos_projection

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
IMAGE = 512
NOISE = (0.0, 1.0, 3.0)
YAW_BINS = (0, 20, 40, 60, 80.001)
FAIL_MM = 10.0


# --- ground truth -------------------------------------------------------------------------
def similarity_error(fitted, truth):
    """Mean per-vertex distance (mm) after the best similarity transform fitted -> truth
    (:func:`morphable.metrics.umeyama`)."""
    scale, R, t = umeyama(fitted, truth)
    return float(np.linalg.norm(scale * fitted @ R.T + t - truth, axis=1).mean())


def make_sample(model, rng, max_yaw: float = 80.0, max_tilt: float = 30.0):
    """One synthetic face: ground-truth mesh, pose (``|yaw|`` <= ``max_yaw``, ``|pitch|``,
    ``|roll|`` <= ``max_tilt`` degrees), detector-like landmarks (68, 2)
    (:func:`morphable.fitting.simulate_landmarks`)."""
    alpha = rng.standard_normal(model.n_identity)
    beta = rng.uniform(0, 0.7, model.n_expression) * (rng.uniform(size=model.n_expression) < 0.4)
    yaw = rng.uniform(-max_yaw, max_yaw)
    pitch, roll = rng.uniform(-max_tilt, max_tilt, 2)
    verts = model.vertices(alpha, beta)
    cam = Camera(kind="affine", rotation=euler_to_matrix(yaw, pitch, roll),
                 translation=np.r_[rng.uniform(-10, 10, 2), -600.0], scale=rng.uniform(1.3, 1.9),
                 image_size=(IMAGE, IMAGE))
    return {"verts": verts, "alpha": alpha, "beta": beta, "yaw": yaw, "pitch": pitch,
            "roll": roll, "camera": cam, "landmarks": simulate_landmarks(model, cam, vertices=verts)}


# --- eos ----------------------------------------------------------------------------------
def eos_fit(fitter, landmarks, image_size):
    """eos' fit of (68, 2) px landmarks: vertices (V, 3) mm, its projection and rotation."""
    verts, pose = fitter.fit_with_pose(landmarks, image_size)
    rotation, project = eos_projection(pose, image_size)
    return verts, project, rotation


def landmark_rmse(model, rotation, project, verts, landmarks):
    """RMS px over all landmarks and over the inner ones (iBUG 18-68), the same way for every
    tool: fixed landmarks to their projected vertices, jaw points across the face's projected
    outline (the rules of ``morphable.fitting.correspondences``)."""
    bank = landmark_bank(model)
    given = np.isfinite(landmarks).all(1)
    y = np.where(given[:, None], landmarks, 0.0)[None]
    corr = Correspondences.fixed(bank, 1)
    uv_rows = project(verts[bank.vertex_ids])
    outline = a, b, w = outline_points(bank, np.asarray(rotation, dtype=np.float64)[None, 2])
    projected = (1 - w[..., None]) * uv_rows[a] + w[..., None] * uv_rows[b]
    targets, tangents = (x[0] for x in slide_contours(bank, corr, outline, projected, y, given[None]))
    a, b, w = corr.a[0], corr.b[0], corr.w[0]
    ok = given & (a >= 0)
    uv = (1 - w[:, None]) * uv_rows[np.maximum(a, 0)] + w[:, None] * uv_rows[np.maximum(b, 0)]
    d2 = (across_outline(uv - targets, tangents) ** 2).sum(1)
    inner = ok & (np.arange(68) >= 17)
    return float(np.sqrt(d2[ok].mean())), float(np.sqrt(d2[inner].mean()))


# --- runs ---------------------------------------------------------------------------------
def _summary(recs):
    e = np.asarray([r["err_mm"] for r in recs], dtype=np.float64)
    fails = int((~np.isfinite(e) | (e > FAIL_MM)).sum())
    ok = e[np.isfinite(e)]
    ms = [r["ms"] for r in recs if np.isfinite(r["ms"])]
    cpu = [r["cpu_ms"] for r in recs if np.isfinite(r.get("cpu_ms", np.nan))]
    return {"n": len(e), "mean_mm": float(ok.mean()) if ok.size else None,
            "median_mm": float(np.median(ok)) if ok.size else None,
            "landmark_rmse_px": float(np.nanmean([r["rmse"] for r in recs])),
            "inner_rmse_px": float(np.nanmean([r["inner"] for r in recs])),
            "ms_per_fit_median": float(np.median(ms)) if ms else None,
            "cpu_ms_per_fit_median": float(np.median(cpu)) if cpu else None,
            "failures": fails}


def _record(model, verts, rotation, project, truth, landmarks, ms, cpu_ms):
    rmse, inner = landmark_rmse(model, rotation, project, verts, landmarks)
    return {"err_mm": similarity_error(verts, truth), "rmse": rmse, "inner": inner, "ms": ms,
            "cpu_ms": cpu_ms}


_FAILED = {"err_mm": np.inf, "rmse": np.nan, "inner": np.nan, "ms": np.nan, "cpu_ms": np.nan}


class _Clock:
    """Wall and CPU milliseconds of a block (CPU time is robust to other processes' load)."""

    def __enter__(self):
        self.t, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.ms = (time.perf_counter() - self.t) * 1e3
        self.cpu_ms = (time.process_time() - self.c) * 1e3


def run(n, seed=0, sweep_n=100, out=Path("reports/bench_fitting.json"), eos_on=True, **fit_kw):
    """The noise-level table, image_0010 and the sweep: the report (a dict); the sweep writes
    its JSON and PNG next to ``out``."""
    model = load_model("sfm")
    rng = np.random.default_rng(seed)
    samples = [make_sample(model, rng) for _ in range(n)]
    eos_fitter = EosFitter() if eos_on else None
    noise_rng = np.random.default_rng(seed + 1)
    fit_landmarks(model, samples[0]["landmarks"], (IMAGE, IMAGE), **fit_kw)     # warm caches
    table = {}
    for sigma in NOISE:
        lms = np.stack([s["landmarks"] for s in samples])
        lms = lms + sigma * noise_rng.standard_normal(lms.shape)
        per = {"ours": [], "eos": []}
        for i, s in enumerate(samples):
            try:
                with _Clock() as clock:
                    res = fit_landmarks(model, lms[i], (IMAGE, IMAGE), **fit_kw)
                cam = res.cameras[0]
                per["ours"].append(_record(model, res.vertices(0), cam.rotation, cam.project,
                                           s["verts"], lms[i], clock.ms, clock.cpu_ms))
            except Exception as e:  # a failure counts, the benchmark goes on
                per["ours"].append(dict(_FAILED, error=str(e)))
            if eos_fitter is not None:
                try:
                    with _Clock() as clock:
                        v, proj, rot = eos_fit(eos_fitter, lms[i], (IMAGE, IMAGE))
                    per["eos"].append(_record(model, v, rot, proj, s["verts"], lms[i], clock.ms,
                                              clock.cpu_ms))
                except Exception as e:
                    per["eos"].append(dict(_FAILED, error=str(e)))
        # batch mode: all images of this noise level in one vectorised call
        clocks = []
        for _ in range(3):          # one call is one sample: the median of three
            with _Clock() as clock:
                bres = fit_landmarks(model, lms, (IMAGE, IMAGE), shared_identity=False, **fit_kw)
            clocks.append(clock)
        batch_ms = float(np.median([c.ms for c in clocks])) / n
        batch_cpu = float(np.median([c.cpu_ms for c in clocks])) / n
        per["ours_batch"] = [
            _record(model, bres.vertices(i), bres.cameras[i].rotation, bres.cameras[i].project,
                    s["verts"], lms[i], batch_ms, batch_cpu) for i, s in enumerate(samples)]
        level = {}
        for tool, recs in per.items():
            if not recs:
                continue
            level[tool] = _summary(recs)
            level[tool]["by_abs_yaw"] = {}
            for lo, hi in zip(YAW_BINS[:-1], YAW_BINS[1:]):
                e = np.asarray([r["err_mm"] for r, s in zip(recs, samples) if lo <= abs(s["yaw"]) < hi])
                level[tool]["by_abs_yaw"][f"{lo:.0f}-{hi:.0f}"] = {
                    "n": len(e), "mean_mm": float(e[np.isfinite(e)].mean()) if len(e) else None}
        level["ours_batch"]["ms_per_image"] = batch_ms
        level["ours_batch"]["cpu_ms_per_image"] = batch_cpu
        table[f"sigma_{sigma:g}"] = level
        _print_level(sigma, level)
    report = {"n": n, "seed": seed, "image_px": IMAGE, "fit_kwargs": {k: str(v) for k, v in fit_kw.items()},
              "table": table, "image_0010": image_0010(model, eos_fitter, **fit_kw)}
    if sweep_n:
        report["sweep"] = sweep(model, samples[:sweep_n], eos_fitter, out.parent, seed)
    return report


def _print_level(sigma, level):
    print(f"\nnoise sigma = {sigma:g} px   (3D error: mean over all vertices after similarity "
          "alignment; ms: median wall and CPU time per fit, batch: per image)")
    print(f"{'tool':<11}{'mean mm':>8}{'median':>8}{'lmk px':>8}{'inner px':>9}{'ms/fit':>8}{'cpu ms':>8}{'fails':>6} "
          + "".join(f"{'|yaw| ' + k:>14}" for k in level["ours"]["by_abs_yaw"]))
    for tool, s in level.items():
        bins = "".join(f"{v['mean_mm']:>14.3f}" if v["mean_mm"] is not None else f"{'-':>14}"
                       for v in s.get("by_abs_yaw", {}).values())
        print(f"{tool:<11}{s['mean_mm']:>8.3f}{s['median_mm']:>8.3f}{s['landmark_rmse_px']:>8.2f}"
              f"{s['inner_rmse_px']:>9.2f}{s['ms_per_fit_median']:>8.2f}{s['cpu_ms_per_fit_median']:>8.2f}"
              f"{s['failures']:>6} {bins}")


def image_0010(model, eos_fitter, **fit_kw):
    """Both tools on the real image: landmark RMSE in px (same definition for both)."""
    from morphable.io.landmark_files import read_pts

    pts = read_pts(DATA / "images" / "image_0010.pts")
    size = (1280, 1024)
    fit_landmarks(model, pts, size, **fit_kw)
    clocks = []
    for _ in range(5):
        with _Clock() as clock:
            res = fit_landmarks(model, pts, size, **fit_kw)
        clocks.append(clock)
    cam = res.cameras[0]
    rmse, inner = landmark_rmse(model, cam.rotation, cam.project, res.vertices(0), pts)
    out = {"ours": {"landmark_rmse_px": rmse, "inner_rmse_px": inner,
                    "ms": float(np.median([c.ms for c in clocks])),
                    "cpu_ms": float(np.median([c.cpu_ms for c in clocks])),
                    "fit_reported_rmse_px": float(res.landmark_rmse_px[0]),
                    "yaw_pitch_roll_deg": res.euler_deg[0].tolist()}}
    if eos_fitter is not None:
        clocks = []
        for _ in range(5):
            with _Clock() as clock:
                v, proj, rot = eos_fit(eos_fitter, pts, size)
            clocks.append(clock)
        rmse, inner = landmark_rmse(model, rot, proj, v, pts)
        out["eos"] = {"landmark_rmse_px": rmse, "inner_rmse_px": inner,
                      "ms": float(np.median([c.ms for c in clocks])),
                      "cpu_ms": float(np.median([c.cpu_ms for c in clocks]))}
    print("\nimage_0010 landmark RMSE px (all / inner 51): " + ", ".join(
        f"{k} {v['landmark_rmse_px']:.3f} / {v['inner_rmse_px']:.3f} ({v['ms']:.1f} ms, "
        f"CPU {v['cpu_ms']:.1f} ms)" for k, v in out.items()))
    return out


def sweep(model, samples, eos_fitter, folder, seed, sigma=1.0):
    """3D error against time per fit for iteration counts and identity mode counts."""
    rng = np.random.default_rng(seed + 2)
    lms = np.stack([s["landmarks"] for s in samples])
    lms = lms + sigma * rng.standard_normal(lms.shape)
    curves = {}
    for k in (10, 20, 40, model.n_identity):
        pts = []
        for it in (0, 1, 2, 4, 8):
            errs, times, cpu = [], [], []
            for i, s in enumerate(samples):
                with _Clock() as clock:
                    res = fit_landmarks(model, lms[i], (IMAGE, IMAGE), n_iterations=it, n_identity=k)
                times.append(clock.ms)
                cpu.append(clock.cpu_ms)
                errs.append(similarity_error(res.vertices(0), s["verts"]))
            pts.append({"n_iterations": it, "ms": float(np.median(cpu)),
                        "wall_ms": float(np.median(times)), "mean_mm": float(np.mean(errs))})
        curves[f"n_identity={k}"] = pts
    # "ms" is CPU time: on a shared machine wall time mostly measures the other processes
    result = {"sigma_px": sigma, "n": len(samples), "curves": curves,
              "time": "ms: median CPU (process) time per fit; wall_ms: median wall time"}
    if eos_fitter is not None:
        errs, times, cpu = [], [], []
        for i, s in enumerate(samples):
            with _Clock() as clock:
                v, _, _ = eos_fit(eos_fitter, lms[i], (IMAGE, IMAGE))
            times.append(clock.ms)
            cpu.append(clock.cpu_ms)
            errs.append(similarity_error(v, s["verts"]))
        result["eos"] = {"ms": float(np.median(cpu)), "wall_ms": float(np.median(times)),
                         "mean_mm": float(np.mean(errs))}
    # not error_vs_runtime.*: evaluation.report writes those (the README's figure)
    write_json(folder / "fitting_error_vs_runtime.json", result)
    from evaluation.plots import fitting_sweep

    fitting_sweep(result, folder / "fitting_error_vs_runtime.png")
    return result


# --- partial landmarks and load -----------------------------------------------------------
LANDMARK_SETS = ("68", "inner51", "facemesh478")


def landmark_set(sample, name: str) -> np.ndarray:
    """A sample's points of a landmark set, px: "68" all (68, 2), "inner51" without the 17
    jaw points (NaN), "facemesh478" the face mesh's (478, 2) (``sample["facemesh478"]``,
    :func:`load_table`)."""
    if name == "facemesh478":
        return sample["facemesh478"]
    out = np.array(sample["landmarks"], dtype=np.float64)
    if name == "inner51":
        out[JAW] = np.nan
    return out


@contextlib.contextmanager
def busy_processes(n: int):
    """``n`` processes beside this one, each spinning a core until the block ends."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        time.sleep(0.2 * bool(n))           # let them start spinning
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


def _fit_rows(model, eos_fitter, samples, names):
    """Per landmark set: ours and eos, median wall / CPU ms per fit and mean 3D error (mm)."""
    rows = {}
    for name in names:
        per = {"ours": [], "eos": []}
        for s in samples:
            lms = landmark_set(s, name)
            with _Clock() as clock:
                res = fit_landmarks(model, lms, (IMAGE, IMAGE))
            per["ours"].append((clock.ms, clock.cpu_ms, similarity_error(res.vertices(0), s["verts"])))
            if eos_fitter is not None:
                lms = landmark_set(s, "68" if name == "facemesh478" else name)
                with _Clock() as clock:
                    verts, _, _ = eos_fit(eos_fitter, lms, (IMAGE, IMAGE))
                per["eos"].append((clock.ms, clock.cpu_ms, similarity_error(verts, s["verts"])))
        rows[name] = {tool: {"ms_per_fit_median": float(np.median([r[0] for r in recs])),
                             "cpu_ms_per_fit_median": float(np.median([r[1] for r in recs])),
                             "mean_mm": float(np.mean([r[2] for r in recs])), "n": len(recs)}
                      for tool, recs in per.items() if recs}
        if "eos" in rows[name]:
            rows[name]["ours_over_eos_time"] = (rows[name]["ours"]["ms_per_fit_median"]
                                                / rows[name]["eos"]["ms_per_fit_median"])
    return rows


def _batch_throughput(model, folder, n_items: int = 40) -> dict:
    """fit-batch's engine (local process pool) on synthetic landmark items: images/s."""
    from morphable.batch import read_manifest

    from .bench_batch import make_synthetic_items, run_config

    items = read_manifest(make_synthetic_items(Path(folder) / "items", model, n_items))
    return {f"workers_{w}": run_config(items, Path(folder) / f"out{w}", "local", w,
                                       {"model": "sfm"})["images_per_s"] for w in (1, 2)}


def _other_paths(model, repeats: int = 5) -> dict:
    """Median ms of open3d ray casting (a 512 px visibility map of the mean face), with
    Embree's default threads and with one, and of 10 torch steps of the classical refinement
    as the library runs them (torch on one thread, :func:`morphable.threads.single_torch_thread`)."""
    out = {}
    try:
        from morphable.camera import Camera
        from morphable.logs import import_open3d

        o3d = import_open3d()
        cam = Camera.looking_at_face(image_size=(IMAGE, IMAGE))
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(model.mean.astype(np.float32)),
                            o3d.core.Tensor(model.triangles.astype(np.uint32)))
        origins, directions = cam.rays()
        rays = o3d.core.Tensor(np.concatenate([origins, directions], -1).astype(np.float32))
        for label, nthreads in (("default", 0), ("one", 1)):
            ms = []
            for _ in range(repeats):
                with _Clock() as clock:
                    scene.cast_rays(rays, nthreads=nthreads)
                ms.append(clock.ms)
            out[f"raycast_ms_{label}_threads"] = float(np.median(ms))
    except ImportError:
        pass
    try:
        import torch  # noqa: F401  (the refinement needs it)

        from morphable.io.landmark_files import read_pts
        from morphable.detection import read_image
        from morphable.refinement import refine

        image = read_image(DATA / "images" / "image_0010.png")
        fit = fit_landmarks(model, read_pts(DATA / "images" / "image_0010.pts"),
                            image.shape[1::-1])
        refine(image, fit, "classical", steps=2)          # first-call set-up, not timed
        ms = []
        for _ in range(max(repeats // 2, 1)):
            with _Clock() as clock:
                refine(image, fit, "classical", steps=10)
            ms.append(clock.ms)
        out["refine10_ms"] = float(np.median(ms))
    except ImportError:
        pass
    return out


def load_table(model, eos_fitter, names=LANDMARK_SETS, loads=(0, 1, 2), n: int = 100,
               seed: int = 0, sigma: float = 1.0, batch_items: int = 40) -> dict:
    """The partial-landmark and load benchmark (see the module docstring): per load, per
    landmark set, ours against eos; fit-batch throughput; the other parallel paths."""
    rng = np.random.default_rng(seed + 3)
    samples = [make_sample(model, rng, max_yaw=45.0, max_tilt=20.0) for _ in range(n)]
    dense = load_scheme(model, "facemesh478") if "facemesh478" in names else None
    for s in samples:
        s["landmarks"] = s["landmarks"] + sigma * rng.standard_normal(s["landmarks"].shape)
        if dense is not None:
            p = simulate_landmarks(model, s["camera"], vertices=s["verts"], scheme=dense)
            s["facemesh478"] = p + sigma * rng.standard_normal(p.shape)
    for name in names:                    # warm the caches of every landmark set
        fit_landmarks(model, landmark_set(samples[0], name), (IMAGE, IMAGE))
    table = {}
    for load in loads:
        with busy_processes(load), tempfile.TemporaryDirectory(prefix="bench_load.") as tmp:
            entry = {"fits": _fit_rows(model, eos_fitter, samples, names)}
            if batch_items:
                entry["fit_batch_images_per_s"] = _batch_throughput(model, tmp, batch_items)
            entry["other_paths"] = _other_paths(model)
        table[f"load_{load}"] = entry
        _print_load(load, entry)
    return {"n": n, "sigma_px": sigma, "max_yaw_deg": 45.0, "max_tilt_deg": 20.0,
            "cpus": os.cpu_count(), "table": table}


def _print_load(load, entry):
    print(f"\n--load {load}: median wall ms per fit (CPU ms), mean 3D error mm")
    for name, row in entry["fits"].items():
        cells = [f"{tool} {r['ms_per_fit_median']:.2f} ms ({r['cpu_ms_per_fit_median']:.2f}), "
                 f"{r['mean_mm']:.3f} mm" for tool, r in row.items() if isinstance(r, dict)]
        ratio = f", ours/eos time {row['ours_over_eos_time']:.2f}" if "ours_over_eos_time" in row else ""
        print(f"  {name:8s} " + "; ".join(cells) + ratio)
    if "fit_batch_images_per_s" in entry:
        print("  fit-batch images/s: " + ", ".join(
            f"{k.replace('_', ' ')} {v:.1f}" for k, v in entry["fit_batch_images_per_s"].items()))
    if entry["other_paths"]:
        print("  other paths (ms): " + ", ".join(f"{k} {v:.1f}" for k, v in entry["other_paths"].items()))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=300, help="synthetic faces per noise level")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sweep-n", type=int, default=100, help="faces in the error-vs-runtime sweep (0 = skip)")
    p.add_argument("--no-eos", action="store_true", help="run ours only")
    p.add_argument("--report", type=Path, default=Path("reports/bench_fitting.json"))
    p.add_argument("--landmark-std", type=landmark_std_arg, default=1.0, metavar="PX|auto",
                   help="ours: landmark_std_px (default 1; auto estimates it per fit)")
    p.add_argument("--no-noise-table", action="store_true",
                   help="skip the noise-level table and image_0010 (the load table only)")
    p.add_argument("--landmarks", nargs="+", choices=LANDMARK_SETS, default=[],
                   help="load table: landmark sets, 68 (with the sliding jaw), inner51 "
                        "(the jaw missing) and/or facemesh478 (the face mesh's points)")
    p.add_argument("--load", nargs="+", type=int, default=[0], metavar="N",
                   help="load table: busy processes beside the benchmark (default 0)")
    p.add_argument("--load-n", type=int, default=100, help="faces of the load table")
    add_verbosity_arguments(p)
    a = p.parse_args(argv)
    configure(verbosity(a))
    if any(n < 0 for n in a.load):
        p.error("--load: the number of busy processes must be >= 0")
    if "facemesh478" in a.landmarks:
        try:                              # before any measurement: the sidecar must exist
            load_scheme(load_model("sfm"), "facemesh478")
        except InputError as e:
            print(f"--landmarks facemesh478: {e}", file=sys.stderr)
            raise SystemExit(2) from None
    a.report.parent.mkdir(parents=True, exist_ok=True)
    if a.no_noise_table:
        report = {"n": 0, "seed": a.seed}
    else:
        report = run(a.n, seed=a.seed, sweep_n=a.sweep_n, out=a.report, eos_on=not a.no_eos,
                     landmark_std_px=a.landmark_std)
    if a.landmarks:
        model = load_model("sfm")
        report["load"] = load_table(model, None if a.no_eos else EosFitter(), a.landmarks,
                                    a.load, n=a.load_n, seed=a.seed)
    write_json(a.report, report)
    print(f"\nwrote {a.report}")


if __name__ == "__main__":
    main()
