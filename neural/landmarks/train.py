"""Train the landmark network: ``python -m neural.landmarks.train --out runs/ldmk
--synthetic PACK [PACK ...] [--annotated PACK] [--profiled PACK] [--recipe cpu|gpu]``.

Each step draws a batch (:func:`neural.landmarks.data.draw_batch`: the packs mixed by the
config's ``mix``, crops jittered as a detector's box would be, mirrored, recoloured, with
crops away from the face), and takes one AdamW step on the Gaussian negative log-likelihood
of every labelled point (:func:`neural.landmarks.network.gaussian_nll`, crop px) plus the face
score's binary cross-entropy. Learning rate: linear warm-up, then cosine to 2 % at
``steps``.

Recipes (explicit options win):

- ``cpu``: float32, channels-last, batch 64, a checkpoint every 5 minutes; run it in the
  background and rerun the same command to resume (bf16 autocast is 3x slower than float32
  on CPUs without native bf16, e.g. this project's AMD EPYC machines: docs/landmark_net.md);
- ``gpu``: ``--device cuda``, bf16, channels-last, batch 256 (learning rate × 2), at most 8
  minutes, a checkpoint every minute; the packs' images decoded once onto the GPU, the crops
  cut and jittered there (:mod:`neural.landmarks.data`), the losses read every
  :data:`neural.training.SYNC_EVERY_DEVICE` steps.

``--arch small|wide``: the network's size (:data:`neural.landmarks.network.ARCHES`; ``--set``
wins over it). ``--init WEIGHTS``: a new run (no checkpoint in ``--out``) starts from those
weights (``landmarks.pt`` or a ``checkpoint.pt`` of the same size), with a fresh optimiser
and the warm-up of its first steps: one GPU run continues the last one's committed network
(docs/gpu_runs.md); the weights' ``meta`` counts the images seen since the first run.

Outputs in ``--out``: ``checkpoint.pt`` (network, optimiser, step), ``landmarks.pt`` (what
:func:`neural.landmarks.network.load_landmark_net` reads: config, ``meta`` with the packs,
licences, images seen, training seconds and device, CPU weights), ``log.jsonl``,
``validation.jsonl`` (per held-out set: NME of the 68 iBUG rows by the face box side, and
of all rows; mean σ), ``samples/step-XXXXXX.png`` (held-out crops, truth green, prediction
red), ``summary.json``.

Held out: a synthetic pack's last ``--hold-out`` faces (default 256; never drawn for
training) and the annotated pack's validation split.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from morphable.errors import InputError, MorphableError
from morphable.logs import add_verbosity_arguments, configure, verbosity

from .data import LandmarkSource, draw_batch, load_source, validation_batch
from .network import ARCHES, LandmarkConfig, LandmarkNet, gaussian_nll, points_in_crop_px
from ..faces.points import IBUG_ROWS
from ..training import AMP_DTYPES, TrainingRun, cpu_state, parse_set

__all__ = ["LandmarkTrainer", "RECIPES", "main"]

log = logging.getLogger("neural.landmarks.train")

RECIPES = {
    "cpu": {"device": "cpu", "amp": "none", "channels_last": True, "batch_size": 64,
            "checkpoint_minutes": 5.0},
    "gpu": {"device": "cuda", "amp": "bf16", "channels_last": True, "batch_size": 256,
            "lr_scale": 2.0, "max_minutes": 8.0, "checkpoint_minutes": 1.0},
}
"""The two recipes of the one script; a recipe sets the options not given explicitly."""

_ARCH = ("resolution", "widths", "blocks", "hidden", "n_points")


class LandmarkTrainer(TrainingRun):
    """Network, optimiser and packs of one landmark-network run.

    Parameters
    ----------
    config : LandmarkConfig
    out : output folder
    sources : dict kind -> :class:`neural.landmarks.data.LandmarkSource` (training faces)
    validation : dict name -> LandmarkSource (held-out faces; reports and sample pictures)
    packs : dict kind -> list of pack descriptions for the weights' ``meta``
    device, amp, channels_last, sync_every, compile : as :class:`neural.training.TrainingRun`
    """

    WEIGHTS_FILE = "landmarks.pt"
    REPORT_KEYS = ("nll", "score", "err_px", "sigma_px", "lr")

    def __init__(self, config: LandmarkConfig, out, sources: dict, validation=None, packs=None,
                 device="cpu", amp=None, channels_last: bool = False, sync_every=None,
                 compile: bool = False):
        super().__init__(out, device=device, amp=amp, channels_last=channels_last,
                         sync_every=sync_every, compile=compile)
        self.config = config
        self.sources = sources
        self.validation = {name: validation_batch(src, config)
                           for name, src in (validation or {}).items() if len(src)}
        self.packs = packs or {}
        self.init = None       # the weights a run started from (--init): path, images seen
        # decoded once where the network trains: the crops are cut there, no image travels
        sources = self.sources = {k: s.to(self.device) for k, s in sources.items()}
        torch.manual_seed(config.seed)
        self.net = self.layout(LandmarkNet(config))
        first = draw_batch(sources, replace(config, negatives=0.0, seed=config.seed + 1), 0)
        w = first["weight"][..., None]
        self.net.set_mean_points((first["points"] * w).sum(0) / w.sum(0).clamp_min(1))
        self.opt = torch.optim.AdamW(self.net.parameters(), lr=config.lr,
                                     weight_decay=config.weight_decay)
        self.compiled(self.net)

    # --- checkpoints --------------------------------------------------------------------
    def meta(self) -> dict:
        before = self.init["images_seen"] if self.init else 0
        return {"packs": self.packs, "step": self.step,
                "images_seen": before + self.step * self.config.batch_size,
                "init": self.init,
                "train_seconds": round(self.train_seconds, 1),
                "device": str(self.device), "amp": bool(self.amp_dtype),
                "research_only": any(p.get("research_only", False)
                                     for ps in self.packs.values() for p in ps)}

    def state_dict(self) -> dict:
        return {"config": self.config.to_dict(), "net": self.net.state_dict(),
                "opt": self.opt.state_dict(), "train_seconds": self.train_seconds,
                "init": self.init}

    def load_state(self, ckpt: dict, path) -> None:
        self._same_network(ckpt, path, "use another --out folder")
        self.net.load_state_dict(ckpt["net"])
        self.opt.load_state_dict(ckpt["opt"])
        self.train_seconds = float(ckpt.get("train_seconds", 0.0))
        self.init = ckpt.get("init")

    def _same_network(self, ckpt: dict, path, advice: str) -> None:
        saved = LandmarkConfig.from_dict(ckpt["config"])
        k = next((k for k in _ARCH if getattr(saved, k) != getattr(self.config, k)), None)
        if k is not None:
            raise InputError(f"{path}: checkpoint of a different network ({k} "
                             f"{getattr(saved, k)}, not {getattr(self.config, k)}); {advice}")

    def init_from(self, path) -> dict:
        """Start this (new) run from the network of ``path`` (a weights file or a checkpoint
        of the same size): its weights, not its optimiser (AdamW's moments start again,
        under the warm-up of steps 0 .. ``config.warmup``) -> ``self.init``."""
        path = Path(path)
        try:
            ckpt = torch.load(path, map_location=self.device, weights_only=True)
            state = ckpt["state"] if "state" in ckpt else ckpt["net"]
        except (OSError, RuntimeError, EOFError, KeyError, TypeError) as e:
            raise InputError(f"{path}: cannot read landmark weights "
                             f"({str(e).splitlines()[0]})") from None
        self._same_network(ckpt, path, "give --arch or --set to match it")
        self.net.load_state_dict(state)
        meta = ckpt.get("meta") or {}
        images = meta.get("images_seen", int(ckpt.get("step", 0)) * int(ckpt["config"]["batch_size"]))
        self.init = {"path": str(path), "images_seen": int(images)}
        return self.init

    def weights(self) -> dict:
        return {"config": self.config.to_dict(), "meta": self.meta(), "state": cpu_state(self.net)}

    # --- one step -----------------------------------------------------------------------
    def batches(self, start: int):
        step = start
        while True:
            yield draw_batch(self.sources, self.config, step)
            step += 1

    def lr_at(self, step: int) -> float:
        cfg = self.config
        if step < cfg.warmup:
            return cfg.lr * (step + 1) / cfg.warmup
        t = min(1.0, (step - cfg.warmup) / max(cfg.steps - cfg.warmup, 1))
        return cfg.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * t)))

    def losses(self, batch: dict) -> tuple:
        """(total loss tensor, dict of 0-d tensor terms) of a batch."""
        half = self.config.resolution / 2
        x = self.layout(batch["image"])
        with self.autocast():
            out = self.net(x)
        q, w = batch["points"].to(self.device), batch["weight"].to(self.device)
        nll = gaussian_nll(out["points"] * half, out["log_sigma"], q * half, w)
        score = F.binary_cross_entropy_with_logits(out["score"], batch["face"].to(self.device))
        with torch.no_grad():
            d = ((out["points"] - q) * half).norm(dim=-1)
            err = (d * w).sum() / w.sum().clamp_min(1)
            sig = (out["log_sigma"].exp() * w).sum() / w.sum().clamp_min(1)
        # 0-d tensors, read every sync_every steps by the loop (no per-step wait on a GPU)
        return nll + score, {"nll": nll.detach(), "score": score.detach(), "err_px": err,
                             "sigma_px": sig}

    def train_step(self, batch) -> dict:
        self.net.train()
        lr = self.lr_at(self.step)
        for group in self.opt.param_groups:
            group["lr"] = lr
        loss, terms = self.losses(batch)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.net.parameters(), 10.0)
        self.opt.step()
        terms["lr"] = lr
        self.step += 1
        return terms

    # --- held-out sets ------------------------------------------------------------------
    @torch.no_grad()
    def predict(self) -> dict:
        """The network (eval mode) on every held-out set -> name -> dict of ``points`` (n, P, 2)
        crop-normalised and ``log_sigma`` (n, P), float32 CPU tensors."""
        self.net.eval()
        out = {}
        for name, b in self.validation.items():
            with self.autocast():
                o = self.net(self.layout(b["image"]))
            out[name] = {k: o[k].float().cpu() for k in ("points", "log_sigma", "score")}
        return out

    def evaluate(self, pred=None) -> dict:
        """Per held-out set (``pred``: :meth:`predict`'s, run when None): ``nme68_percent``
        (mean distance of the 68 iBUG rows by the face box side, which is the crop side: %),
        ``nme_all_percent`` (every labelled row), ``sigma_px`` (mean predicted σ, crop px),
        ``calibration`` (mean of d²/(2σ²): 1 when σ is right), ``score_mean``; appended to
        ``validation.jsonl``."""
        pred = self.predict() if pred is None else pred
        R, report = self.config.resolution, {"step": self.step}
        for name, b in self.validation.items():
            out = pred[name]
            d = ((out["points"] - b["points"]) * R / 2).norm(dim=-1)
            w = b["weight"]
            sig = out["log_sigma"].exp()
            w68 = w[:, IBUG_ROWS]
            report[name] = {
                "n": len(w),
                "nme68_percent": round(float((d[:, IBUG_ROWS] * w68).sum() / w68.sum().clamp_min(1))
                                       / R * 100, 3) if w68.sum() > 0 else None,
                "nme_all_percent": round(float((d * w).sum() / w.sum()) / R * 100, 3),
                "sigma_px": round(float((sig * w).sum() / w.sum()), 3),
                "calibration": round(float((d ** 2 / (2 * sig ** 2) * w).sum() / w.sum()), 3),
                "score_mean": round(float(torch.sigmoid(out["score"]).mean()), 3)}
        with open(self.out / "validation.jsonl", "a") as f:
            f.write(json.dumps(report) + "\n")
        return report

    def sample_grid(self, path, n: int = 8) -> Path | None:
        """Held-out crops with their labels (green) and the predicted 68 iBUG points (red)."""
        from PIL import Image, ImageDraw

        from morphable.io.atomic import atomic_path

        predicted = self.predict()
        report = self.evaluate(predicted)
        log.info("held out at step %d: %s", self.step, json.dumps(report))
        if not self.validation:
            return None
        R, tiles = self.config.resolution, []
        for name, b in self.validation.items():
            pred = predicted[name]["points"][:n]
            for i in range(len(pred)):
                img = ((b["image"][i].permute(1, 2, 0) + 1) * 127.5).clamp(0, 255).byte().numpy()
                tile = Image.fromarray(img)
                draw = ImageDraw.Draw(tile)
                for pts, colour, wt in ((b["points"][i], (0, 255, 0), b["weight"][i]),
                                        (pred[i], (255, 0, 0), torch.ones(len(pred[i])))):
                    px = points_in_crop_px(pts[IBUG_ROWS], R)
                    for (x, y), ok in zip(px.tolist(), wt[IBUG_ROWS].tolist()):
                        if ok:
                            draw.point((x, y), fill=colour)
                tiles.append(np.asarray(tile))
        cols = n
        rows = -(-len(tiles) // cols)
        grid = np.zeros((rows * R, cols * R, 3), np.uint8)
        for k, t in enumerate(tiles):
            r, c = divmod(k, cols)
            grid[r * R:(r + 1) * R, c * R:(c + 1) * R] = t
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            Image.fromarray(grid).save(tmp, format="PNG")
        return Path(path)


def _describe(path, kind: str, n: int) -> dict:
    """A pack for the weights' meta: path, kind, faces, sources and licences."""
    path = Path(path)
    d = {"path": str(path), "kind": kind, "faces": int(n)}
    manifest = path / "pack.json" if path.is_dir() else None
    if manifest is not None and manifest.is_file():
        m = json.loads(manifest.read_text())
        if "sources" in m:
            d["sources"] = [s["name"] for s in m["sources"]]
            d["research_only"] = any(s.get("research_only") for s in m["sources"])
        else:     # synthetic: London textures (CC BY 4.0); 300-W backgrounds: research only
            d["material"] = m.get("material")
            d["research_only"] = "research" in json.dumps(m.get("material", ""))
    return d


def load_sources(synthetic=(), annotated=None, profiled=None, hold_out: int = 256) -> tuple:
    """The packs -> (sources, validation, packs) for :class:`LandmarkTrainer`: every
    synthetic pack concatenated (its last ``hold_out`` faces of the first pack held out), the
    annotated and profiled packs' train splits; validation: those held-out synthetic faces
    and the annotated pack's validation split."""
    sources, validation, packs = {}, {}, {}
    syn = [load_source(p, "synthetic") for p in synthetic]
    if syn:
        first = syn[0]
        if hold_out and len(first) > 2 * hold_out:
            validation["synthetic"] = first.subset(np.arange(len(first) - hold_out, len(first)))
            syn[0] = first.subset(np.arange(len(first) - hold_out))
        sources["synthetic"] = _concat(syn)
        packs["synthetic"] = [_describe(p, "synthetic", len(s)) for p, s in zip(synthetic, syn)]
    for kind, path in (("annotated", annotated), ("profiled", profiled)):
        if path is None:
            continue
        sources[kind] = load_source(path, kind, "train")
        packs[kind] = [_describe(path, kind, len(sources[kind]))]
        held = load_source(path, kind, "validation")
        if len(held) and kind == "annotated":
            validation[kind] = held
    if not sources:
        raise InputError("no training data: give --synthetic, --annotated or --profiled packs")
    return sources, validation, packs


def _concat(parts: list):
    if len(parts) == 1:
        return parts[0]
    sides = {tuple(p.images.shape[1:3]) for p in parts}
    if len(sides) > 1:
        raise InputError(f"synthetic packs of different resolutions {sorted(sides)}: build "
                         "them at one --resolution")
    return LandmarkSource("synthetic", parts[0].path, torch.cat([p.images for p in parts]),
                          torch.cat([p.points for p in parts]), torch.cat([p.weight for p in parts]),
                          torch.cat([p.boxes for p in parts]), np.concatenate([p.yaw for p in parts]))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m neural.landmarks.train",
                                description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="output folder (resumes from its checkpoint)")
    p.add_argument("--synthetic", nargs="*", default=[], metavar="PACK",
                   help="synthetic packs (python -m neural.faces.build_synthetic), one resolution")
    p.add_argument("--annotated", metavar="PACK", help="real photos with sparse annotations "
                   "(python -m neural.faces.build_annotated)")
    p.add_argument("--profiled", metavar="PACK", help="profiled real photos "
                   "(python -m neural.faces.build_profiled)")
    p.add_argument("--hold-out", type=int, default=256,
                   help="faces at the end of the first synthetic pack kept for validation")
    p.add_argument("--recipe", choices=sorted(RECIPES), default="cpu")
    p.add_argument("--arch", choices=sorted(ARCHES), default="small",
                   help="network size (neural.landmarks.network.ARCHES; --set wins)")
    p.add_argument("--init", metavar="WEIGHTS", help="a new run starts from these weights "
                   "(landmarks.pt or checkpoint.pt; fresh optimiser, warm-up)")
    p.add_argument("--steps", type=int, help="total steps (the cosine schedule's length)")
    p.add_argument("--batch-size", type=int)
    p.add_argument("--seed", type=int)
    p.add_argument("--set", nargs="*", metavar="KEY=VALUE",
                   help="override config fields, e.g. lr=0.001 'widths=[16,32,64,96,128]'")
    p.add_argument("--device")
    p.add_argument("--amp", choices=sorted(AMP_DTYPES))
    p.add_argument("--channels-last", action=argparse.BooleanOptionalAction, default=None)
    p.add_argument("--threads", type=int, help="torch CPU threads")
    p.add_argument("--compile", action="store_true", help="torch.compile the network (GPU)")
    p.add_argument("--max-minutes", type=float)
    p.add_argument("--checkpoint-minutes", type=float)
    p.add_argument("--max-steps", type=int, help="stop (with a checkpoint) after N steps of this run")
    add_verbosity_arguments(p)
    return p


def config_from(args) -> tuple:
    """The config and the run options of ``args`` with the recipe's defaults filled in."""
    recipe = dict(RECIPES[args.recipe])
    overrides = {**ARCHES[args.arch], **parse_set(args.set)}
    for key in ("steps", "batch_size", "seed"):
        if getattr(args, key) is not None:
            overrides[key] = getattr(args, key)
    overrides.setdefault("batch_size", recipe["batch_size"])
    try:
        cfg = LandmarkConfig.from_dict({**LandmarkConfig().to_dict(), **overrides})
    except (TypeError, ValueError) as e:
        raise InputError(f"--set: {e}") from None
    if "lr" not in overrides and recipe.get("lr_scale"):
        cfg = replace(cfg, lr=cfg.lr * recipe["lr_scale"])
    run = {k: getattr(args, k) if getattr(args, k) is not None else recipe.get(k)
           for k in ("device", "amp", "channels_last", "max_minutes", "checkpoint_minutes")}
    return cfg, run


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure(verbosity(args))
    try:
        cfg, run = config_from(args)
        if args.threads:
            torch.set_num_threads(args.threads)
        sources, validation, packs = load_sources(args.synthetic, args.annotated, args.profiled,
                                                  args.hold_out)
        trainer = LandmarkTrainer(cfg, args.out, sources, validation, packs, device=run["device"],
                                  amp=run["amp"], channels_last=bool(run["channels_last"]),
                                  compile=args.compile)
        if trainer.checkpoint_path.exists():
            log.info("resuming from %s at step %d", trainer.checkpoint_path, trainer.load())
        elif args.init:
            log.info("starting from %s (%d images seen)", args.init,
                     trainer.init_from(args.init)["images_seen"])
        trainer.fit(progress=not args.quiet, max_minutes=run["max_minutes"],
                    max_steps=args.max_steps, checkpoint_minutes=run["checkpoint_minutes"])
        log.info("done: step %d, weights in %s", trainer.step, trainer.out / trainer.WEIGHTS_FILE)
        return 0
    except MorphableError as e:
        print(f"neural.landmarks.train: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("neural.landmarks.train: interrupted (checkpoint saved; rerun the command to "
              "resume)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
