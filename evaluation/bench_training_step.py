"""Where a training step's time goes, for each recipe of the plugin, on the CPU:
``python -m evaluation.bench_training_step [--recipes landmarks,landmarks-wide,gar,inverter]
[--steps 4] [--batch-size 16[,32...]] [--threads 1] [--sync-every 25] [--device cpu|cuda]
[--amp none|bf16] [--channels-last] [--compile] [--report FILE]``.

One trainer per recipe is built on stand-in data of the real shapes (random pixels: the
time of a step does not depend on them): the landmark network (``--arch small`` at 128 px
and ``wide`` at 160 px, a pack of 512 faces of 160 px in memory), the 64-px GAR
(``tiny-gpu``'s network) and its inverter V on a pack of 256 random crops (:mod:`neural.gar.real_faces`), with
the committed aux networks of ``neural/gar/weights/real/`` (those of the GPU recipe). After
a warm-up step, ``--steps`` steps of the training loop run under timers:

- ``data``: drawing the batch (the landmark crops: gather, crop, colour jitter; the GAR's
  pack draws);
- the forward passes of each network, by forward hooks (landmarks: the network; GAR: ``G``,
  ``D``, the frozen aux networks ``N``, ``P``, ``L``, ``R``; inverter: ``V``, frozen ``G``);
- ``diffaugment`` and ``r1`` (the regularisers, R1's gradient through D included);
- ``rest``: the step's time less all of these (backward passes, optimisers, EMA, losses);
- ``reads``: the reads of tensors' values that the project's own code makes per step
  (:class:`Reads`: ``float(t)``, ``int(t)``, ``bool(t)``, ``.item()``, ``.tolist()``,
  ``.cpu()`` called from a file of this repository): each one makes the host wait for the
  GPU when its tensor lives there. Not counted: torch's own (the optimisers read their step
  counters, which stay on the CPU) and hidden ones (a boolean mask index).

Every share is a mean over the timed steps in ms per step; the step's own mean ms and
images/s beside them. ``--sync-every`` sets the loop's reading interval of the trainers that
have one (:class:`neural.training.TrainingRun`; the CPU default is 1, a GPU's
:data:`neural.training.SYNC_EVERY_DEVICE`): ``reads`` per step then shows what a GPU run
does. The figures run the module against any version of ``neural`` on ``PYTHONPATH`` (the
"before" column of docs/gpu_runs.md is the tree before these changes).

On a GPU (``--device cuda --amp bf16 --channels-last --batch-size 64,256,512``: the
one-minute throughput probe of docs/gpu_runs.md) the timers see the host's launches only;
``images_per_second_wall`` (the timed loop's wall clock, the device synchronised at its
end) is the figure, and ``gpu_syncs_per_step`` counts every operation that made the host
wait for the GPU (torch's CUDA sync debug mode: reads, synchronous copies, boolean masks),
the checkpoint's excepted.

The report (``--report``, JSON): per recipe (``name@batch`` with several batch sizes)
``batch_size``, ``steps``, ``ms_per_step``, ``images_per_second``, ``ms`` (dict share -> ms
per step), ``reads_per_step``, ``loop_wall_seconds`` and ``images_per_second_wall`` (not for
the inverter); the clock, threads, device and load average.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

__all__ = ["Reads", "Timers", "landmark_trainer", "gar_trainer", "random_gar_pack", "run_trainer",
           "run_inverter", "main"]

REPO = Path(__file__).resolve().parents[1]
AUX_DIR = REPO / "neural" / "gar" / "weights" / "real"


class Timers:
    """Seconds of ``clock`` by name, summed: :meth:`section` (a ``with`` block),
    :meth:`hook` (a module's forward passes) and :meth:`wrap` (a function's calls). The
    default clock is the calling thread's CPU time: with torch on one thread, a step's
    figures hardly change when other jobs share the cores (wall time does, several-fold)."""

    def __init__(self, clock=time.thread_time):
        self.clock = clock
        self.seconds: dict = {}

    def add(self, name: str, dt: float) -> None:
        """Add ``dt`` seconds to ``name``."""
        self.seconds[name] = self.seconds.get(name, 0.0) + dt

    @contextlib.contextmanager
    def section(self, name: str):
        """The time of the ``with`` block, added to ``name``."""
        t0 = self.clock()
        try:
            yield
        finally:
            self.add(name, self.clock() - t0)

    def hook(self, name: str, module) -> list:
        """Time ``module``'s forward passes under ``name``; -> the hooks' handles."""
        starts = []
        return [module.register_forward_pre_hook(lambda m, args: starts.append(self.clock())),
                module.register_forward_hook(
                    lambda m, args, out: self.add(name, self.clock() - starts.pop()))]

    def wrap(self, name: str, fn):
        """``fn`` with the time of each call added to ``name``."""
        def timed(*args, **kwargs):
            with self.section(name):
                return fn(*args, **kwargs)
        return timed


class Reads:
    """Counts the reads of tensor values (``METHODS``) whose caller is a file of the
    tree that ``neural`` is imported from, while a ``with`` block runs (``count``)."""

    METHODS = ("item", "tolist", "cpu", "__float__", "__int__", "__bool__")

    def __init__(self):
        self.count = 0
        self.counting = True

    @contextlib.contextmanager
    def paused(self):
        """No counting while the ``with`` block runs."""
        self.counting = False
        try:
            yield
        finally:
            self.counting = True

    def __enter__(self):
        import torch

        import neural

        self.root = str(Path(neural.__file__).resolve().parents[1])
        self.saved = {name: getattr(torch.Tensor, name) for name in self.METHODS}
        for name, method in self.saved.items():
            setattr(torch.Tensor, name, self._counted(method))
        return self

    def __exit__(self, *exc):
        import torch

        for name, method in self.saved.items():
            setattr(torch.Tensor, name, method)

    def _counted(self, method):
        def counted(tensor, *args, **kwargs):
            caller = sys._getframe(1).f_code.co_filename
            if self.counting and caller.startswith(self.root) and "site-packages" not in caller:
                self.count += 1
            return method(tensor, *args, **kwargs)
        return counted


def landmark_trainer(out, arch: str, batch_size: int, faces: int = 512, side: int = 160,
                     **run):
    """A :class:`neural.landmarks.train.LandmarkTrainer` of ``arch`` on ``faces`` random
    ``side``-px faces in memory (every point labelled), no held-out set; ``run``: its
    ``device``, ``amp``, ``channels_last``."""
    import torch

    from neural.faces.points import N_POINTS
    from neural.landmarks.data import LandmarkSource
    from neural.landmarks.network import LandmarkConfig
    from neural.landmarks.train import LandmarkTrainer

    try:
        from neural.landmarks.network import ARCHES
        sizes = ARCHES[arch]
    except ImportError:     # a version of neural before --arch: the small network only
        if arch != "small":
            raise
        sizes = {}
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (faces, side, side, 3), dtype=np.uint8)
    points = rng.uniform(0.3 * side, 0.7 * side, (faces, N_POINTS, 2)).astype(np.float32)
    boxes = np.tile(np.array([0.2, 0.2, 0.8, 0.8], np.float32) * side, (faces, 1))
    source = LandmarkSource("synthetic", "random", torch.as_tensor(images), points,
                            np.ones((faces, N_POINTS), np.float32), boxes, np.zeros(faces))
    cfg = LandmarkConfig(**sizes, batch_size=batch_size, mix=(("synthetic", 1.0),),
                         print_every=10**6, sample_every=10**6, checkpoint_every=10**6)
    return LandmarkTrainer(cfg, out, {"synthetic": source}, {}, {}, **run)


def random_gar_pack(path, n: int = 256, resolution: int = 64, seed: int = 0) -> Path:
    """A :mod:`neural.gar.real_faces` pack of ``n`` random crops (two per person, every
    fourth person held out): unit normals over a disc, random pixels and landmarks."""
    from neural.gar.real_faces import save_pack

    rng = np.random.default_rng(seed)
    R = resolution
    yy, xx = (np.mgrid[:R, :R] + 0.5) / R * 2 - 1
    inside = xx ** 2 + yy ** 2 < 0.8
    normals = np.zeros((n, R, R, 3), np.float32)
    normals[:, inside] = np.stack([xx[inside], yy[inside], np.sqrt(1.0 - xx[inside] ** 2
                                                                   - yy[inside] ** 2 + 0.2)], -1)
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-9)
    person = np.arange(n) // 2
    arrays = {"image": rng.integers(0, 256, (n, R, R, 3), dtype=np.uint8), "normals": normals,
              "mask": np.broadcast_to(inside, (n, R, R)).astype(np.float32),
              "landmarks": rng.uniform(0.2 * R, 0.8 * R, (n, 68, 2)).astype(np.float32),
              "person": person, "held_out": person % 4 == 3,
              "source": np.array(["random"] * n), "name": np.array([f"{i}" for i in range(n)])}
    return save_pack(path, arrays)


def gar_trainer(out, pack, batch_size: int, config: str = "tiny-gpu", **run):
    """A :class:`neural.gar.train.Trainer` of ``config`` on ``pack`` with the committed aux
    networks of the GPU recipe; ``run``: its ``device``, ``amp``, ``channels_last``."""
    from neural.gar.config import get_config
    from neural.gar.train import Trainer

    cfg = get_config(config, batch_size=batch_size, print_every=10**6, sample_every=10**6,
                     checkpoint_every=10**6, steps=10**6)
    return Trainer(cfg, out, aux_dir=AUX_DIR, data=str(pack), **run)


def run_trainer(trainer, steps: int, sync_every=None, hooks=(), patches=(),
                clock=time.thread_time) -> dict:
    """Time ``steps`` steps of ``trainer``'s own loop (after one warm-up step): ``hooks``
    (name, module) pairs timed by forward hooks, ``patches`` (module, attribute, name)
    functions timed by wrappers, on ``clock``; -> the recipe's report (see the module)."""
    timers = Timers(clock)
    reads = Reads()
    for name, module in hooks:
        timers.hook(name, module)
    originals = [(owner, attr, getattr(owner, attr)) for owner, attr, _ in patches]
    for owner, attr, name in patches:
        setattr(owner, attr, timers.wrap(name, getattr(owner, attr)))
    if sync_every is not None and hasattr(trainer, "sync_every"):
        trainer.sync_every = sync_every
    batches = trainer.batches

    def timed_batches(start):
        it = iter(batches(start))
        while True:
            with timers.section("data"):
                batch = next(it)
            yield batch

    trainer.batches = timed_batches
    step = trainer.train_step
    trainer.train_step = timers.wrap("step", step)
    trainer.sample_grid = lambda path: None
    save = trainer.save

    def save_unread():     # the checkpoint's copies to the CPU are no step's
        with reads.paused(), _sync_debug(trainer.device, "default"):
            return save()

    trainer.save = save_unread
    with open(os.devnull, "w") as null, contextlib.redirect_stdout(null):
        trainer.fit(progress=False, max_steps=1)
        timers.seconds.clear()
        with reads, warnings.catch_warnings(record=True) as caught, \
                _sync_debug(trainer.device, "warn"):
            warnings.simplefilter("always")
            t0 = time.perf_counter()
            trainer.fit(progress=False, max_steps=steps)
            _synchronize(trainer.device)
            wall = time.perf_counter() - t0
    syncs = sum("synchroniz" in str(w.message) for w in caught)
    for owner, attr, fn in originals:
        setattr(owner, attr, fn)
    ms = {k: 1000 * v / steps for k, v in timers.seconds.items()}
    total = ms.pop("step") + ms["data"]
    ms["rest"] = total - sum(ms.values())
    B = trainer.config.batch_size
    return {"batch_size": B, "steps": steps, "ms_per_step": round(total, 1),
            "images_per_second": round(1000 * B / total, 1),
            "ms": {k: round(v, 1) for k, v in ms.items()},
            "reads_per_step": round(reads.count / steps, 2),
            "loop_wall_seconds": round(wall, 2),
            "images_per_second_wall": round(steps * B / wall, 1),
            "gpu_syncs_per_step": round(syncs / steps, 2) if trainer.device.type == "cuda"
            else None}


@contextlib.contextmanager
def _sync_debug(device, mode: str):
    """torch's CUDA sync debug mode ``mode`` ("warn": a warning at each operation that
    makes the host wait for the GPU) while the block runs; nothing off CUDA."""
    import torch

    if device.type != "cuda":
        yield
        return
    previous = torch.cuda.get_sync_debug_mode()
    torch.cuda.set_sync_debug_mode(mode)
    try:
        yield
    finally:
        torch.cuda.set_sync_debug_mode(previous)


def _synchronize(device) -> None:
    import torch

    if device.type == "cuda":
        torch.cuda.synchronize(device)


def run_inverter(pack, steps: int, batch_size: int, clock=time.thread_time,
                 device="cpu") -> dict:
    """V's training (:func:`neural.gar.train_inverter.train`) against an untrained 64-px
    ``tiny-gpu`` G: the per-step figures are the difference of a ``steps + 1``-step and a
    one-step run (their evaluation cancels)."""
    import torch

    from neural.gar import train_inverter
    from neural.gar.config import get_config
    from neural.gar.inverter import Inverter
    from neural.gar.networks import Generator

    torch.manual_seed(0)
    G = Generator(get_config("tiny-gpu")).eval().requires_grad_(False)
    runs = {}
    for n in (1, steps + 1):
        timers = Timers(clock)
        # V's loss runs G block by block (neural.gar.inverter.generator_features)
        handles = [h for m in (G.mapping, *G.blocks) for h in timers.hook("G (frozen)", m)]
        forward = Inverter.forward
        Inverter.forward = timers.wrap("V", forward)
        try:
            with Reads() as reads:
                t0 = clock()
                train_inverter.train(G, steps=n, batch_size=batch_size, pool=64, held_out=8,
                                     data=str(pack), progress=False, eval_steps=1,
                                     device=device)
                wall = clock() - t0
        finally:
            Inverter.forward = forward
            for h in handles:
                h.remove()
        runs[n] = (wall, dict(timers.seconds), reads.count)
    (w1, s1, r1), (w2, s2, r2) = runs[1], runs[steps + 1]
    ms = {k: 1000 * (s2[k] - s1.get(k, 0.0)) / steps for k in s2}
    total = 1000 * (w2 - w1) / steps
    ms["rest"] = total - sum(ms.values())
    return {"batch_size": batch_size, "steps": steps, "ms_per_step": round(total, 1),
            "images_per_second": round(1000 * batch_size / total, 1),
            "ms": {k: round(v, 1) for k, v in ms.items()},
            "reads_per_step": round((r2 - r1) / steps, 2)}


def per_face_ms(arch: str, runs: int = 50) -> dict:
    """The landmark network of ``arch`` on one crop at a time, one CPU thread, channels-last
    (the detector's torch path without the crop): median and best ms of ``runs`` passes of
    the thread's CPU time, the parameters and the weights file's MB."""

    import torch

    from neural.landmarks.network import ARCHES, LandmarkConfig, LandmarkNet, save_landmark_net

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        cfg = LandmarkConfig(**ARCHES[arch])
        net = LandmarkNet(cfg).eval().to(memory_format=torch.channels_last)
        x = torch.zeros(1, 3, cfg.resolution, cfg.resolution).to(memory_format=torch.channels_last)
        times = []
        with torch.no_grad():
            for k in range(runs + 5):
                t0 = time.thread_time()
                net(x)
                if k >= 5:
                    times.append(1000 * (time.thread_time() - t0))
    finally:
        torch.set_num_threads(threads)
    with tempfile.TemporaryDirectory() as tmp:
        save_landmark_net(net, Path(tmp) / "w.pt")
        size = (Path(tmp) / "w.pt").stat().st_size
    return {"arch": arch, "resolution": cfg.resolution,
            "parameters": sum(p.numel() for p in net.parameters()),
            "weights_mb": round(size / 1e6, 1), "median_ms": round(float(np.median(times)), 2),
            "best_ms": round(min(times), 2)}


RECIPES = ("landmarks", "landmarks-wide", "gar", "inverter")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m evaluation.bench_training_step",
                                description=__doc__.splitlines()[0])
    p.add_argument("--recipes", default=",".join(RECIPES),
                   help=f"comma-separated, of {', '.join(RECIPES)}")
    p.add_argument("--steps", type=int, default=4, help="timed steps per recipe")
    p.add_argument("--batch-size", default="16",
                   help="comma-separated: each recipe at each (the GPU probe: 64,256,512)")
    p.add_argument("--device", default="cpu", help="torch device (cuda: the GPU probe; "
                   "then read images_per_second_wall, the section timers see launches only)")
    p.add_argument("--amp", default="none", help="bf16 on a GPU")
    p.add_argument("--channels-last", action="store_true")
    p.add_argument("--compile", action="store_true", help="torch.compile the trained networks "
                   "(landmarks, GAR)")
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads (1: the figures are the thread's CPU time)")
    p.add_argument("--sync-every", type=int, help="the loop's reading interval (GPU: 25)")
    p.add_argument("--per-face", action="store_true", help="instead: the landmark networks' "
                   "ms per face on one CPU thread (per_face_ms)")
    p.add_argument("--report", help="JSON report")
    return p


def main(argv=None) -> int:
    import torch

    args = build_parser().parse_args(argv)
    if args.per_face:
        rows = [per_face_ms(a) for a in ("small", "wide")]
        for r in rows:
            print(json.dumps(r))
        print(f"load average {os.getloadavg()[0]:.2f}")
        return 0
    recipes = [r for r in args.recipes.split(",") if r]
    unknown = [r for r in recipes if r not in RECIPES]
    try:
        sizes = [int(b) for b in args.batch_size.split(",")]
    except ValueError:
        sizes = []
    if unknown or args.steps < 1 or not sizes or min(sizes) < 2:
        print(f"bench_training_step: error: recipes must be of {', '.join(RECIPES)}, "
              "--steps >= 1, --batch-size integers >= 2", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    clock = time.thread_time if args.threads == 1 and args.device == "cpu" else time.perf_counter
    run = {"device": args.device, "amp": args.amp, "channels_last": args.channels_last}
    if args.compile:
        run["compile"] = True
    report = {"clock": clock.__name__, "threads": args.threads, "sync_every": args.sync_every,
              **run, "load_average": os.getloadavg()[0], "recipes": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        pack = None
        if {"gar", "inverter"} & set(recipes):
            pack = random_gar_pack(tmp / "pack.npz")
        for name in recipes:
            for B in sizes:
                key = name if len(sizes) == 1 else f"{name}@{B}"
                out = tmp / key
                if name.startswith("landmarks"):
                    t = landmark_trainer(out, "wide" if name.endswith("wide") else "small", B,
                                         **run)
                    r = run_trainer(t, args.steps, args.sync_every, hooks=[("network", t.net)],
                                    clock=clock)
                elif name == "gar":
                    from neural.gar import train as gar_train

                    t = gar_trainer(out, pack, B, **run)
                    hooks = [("G", t.G), ("D", t.D)] + [(f"aux {k}", m) for k, m in t.aux.items()]
                    r = run_trainer(t, args.steps, args.sync_every, hooks=hooks, clock=clock,
                                    patches=[(gar_train, "diff_augment", "diffaugment"),
                                             (gar_train, "r1_penalty", "r1")])
                else:
                    r = run_inverter(pack, args.steps, B, clock, device=args.device)
                report["recipes"][key] = r
                print(f"{key}: {r['ms_per_step']} ms/step of {r['batch_size']} "
                      f"({r['images_per_second']} img/s), reads/step {r['reads_per_step']}: "
                      + ", ".join(f"{k} {v}" for k, v in r["ms"].items()), flush=True)
    report["load_average_after"] = os.getloadavg()[0]
    if args.report:
        Path(args.report).parent.mkdir(parents=True, exist_ok=True)
        Path(args.report).write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
