"""GPU recipes: one command that trains a set of networks on a lent GPU within a time budget
and leaves their weights, logs and one JSON summary in an output folder.

``python -m neural.gpu_recipe gar --data gar_data/real128.npz --out OUT --minutes 5
[--inverter-minutes 1] [--device cuda] [--continue] [--side-by-side] [--compile]``
(``make gar-gpu``);
``python -m neural.gpu_recipe landmarks [--synthetic PACK ...] [--annotated PACK]
[--profiled PACK] [--generate N --kit DIR] [--arch small|wide] [--init WEIGHTS | --continue]
--out OUT --minutes 8`` (``make landmark-gpu``: the landmark network,
:mod:`neural.landmarks.train` with its ``gpu`` recipe: ``landmarks_gpu.pt``, its
``validation.jsonl`` as ``validation_landmarks.jsonl``, ``recipe.json``, ``log.txt``).

``--continue`` starts each network from its committed weights (:data:`CONTINUE`), so that
one GPU run continues the last (docs/gpu_runs.md); ``--generate N`` first renders N
synthetic faces on the GPU machine's cores from the kit of :mod:`neural.gpu_travel`.

A recipe is a list of stages; the jobs of a stage run at the same time, each a ``python -m``
command of this package with its own time limit (``--max-minutes``; the runner kills a job
that overruns it by ``GRACE_MINUTES``). The ``gar`` recipe gives each job a stage of its own
by default: side by side (``--side-by-side``) was meant to fill the GPU's idle time between
the small networks' kernel launches, but on the first run (an H200, three GARs together) each
trained at 0.4 s per step of 64, far below the estimate (docs/history.md, "The GPU recipe and
its first run"; docs/gpu_runs.md). While a job runs, its newest weights are
copied into the output folder every ``POLL_SECONDS``, so a run cut off from outside still
leaves the last checkpoint's weights (the trainers write one each minute). Output file names
are flat (``gar_64.pt``, ``inverter_64.pt``, ...) and few, as the device tool returns at most
8 files of 16 MiB.

``recipe.json``: per job its command, wall seconds, exit status, and the trainer's own
``summary.json`` / ``metrics.json`` (steps, images seen, images/s, final losses); the device
and the torch version. ``log.txt``: every job's output.

The ``gar`` recipe trains ``tiny-gpu`` (64 px), ``tiny128-gpu`` (128 px) and ``tiny-gpu``
with lambda_n = 0 (the "w/o norm-cycle" ablation) on one pack, one at a time (with
``--side-by-side`` together, the first run's way; a 128-px pack serves all: the 64-px runs
area-downsample it), then the first two's inverters V; it returns ``gar_64.pt``,
``gar_128.pt``, ``gar_64_no_norm_cycle.pt``, ``inverter_64.pt``, ``inverter_128.pt``,
``recipe.json`` and ``log.txt`` (sample grids are made from the weights afterwards:
``evaluation.gar_quality --grid``). ``--max-steps N`` runs N steps of each job instead (the
CPU test of the recipe).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from morphable.errors import InputError, one_line_errors
from morphable.io.atomic import write_json
from morphable.logs import add_verbosity_arguments, configure, verbosity

__all__ = ["gar_recipe", "landmark_recipe", "run_recipe", "main", "RECIPES", "CONTINUE",
           "POLL_SECONDS", "GRACE_MINUTES"]

POLL_SECONDS = 15
GRACE_MINUTES = 2.0


def _job(name, module, args, minutes, outputs, run_dir):
    """A job: ``python -m module args`` in ``run_dir/name``; ``outputs`` maps a file of
    that folder to its flat name in the output folder."""
    return {"name": name, "module": module, "args": [str(a) for a in args],
            "minutes": float(minutes), "dir": str(Path(run_dir) / name), "outputs": outputs}


def gar_recipe(data, run_dir, minutes: float = 5.0, inverter_minutes: float = 1.0,
               device: str = "cuda", max_steps=None, batch_size=None, overrides=(),
               aux_dir: str = "neural/gar/weights/real", init=None,
               side_by_side: bool = False, compile: bool = False) -> list:
    """The GAR's stages (see the module): tiny-gpu, tiny128-gpu and tiny-gpu with
    lambda_n = 0, then the first two's inverters; one job at a time, or with
    ``side_by_side`` the GARs together and then the inverters together; ``compile``: the
    GARs' ``--compile``. ``init``: dict job
    name -> weights its run starts from (``--init``; default none: from scratch; the
    committed ones: :data:`CONTINUE`). ``max_steps``, ``batch_size`` and ``overrides``
    (``KEY=VALUE`` config fields of every GAR, e.g. smaller widths) shrink it for a test."""
    limit = ["--max-steps", max_steps] if max_steps else []
    limit += ["--batch-size", batch_size] if batch_size else []
    gars = [("gar64", "tiny-gpu", [], "gar_64"), ("gar128", "tiny128-gpu", [], "gar_128"),
            ("gar64_n0", "tiny-gpu", ["lambda_n=0"], "gar_64_no_norm_cycle")]
    stages = [[], []]
    for name, config, extra, stem in gars:
        gdir = Path(run_dir) / name
        start = ["--init", init[name]] if init and init.get(name) else []
        start += ["--compile"] if compile else []
        stages[0].append(_job(name, "neural.gar.train", [
            "--config", config, "--data", data, "--aux-dir", aux_dir, "--set",
            *overrides, *extra, "--out", gdir, "--device", device, "--amp",
            "bf16" if device != "cpu" else "none", "--channels-last", "--steps", 10**6,
            "--max-minutes", minutes, "--checkpoint-minutes", 1, "-q", *start, *limit],
            minutes, {"generator.pt": f"{stem}.pt", "summary.json": f"summary_{stem}.json"},
            run_dir))
        if extra:
            continue
        tag = stem[4:]
        stages[1].append(_job(f"inv{tag}", "neural.gar.train_inverter", [
            "--generator", gdir / "generator.pt", "--data", data, "--out",
            Path(run_dir) / f"inv{tag}", "--device", device, "--batch-size", batch_size or 64,
            "--pool", 2048, "--held-out", 64, "--steps", max_steps or 10**6, "--max-minutes",
            inverter_minutes, "--eval-steps", max_steps or 100, "-q"], inverter_minutes,
            {"inverter.pt": f"inverter_{tag}.pt", "metrics.json": f"summary_inv_{tag}.json"},
            run_dir))
    # one at a time by default: side by side, each small launch-bound job waited through the
    # others' time slices (the first GPU run, docs/neural.md)
    return stages if side_by_side else [[job] for stage in stages for job in stage]


def landmark_recipe(run_dir, synthetic=(), annotated=None, profiled=None, minutes: float = 8.0,
                    device: str = "cuda", max_steps=None, batch_size=None, overrides=(),
                    init=None, arch: str = "small", generate: int = 0, kit=None,
                    generate_px: int = 160, generate_minutes: float = 1.0,
                    workers: int = 16, compile: bool = False) -> list:
    """The landmark network's stages: with ``generate`` (faces), first
    :mod:`neural.faces.build_synthetic` makes that many SFM faces of ``generate_px`` (the
    side of the committed synthetic packs; the trainer resamples its crops from them) on
    ``workers`` processes from ``kit`` (:mod:`neural.gpu_travel`'s; procedural albedo and
    backgrounds), which join ``synthetic`` (packs of that side); then :mod:`neural.landmarks.train`
    ``--recipe gpu --arch arch`` on the packs for ``minutes``, from ``init`` (weights) when
    given, with ``--compile`` when ``compile`` (``max_steps``, ``batch_size``, ``overrides``: a test's)."""
    stages = []
    synthetic = list(synthetic)
    if generate:
        pack = Path(run_dir) / "synthetic_generated"
        stages.append([_job("generate", "neural.faces.build_synthetic", [
            "--out", pack, "--n", generate, "--resolution", generate_px, "--seed", 101,
            "--workers", workers, "--data", kit or "gpu_kit/data", "--textures", 0,
            "--backgrounds", "none", "-q"], generate_minutes, {}, run_dir)])
        synthetic.append(pack)
    packs = (["--synthetic", *synthetic] if synthetic else [])
    packs += ["--annotated", annotated] if annotated else []
    packs += ["--profiled", profiled] if profiled else []
    limit = ["--max-steps", max_steps] if max_steps else []
    limit += ["--batch-size", batch_size] if batch_size else []
    limit += ["--init", init] if init else []
    limit += ["--compile"] if compile else []
    folder = Path(run_dir) / "landmarks"
    return stages + [[_job("landmarks", "neural.landmarks.train", [
        "--recipe", "gpu", "--arch", arch, *packs, "--out", folder, "--device", device,
        "--max-minutes", minutes, "--checkpoint-minutes", 1, "-q", *limit,
        *(["--set", *overrides] if overrides else [])], minutes,
        {"landmarks.pt": "landmarks_gpu.pt", "summary.json": "summary_landmarks.json",
         "validation.jsonl": "validation_landmarks.jsonl"}, run_dir)]]


RECIPES = {"gar": gar_recipe, "landmarks": landmark_recipe}

CONTINUE = {"landmarks": "neural/landmarks/weights/landmarks.pt",
            "gar64": "neural/gar/weights/real/gar_tiny.pt",
            "gar128": "neural/gar/weights/gpu/gar_128.pt"}
"""``--continue``: the committed weights each run starts from (the best 64-px GAR, trained
on the CPU, and the 128-px one of the first GPU run; the landmark network)."""


def _copy_outputs(job, out: Path, seen: dict) -> None:
    """Copy the job's outputs that changed since the last call (by mtime) into ``out``."""
    folder = Path(job["dir"])
    for src, dest in job["outputs"].items():
        path = folder / src
        if not path.is_file():
            continue
        stamp = path.stat().st_mtime_ns
        if seen.get(dest) != stamp:
            tmp = out / f".{dest}.tmp"
            shutil.copyfile(path, tmp)
            os.replace(tmp, out / dest)
            seen[dest] = stamp


def run_recipe(stages: list, out, python: str = sys.executable) -> dict:
    """Run ``stages`` (lists of jobs, stage by stage, a stage's jobs side by side), copying
    outputs into ``out`` as they appear -> the ``recipe.json`` dict (also written)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    report = {"python": python, "jobs": {}, "environment": _environment()}
    seen: dict = {}
    with open(out / "log.txt", "a") as log:
        for stage in stages:
            procs = []
            for job in stage:
                Path(job["dir"]).mkdir(parents=True, exist_ok=True)
                cmd = [python, "-m", job["module"], *job["args"]]
                log.write(f"$ {' '.join(cmd)}\n")
                log.flush()
                env = {**os.environ, "PYTHONUNBUFFERED": "1"}
                procs.append((job, subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT,
                                                     env=env), time.monotonic(), cmd))
            running, last_copy = list(procs), time.monotonic()
            while running:
                time.sleep(1)
                copy = time.monotonic() - last_copy > POLL_SECONDS
                last_copy = time.monotonic() if copy else last_copy
                for job, proc, t0, cmd in list(running):
                    if copy:
                        _copy_outputs(job, out, seen)
                    over = time.monotonic() - t0 > 60 * (job["minutes"] + GRACE_MINUTES)
                    if proc.poll() is None and over:
                        proc.kill()
                        proc.wait()
                        log.write(f"[{job['name']}] killed after {job['minutes']} + "
                                  f"{GRACE_MINUTES} min\n")
                    if proc.poll() is not None:
                        running.remove((job, proc, t0, cmd))
                        _copy_outputs(job, out, seen)
                        entry = {"command": " ".join(cmd), "returncode": proc.returncode,
                                 "wall_seconds": round(time.monotonic() - t0, 1)}
                        for src, dest in job["outputs"].items():
                            if dest.endswith(".json") and (out / dest).is_file():
                                entry[src.replace(".json", "")] = json.loads(
                                    (out / dest).read_text())
                        report["jobs"][job["name"]] = entry
                        log.flush()
                        write_json(out / "recipe.json", report, indent=2)
                        # now in recipe.json: the folder keeps few files even if the run is
                        # cut off later (the device tool returns 8)
                        for dest in job["outputs"].values():
                            if dest.endswith(".json"):
                                (out / dest).unlink(missing_ok=True)
    return report


def _environment() -> dict:
    """torch's version and the CUDA device's name, where there is one."""
    try:
        import torch
    except ImportError:
        return {}
    env = {"torch": torch.__version__, "cuda": torch.cuda.is_available()}
    if torch.cuda.is_available():
        env["device"] = torch.cuda.get_device_name(0)
    return env


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m neural.gpu_recipe",
                                description=__doc__.splitlines()[0])
    p.add_argument("recipe", choices=sorted(RECIPES))
    p.add_argument("--data", help="gar: the training pack (neural.gar.real_faces)")
    p.add_argument("--synthetic", nargs="*", default=[], metavar="PACK",
                   help="landmarks: synthetic packs")
    p.add_argument("--annotated", metavar="PACK", help="landmarks: the annotated pack")
    p.add_argument("--profiled", metavar="PACK", help="landmarks: the profiled pack")
    p.add_argument("--out", required=True, help="output folder (weights, grids, recipe.json)")
    p.add_argument("--runs", default="runs/gpu-recipe",
                   help="working folder of the jobs (checkpoints, full logs)")
    p.add_argument("--minutes", type=float,
                   help="training minutes of each network (gar 5, landmarks 8)")
    p.add_argument("--inverter-minutes", type=float, default=1.0)
    p.add_argument("--device", default="cuda")
    p.add_argument("--max-steps", type=int, help="N steps of each job instead (tests)")
    p.add_argument("--batch-size", type=int, help="every job's batch size (tests)")
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                   help="config fields of every GAR (tests: smaller networks)")
    p.add_argument("--continue", dest="resume_committed", action="store_true",
                   help="start each network from its committed weights (CONTINUE)")
    p.add_argument("--init", metavar="WEIGHTS", help="landmarks: start from these weights")
    p.add_argument("--arch", default="small", help="landmarks: small or wide")
    p.add_argument("--generate", type=int, default=0, metavar="N",
                   help="landmarks: first render N synthetic faces there (needs --kit)")
    p.add_argument("--generate-px", type=int, default=160, help="landmarks: their side")
    p.add_argument("--kit", default="gpu_kit/data", help="landmarks: the data kit of "
                   "neural.gpu_travel kit (the SFM model)")
    p.add_argument("--workers", type=int, default=16, help="landmarks: rendering processes")
    p.add_argument("--compile", action="store_true", help="torch.compile the trained networks")
    p.add_argument("--side-by-side", action="store_true",
                   help="gar: the GARs at the same time (the first run's way), not one by one")
    add_verbosity_arguments(p)
    return p


@one_line_errors("neural.gpu_recipe")
def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure(verbosity(args))
    common = dict(device=args.device, max_steps=args.max_steps, batch_size=args.batch_size,
                  overrides=args.set, compile=args.compile)
    if args.recipe == "gar":
        if args.data is None or not Path(args.data).is_file():
            raise InputError(f"{args.data}: pack not found (build it with `make gar-data`)")
        stages = gar_recipe(args.data, args.runs, minutes=args.minutes or 5.0,
                            inverter_minutes=args.inverter_minutes,
                            init=CONTINUE if args.resume_committed else None,
                            side_by_side=args.side_by_side, **common)
    else:
        packs = [*args.synthetic, args.annotated, args.profiled]
        missing = next((p for p in packs if p is not None and not Path(p).exists()), None)
        if missing is not None or not (any(packs) or args.generate):
            raise InputError(f"{missing or '--synthetic'}: landmark pack not found (build the "
                             "packs with `make landmark-data` and neural.faces.build_synthetic)")
        if args.generate and not Path(args.kit).is_dir():
            raise InputError(f"{args.kit}: no data kit for --generate (python -m "
                             "neural.gpu_travel kit)")
        init = args.init or (CONTINUE["landmarks"] if args.resume_committed else None)
        if init and not Path(init).is_file():
            raise InputError(f"{init}: landmark weights not found")
        stages = landmark_recipe(args.runs, args.synthetic, args.annotated, args.profiled,
                                 minutes=args.minutes or 8.0, init=init, arch=args.arch,
                                 generate=args.generate, kit=args.kit, workers=args.workers,
                                 generate_px=args.generate_px,
                                 **common)
    report = run_recipe(stages, args.out)
    failed = [k for k, v in report["jobs"].items() if v["returncode"] != 0]
    print(json.dumps({k: {"returncode": v["returncode"], "wall_seconds": v["wall_seconds"]}
                      for k, v in report["jobs"].items()}))
    if failed:
        print(f"neural.gpu_recipe: error: {', '.join(failed)} failed (see "
              f"{Path(args.out) / 'log.txt'})", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
