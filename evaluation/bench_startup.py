"""What one photo costs from a cold start: the landmark network on torch and on onnxruntime,
and ``morphable fit`` of one photo, side by side in one run.

- ``network``: per backend, in a fresh process each: seconds to import and load the network
  (``NetworkDetector(backend=...)``), median ms per face on one thread (the default options:
  one pass, crop also read mirrored; the framing of the dataset's 68-point box; the photo
  decoded first, not timed), the process's peak RSS; then how far onnxruntime's readings lie
  from torch's on the same faces (largest ``|Δ|`` of the 546 points px, of σ relative, of the face
  probability) and each one's NME (AFLW2000-3D, research use only: the first ``--n`` photos);
  ``--fp16`` adds the graph exported with float16 weights (needs torch's exporter);
- ``fit``: ``python -m morphable.cli fit PHOTO --out-mesh X.obj`` wall seconds and peak RSS
  (median of ``--repeat`` runs, the cases interleaved): the default detector (fused, the
  network on onnxruntime), the same with the network on torch (the weights without their
  exported graph beside them), and ``--landmarks`` given; with ``--baseline REV`` also the
  default detector and ``--landmarks`` at commit REV (its tree unpacked by ``git archive``);
  one unmeasured run of each case first; ratios to the first;
- ``--profile``: where a default-detector fit's time goes (cProfile, cumulative seconds of
  the stages; nested stages count in their callers too).

    python -m evaluation.bench_startup --n 20 --repeat 5 --profile --fp16 --baseline d130b64
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from morphable.errors import one_line_errors

__all__ = ["main", "run_measured", "network_worker", "STAGES"]

REPO = Path(__file__).resolve().parents[1]
PHOTO = REPO.parent / "shared" / "data" / "images" / "image_0010.png"
STAGES = (
    ("whole command", "morphable/cli/__init__.py", "main"),
    ("detection (both detectors, their loading included)", "morphable/detection/__init__.py", "detect"),
    ("load the network (its runtime's import included)", "neural/landmarks/runtime.py", "load"),
    ("run the network (crops, both readings, back to px)", "neural/landmarks/detector.py", "run"),
    ("import mediapipe's two solutions", "morphable/detection/facemesh.py", "_solutions"),
    ("open the face-mesh graphs (their import included)", "morphable/detection/facemesh.py", "_opened"),
    ("face mesh and face detector on the photo", "morphable/detection/facemesh.py", "_process"),
    ("load the model", "morphable/cli/common.py", "model_from"),
    ("fit the landmarks", "morphable/fitting/landmark_fit.py", "fit_landmarks"),
    ("write the mesh and report", "morphable/fitting/files.py", "write_fit"),
)
"""(stage, file, function) of ``--profile``."""


def run_measured(cmd, env=None, cwd=REPO) -> tuple[float, float]:
    """Run ``cmd`` -> (wall s, peak RSS MB) of that process alone (its peak, or this process's
    where larger: Linux hands a child its parent's peak; this one stays small); RuntimeError
    with its last line of stderr when it fails."""
    with tempfile.TemporaryFile() as err:
        t = time.perf_counter()
        p = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t
        p.returncode = os.waitstatus_to_exitcode(status)
        if p.returncode:
            err.seek(0)
            last = (err.read().decode(errors="replace").strip().splitlines() or [""])[-1]
            raise RuntimeError(f"{' '.join(map(str, cmd))} (in {cwd}): exit {p.returncode}: {last}")
    return wall, usage.ru_maxrss / 1024


def network_worker(backend: str, n: int, out: str, weights=None) -> None:
    """In its own process: the network of ``weights`` (None: the detector's) on ``backend`` over
    the first ``n`` AFLW2000-3D photos -> ``out`` (npz): load seconds, ms per face, points, σ,
    probability, NME, peak RSS."""
    t = time.perf_counter()
    from neural.landmarks.detector import NetworkDetector

    det = NetworkDetector(weights, backend=backend)
    load_s = time.perf_counter() - t
    if backend == "torch":
        import torch

        torch.set_num_threads(1)
    from morphable.detection.images import read_image

    from .bench_alignment import box_size, data_root, dataset_boxes, load_aflw2000, nme

    d = load_aflw2000(data_root(), n)
    boxes = dataset_boxes(d["gt"])
    pts, sig, prob, ibug, ms = [], [], [], [], []
    for i, path in enumerate(d["paths"]):
        img = read_image(path)
        t = time.perf_counter()
        found = det.detect(img, box=boxes[i])
        ms.append((time.perf_counter() - t) * 1e3)
        pts.append(found.points), sig.append(found.sigma_px), prob.append(found.score), ibug.append(found.ibug68)
    err = nme(np.array(ibug), d["gt"], box_size(d["gt"]))
    np.savez(out, load_s=load_s, ms=ms, points=pts, sigma=sig, prob=prob, nme=err,
             rss_mb=_peak_rss_mb(),
             torch_loaded="torch" in sys.modules)


def _peak_rss_mb() -> float:
    """This process's peak resident memory, MB (Linux: VmHWM, its own since exec)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _network(n: int, tmp: Path, fp16: bool) -> None:
    cases = [("torch", "torch", None), ("onnxruntime", "onnxruntime", None)]
    if fp16:
        from neural.landmarks.detector import weights_path

        (tmp / "fp16").mkdir()
        half = shutil.copy(weights_path(), tmp / "fp16" / "landmarks.pt")
        # in its own process: this one stays small, as the processes it measures inherit its
        # peak RSS as their own starting figure (Linux keeps it across fork and exec)
        subprocess.run([sys.executable, "-m", "neural.landmarks.export", "--fp16", "--weights", half],
                       check=True, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        cases.append(("onnxruntime, float16 weights", "onnxruntime", half))
    res = {}
    for i, (name, backend, weights) in enumerate(cases):
        out = tmp / f"network{i}.npz"
        subprocess.run([sys.executable, "-m", "evaluation.bench_startup", "--worker", backend, "--n", str(n),
                        "--out", str(out)] + (["--weights", str(weights)] if weights else []), check=True, cwd=REPO)
        res[name] = dict(np.load(out))
    print(f"The landmark network, {n} AFLW2000-3D faces (research use only), one thread\n\n"
          "| backend | import + load s | median ms per face | peak RSS MB | NME % | torch imported |\n"
          "|---|---|---|---|---|---|")
    for name, r in res.items():
        print(f"| {name} | {float(r['load_s']):.2f} | {np.median(r['ms']):.1f} | {float(r['rss_mb']):.0f} | "
              f"{np.nanmean(r['nme']):.3f} | {'yes' if r['torch_loaded'] else 'no'} |")
    a = res["torch"]
    for name, b in list(res.items())[1:]:
        print(f"\n{name} / torch: load {float(b['load_s']) / float(a['load_s']):.2f}, ms per face "
              f"{np.median(b['ms']) / np.median(a['ms']):.2f}; {name} - torch, largest |difference| "
              f"(mean): points {np.abs(a['points'] - b['points']).max():.1e} "
              f"({np.abs(a['points'] - b['points']).mean():.1e}) px, "
              f"σ {np.abs(a['sigma'] / b['sigma'] - 1).max():.1e} (relative), "
              f"face probability {np.abs(a['prob'] - b['prob']).max():.1e}")
    print()


def _fit(repeat: int, tmp: Path, baseline=None) -> None:
    from neural.landmarks.detector import WEIGHTS_ENV, weights_path

    plain = tmp / "torch_only"
    plain.mkdir()
    shutil.copy(weights_path(), plain / "landmarks.pt")   # no exported graph beside it: torch
    env = {k: v for k, v in os.environ.items() if k != WEIGHTS_ENV}
    fit = [sys.executable, "-m", "morphable.cli", "fit", str(PHOTO), "--out-mesh", str(tmp / "fit.obj")]
    landmarks = fit + ["--landmarks", str(PHOTO.with_suffix(".pts"))]
    cases = {"default detector (network on onnxruntime)": (fit, env, REPO),
             "default detector, network on torch": (fit, {**env, WEIGHTS_ENV: str(plain / "landmarks.pt")}, REPO),
             "--landmarks given": (landmarks, env, REPO)}
    if baseline:
        tree = tmp / "baseline"
        tree.mkdir()
        # piped, not held here: this process's peak RSS is the floor of the children's figures
        git = subprocess.Popen(["git", "archive", baseline], cwd=REPO, stdout=subprocess.PIPE)
        subprocess.run(["tar", "-x", "-C", str(tree)], stdin=git.stdout, check=True)
        git.stdout.close()
        if git.wait():
            raise RuntimeError(f"git archive {baseline}: exit {git.returncode}")
        # run in the baseline's tree, its packages first on the path (entry points: the
        # environment's), the models where this tree finds them
        from morphable.io.registry import search_path

        old = {**env, "PYTHONPATH": os.pathsep.join([str(tree), env.get("PYTHONPATH", "")]),
               "MORPHABLE_DATA": os.pathsep.join(map(str, search_path()))}
        cases[f"{baseline}: default detector"] = (fit, old, tree)
        cases[f"{baseline}: --landmarks given"] = (landmarks, old, tree)
    runs = {name: [] for name in cases}
    for cmd, e, cwd in cases.values():          # compiles each tree's bytecode, fills caches
        run_measured(cmd, e, cwd)
    for _ in range(repeat):
        for name, (cmd, e, cwd) in cases.items():
            runs[name].append(run_measured(cmd, e, cwd))
    base = np.median(runs[next(iter(cases))], axis=0)
    print(f"morphable fit {PHOTO.name} --out-mesh X.obj, median of {repeat} (peak RSS: at least "
          f"this process's, {_peak_rss_mb():.0f} MB, which Linux hands its children)\n\n"
          "| case | wall s | peak RSS MB | wall / default | RSS / default |\n|---|---|---|---|---|")
    for name, r in runs.items():
        wall, rss = np.median(r, axis=0)
        print(f"| {name} | {wall:.2f} | {rss:.0f} | {wall / base[0]:.2f} | {rss / base[1]:.2f} |")
    print()


def _profile(tmp: Path) -> None:
    import pstats

    prof = tmp / "fit.prof"
    subprocess.run([sys.executable, "-m", "cProfile", "-o", str(prof), "-m", "morphable.cli", "fit",
                    str(PHOTO), "--out-mesh", str(tmp / "fit.obj")], check=True, cwd=REPO,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    stats = pstats.Stats(str(prof)).stats
    print("Where a default-detector fit's time goes (cProfile; cumulative s, nested stages "
          "counted in their callers too)\n\n| stage | s |\n|---|---|")
    for stage, file, func in STAGES:
        s = sum(v[3] for (f, _, fn), v in stats.items() if f.endswith(file) and fn == func)
        print(f"| {stage} | {s:.2f} |")
    print()


@one_line_errors("python -m evaluation.bench_startup")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=20, help="AFLW2000-3D photos for the network's figures")
    p.add_argument("--repeat", type=int, default=3, help="runs of each fit case")
    p.add_argument("--profile", action="store_true", help="also where a fit's time goes")
    p.add_argument("--fp16", action="store_true", help="also the graph with float16 weights")
    p.add_argument("--baseline", help="also fit at this commit (e.g. the one before a change)")
    p.add_argument("--worker", choices=("torch", "onnxruntime"), help=argparse.SUPPRESS)
    p.add_argument("--out", help=argparse.SUPPRESS)
    p.add_argument("--weights", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.worker:
        network_worker(a.worker, a.n, a.out, a.weights)
        return 0
    print(json.dumps({"python": sys.version.split()[0], "cpus": os.cpu_count(),
                      "load average": [round(x, 1) for x in os.getloadavg()]}) + "\n")
    with tempfile.TemporaryDirectory() as tmp:
        _network(a.n, Path(tmp), a.fp16)
        _fit(a.repeat, Path(tmp), a.baseline)
        if a.profile:
            _profile(Path(tmp))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
