"""The training machinery every network of the plugin shares: device and mixed precision,
atomic checkpoints with resume, the loop with its time and step budgets, ``log.jsonl`` and
``summary.json``. The GAR (:class:`neural.gar.train.Trainer`) and the landmark network
(:class:`neural.landmarks.train.LandmarkTrainer`) subclass :class:`TrainingRun` and supply
their networks, their batches and one step; the GPU recipe (:mod:`neural.gpu_recipe`) runs
either through its command line.

A subclass provides:

- ``config``: a dataclass with ``steps``, ``batch_size``, ``seed``, ``print_every``,
  ``sample_every``, ``checkpoint_every`` and ``to_dict()``;
- ``state_dict()`` / ``load_state(ckpt)``: everything a resumed run needs (networks,
  optimisers; the step is added here);
- ``weights()`` and ``WEIGHTS_FILE``: what the weights file beside the checkpoint holds (CPU
  tensors: a file written on a GPU must load where there is none);
- ``batches(start)``: an iterator of batches for steps ``start, start + 1, ...``;
- ``train_step(batch) -> dict`` of loss terms (increments ``self.step``): floats or 0-d
  tensors left on the device; the loop reads them in one transfer every ``sync_every``
  steps (1 on the CPU, where reading costs nothing: every step; ``SYNC_EVERY_DEVICE`` on a
  GPU, which otherwise waits for the host at every step);
- optionally ``sample_grid(path)`` (pictures of the run) and ``REPORT_KEYS`` (the terms the
  progress line shows).
"""
from __future__ import annotations

import collections
import json
import logging
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import torch

from morphable.errors import InputError, MorphableError

__all__ = ["AMP_DTYPES", "SYNC_EVERY_DEVICE", "TrainingRun", "cpu_state", "device_from",
           "device_name", "parse_set", "read_terms", "step_generator", "to_device"]

AMP_DTYPES = {"bf16": "bfloat16", "none": None}
"""``--amp`` choices -> the torch.autocast dtype (None: full precision)."""

SYNC_EVERY_DEVICE = 25
"""Steps between two reads of the loss terms on an accelerator (:class:`TrainingRun`)."""

log = logging.getLogger("neural.training")


def device_from(name) -> torch.device:
    """The torch device ``name`` (e.g. ``"cuda"``) once a tensor could be made on it; an
    InputError naming it otherwise (no CUDA build, no GPU)."""
    try:
        device = torch.device(name)
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as e:
        raise InputError(f"--device {name}: {str(e).splitlines()[0]}") from None
    return device


def device_name(device) -> str:
    """The device in words: the GPU's name for CUDA devices, else the torch device."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    return str(device)


def cpu_state(module) -> dict:
    """``module.state_dict()`` as detached CPU tensors (a weights file written on a GPU must
    load where there is none)."""
    return {k: v.detach().cpu() for k, v in module.state_dict().items()}


def parse_set(items) -> dict:
    """``--set key=value ...`` -> dict (values parsed as JSON where they are JSON)."""
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise InputError(f"--set expects key=value, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def to_device(x: torch.Tensor, device) -> torch.Tensor:
    """A CPU tensor on ``device`` without making the host wait: through pinned memory and an
    asynchronous copy (a plain ``.to("cuda")`` waits for every kernel queued before it). The
    tensor itself on the CPU, or when it is on ``device`` already."""
    device = torch.device(device)
    if x.device == device or device.type != "cuda":
        return x.to(device)
    return x.pin_memory().to(device, non_blocking=True)


def step_generator(seed: int, device) -> torch.Generator:
    """The random generator of one step, seeded by ``seed``, on ``device``: the CPU's
    generator there (the draws of every earlier run), the device's own elsewhere, so that
    the step's draws need no copy to the device (different numbers from the CPU's)."""
    device = torch.device(device)
    gen = torch.Generator() if device.type == "cpu" else torch.Generator(device=device)
    return gen.manual_seed(int(seed))


def read_terms(rows: list) -> list:
    """``rows`` (dicts of floats and 0-d tensors) -> the same dicts of floats, every tensor
    read in one device-to-host transfer (one synchronisation however many steps)."""
    tensors = [v for r in rows for v in r.values() if torch.is_tensor(v)]
    if not tensors:
        return [dict(r) for r in rows]
    values = iter(torch.stack([t.detach().float().reshape(()) for t in tensors]).cpu().tolist())
    return [{k: next(values) if torch.is_tensor(v) else v for k, v in r.items()} for r in rows]


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _stop_on_sigterm():
    """SIGTERM -> KeyboardInterrupt while the loop runs, so that ``kill`` (and a background
    run, where Python leaves SIGINT ignored) stops with a checkpoint like Ctrl-C; returns the
    previous handler (None off the main thread, where signals cannot be caught)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _interrupt)


class TrainingRun:
    """Device, precision, output folder and the training loop of one run.

    Parameters
    ----------
    out : output folder (created when the run writes to it: a bad input leaves nothing)
    device : torch device name
    amp : ``"bf16"`` for bfloat16 autocast of the forward passes, None or ``"none"`` for float32
    channels_last : networks and images in channels-last memory format
    compile : compile the networks given to :meth:`compiled` (``torch.compile`` through
        ``Module.compile``: the same parameters and state-dict names, so checkpoints and
        weights files do not change); for launch-bound small networks on a GPU
    sync_every : steps between reads of the loss terms (default 1 on the CPU,
        :data:`SYNC_EVERY_DEVICE` elsewhere); a NaN is reported at most this many steps late,
        and never reaches a checkpoint (the terms are read before each one)
    """

    WEIGHTS_FILE = "weights.pt"
    REPORT_KEYS: tuple = ()

    def __init__(self, out, device="cpu", amp=None, channels_last: bool = False,
                 sync_every=None, compile: bool = False):
        if amp is not None and amp not in AMP_DTYPES:
            raise InputError(f"--amp must be one of {', '.join(AMP_DTYPES)}, got {amp!r}")
        self.device = device_from(device)
        if self.device.type == "cuda":
            torch.backends.cudnn.benchmark = True     # fixed shapes: pick the fastest kernels
        self.amp_dtype = getattr(torch, AMP_DTYPES[amp]) if AMP_DTYPES.get(amp) else None
        self.channels_last = bool(channels_last)
        self.compile = bool(compile)
        self.sync_every = max(1, int(sync_every or (1 if self.device.type == "cpu"
                                                     else SYNC_EVERY_DEVICE)))
        self.out = Path(out)      # created by the subclass once its inputs loaded, or by fit
        self.step = 0
        self.train_seconds = 0.0  # every fit's, batches and reads included (checkpoints may keep it)

    def layout(self, x):
        """A module or tensor on the device, channels-last with ``channels_last`` (4-D
        tensors only); otherwise as it is."""
        x = x.to(self.device)
        if self.channels_last and (isinstance(x, torch.nn.Module) or x.dim() == 4):
            x = x.to(memory_format=torch.channels_last)
        return x

    def compiled(self, module):
        """``module``, compiled in place with ``compile`` (see the class)."""
        if self.compile:
            module.compile()
        return module

    def autocast(self):
        """The forward passes' autocast context (a no-op in float32)."""
        return torch.autocast(self.device.type, dtype=self.amp_dtype or torch.bfloat16,
                              enabled=self.amp_dtype is not None)

    # --- checkpoints --------------------------------------------------------------------
    @property
    def checkpoint_path(self) -> Path:
        return self.out / "checkpoint.pt"

    def save(self) -> Path:
        """``checkpoint.pt`` (:meth:`state_dict` and the step) and the weights file, each
        written atomically."""
        from morphable.io.atomic import atomic_path

        self.out.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.checkpoint_path) as tmp:
            torch.save({**self.state_dict(), "step": self.step}, tmp)
        with atomic_path(self.out / self.WEIGHTS_FILE) as tmp:
            torch.save(self.weights(), tmp)
        return self.checkpoint_path

    def load(self, path=None) -> int:
        """Restore from a checkpoint (default ``out/checkpoint.pt``); returns the step."""
        path = Path(path or self.checkpoint_path)
        try:
            ckpt = torch.load(path, map_location=self.device, weights_only=True)
        except (OSError, RuntimeError, EOFError) as e:
            raise InputError(f"{path}: cannot read checkpoint ({str(e).splitlines()[0]})") from None
        self.load_state(ckpt, path)
        self.step = int(ckpt["step"])
        return self.step

    def state_dict(self) -> dict:
        """What a checkpoint holds besides the step to resume the run (the subclass's networks,
        optimisers and config)."""
        raise NotImplementedError

    def load_state(self, ckpt: dict, path) -> None:
        raise NotImplementedError

    def weights(self) -> dict:
        raise NotImplementedError

    # --- the loop -----------------------------------------------------------------------
    def batches(self, start: int):
        raise NotImplementedError

    def train_step(self, batch) -> dict:
        raise NotImplementedError

    def sample_grid(self, path):
        """Pictures of the run so far (none by default)."""
        return None

    def finite_or_raise(self, terms: dict, step=None) -> dict:
        """``terms`` (floats) when every loss is finite; a MorphableError naming the step
        (default the current one) otherwise (never a silent NaN)."""
        if not all(np.isfinite(v) for v in terms.values()):
            raise MorphableError(f"training diverged at step {self.step if step is None else step}: "
                                 f"{terms}")
        return terms

    def report(self, terms: dict, steps: int, images: int, seconds: float, out=None) -> str:
        """One line: step, the loss terms, throughput (images/s: batch size x steps per second
        of training steps) over ``images`` in ``seconds``; printed to ``out`` (default stdout)."""
        keys = self.REPORT_KEYS or tuple(k for k in terms if k not in ("step", "seconds"))
        losses = " ".join(f"{k} {terms[k]:.4f}" for k in keys if k in terms)
        line = (f"step {self.step}/{steps} {losses} | {images / max(seconds, 1e-9):.1f} img/s "
                f"({images} images in {seconds:.1f} s)")
        print(line, file=out or sys.stdout, flush=True)
        return line

    def fit(self, steps=None, progress: bool = True, max_minutes=None, max_steps=None,
            checkpoint_minutes=None) -> int:
        """Train up to ``steps`` (default config.steps) total steps, or until ``max_minutes``
        have passed or ``max_steps`` steps of this call are done (then a sample grid and a
        checkpoint are written; rerun to continue); returns the final step. Prints the
        losses and throughput every ``config.print_every`` steps and at the end.

        ``checkpoint_minutes``: also a checkpoint each time this many minutes have passed
        since the last one (a run cut off from outside still leaves recent weights);
        ``summary.json`` is rewritten with each checkpoint.
        Ctrl-C or SIGTERM: a checkpoint, then KeyboardInterrupt.
        At the end, ``summary.json`` in the output folder: the config, step, images seen in
        all (step x batch size), this call's training seconds, images/s and wall seconds,
        the device, and the mean loss terms of the last ``print_every`` steps."""
        from tqdm import tqdm

        cfg = self.config
        steps = cfg.steps if steps is None else steps
        first = self.step
        (self.out / "samples").mkdir(parents=True, exist_ok=True)
        bar = tqdm(total=steps, initial=self.step, disable=not progress, unit="step",
                   dynamic_ncols=True)
        logf = open(self.out / "log.jsonl", "a")
        start = last_save = time.monotonic()
        train_seconds, window, terms = 0.0, [0.0, 0], None
        recent = collections.deque(maxlen=max(cfg.print_every, 1))   # for summary.json
        pending = []       # steps whose terms are not read yet (tensors on the device)

        def flush():
            """Read the pending steps' terms (one transfer), check them, log them."""
            nonlocal terms
            for row in read_terms(pending):
                self.finite_or_raise({k: v for k, v in row.items()
                                      if k not in ("step", "seconds")}, row["step"])
                logf.write(json.dumps(row) + "\n")
                recent.append(row)
                terms = row
            logf.flush()
            if pending:
                bar.set_postfix({k: f"{terms[k]:.3f}" for k in self.REPORT_KEYS if k in terms})
            pending.clear()

        previous = _stop_on_sigterm()
        try:
            it = iter(self.batches(self.step))
            while self.step < steps:
                over_time = max_minutes is not None and time.monotonic() - start > 60 * max_minutes
                if over_time or (max_steps is not None and self.step - first >= max_steps):
                    log.info("%s reached at step %d", f"time budget of {max_minutes:g} min"
                             if over_time else f"--max-steps {max_steps}", self.step)
                    flush()
                    self.sample_grid(self.out / "samples" / f"step-{self.step:06d}.png")
                    self.save()
                    break
                # the step's seconds count its batch too, and the read of the terms where
                # it ends with one (on a GPU the kernels finish there): images/s is what the
                # run achieves, not what the step's Python alone takes
                t0 = time.perf_counter()
                row = self.train_step(next(it))
                row["step"], row["seconds"] = self.step, round(time.perf_counter() - t0, 4)
                pending.append(row)
                bar.update(1)
                report = cfg.print_every and self.step % cfg.print_every == 0
                sample = self.step % cfg.sample_every == 0 or self.step == steps
                due = (checkpoint_minutes is not None
                       and time.monotonic() - last_save > 60 * checkpoint_minutes)
                save = self.step % cfg.checkpoint_every == 0 or self.step == steps or due
                if len(pending) >= self.sync_every or report or sample or save:
                    flush()
                dt = time.perf_counter() - t0
                train_seconds += dt
                self.train_seconds += dt
                window = [window[0] + dt, window[1] + 1]
                if report:
                    self.report(terms, steps, window[1] * cfg.batch_size, window[0])
                    window = [0.0, 0]
                if sample:
                    self.sample_grid(self.out / "samples" / f"step-{self.step:06d}.png")
                if save:
                    self.save()
                    # the run so far, beside the weights: a run cut off from outside still
                    # tells its losses, images seen and images/s
                    self.write_summary(recent, self.step - first, train_seconds,
                                       time.monotonic() - start)
                    last_save = time.monotonic()
        except KeyboardInterrupt:
            flush()
            self.save()
            raise
        finally:
            bar.close()
            logf.close()
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)
        if terms is not None:
            print("end: ", end="", flush=True)
            self.report(terms, steps, (self.step - first) * cfg.batch_size, train_seconds)
            self.write_summary(recent, self.step - first, train_seconds,
                               time.monotonic() - start)
        return self.step

    def write_summary(self, recent, steps: int, train_seconds: float,
                      wall_seconds: float) -> Path:
        """``summary.json`` of :meth:`fit` (``recent``: the last steps' loss dicts)."""
        from morphable.io.atomic import write_json

        cfg = self.config
        keys = sorted({k for t in recent for k in t} - {"step", "seconds"})
        losses = {k: float(np.mean([t[k] for t in recent if k in t])) for k in keys}
        summary = {"config": cfg.to_dict(), "step": self.step,
                   "images_seen": self.step * cfg.batch_size, "steps_this_run": steps,
                   "train_seconds": round(train_seconds, 2),
                   # 4 significant digits: a slow smoke-test step must not read 0
                   "images_per_second": float(f"{steps * cfg.batch_size / max(train_seconds, 1e-9):.4g}"),
                   "wall_seconds": round(wall_seconds, 2), "device": device_name(self.device),
                   "amp": str(self.amp_dtype).replace("torch.", "") if self.amp_dtype else None,
                   "channels_last": self.channels_last, "losses_recent_mean": losses}
        return write_json(self.out / "summary.json", summary, indent=2)
