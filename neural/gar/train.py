"""Train the GAR: ``python -m neural.gar.train --config tiny --out runs/tiny``.

Each step: sample pairs of normal maps of the same identities (synthetic renders, or with
``--data PACK`` the fits of real photos, :class:`neural.gar.real_faces.RealFaces`), one
generator step on ``L_GAR`` (:func:`neural.gar.losses.generator_losses`; its contrastive terms
every ``contrastive_every`` steps), one discriminator step (logistic loss, lazy R1 every
``r1_every`` steps; with ``--data`` its real images are other photos of the pack, and both
its inputs pass through the differentiable augmentation of :mod:`neural.augment`), and an
exponential moving average of the generator (``G_ema``, used for samples and the saved
weights). ``--device cuda --amp bf16 --channels-last`` is the GPU recipe (``make gar-gpu``).

Reproducible and resumable: step ``k`` draws its data, latents and noise from seeds
``(seed, k)``, and ``out/checkpoint.pt`` (written atomically every ``checkpoint_every``
steps, at the end, and on Ctrl-C) holds the networks, optimiser states and step, so a run
killed at any moment and restarted with the same command continues from its last
checkpoint and ends with the same weights as an uninterrupted run.

Outputs in ``--out``: ``checkpoint.pt``, ``generator.pt`` (config, G_ema and D weights),
``samples/step-XXXXXX.png`` (rows: a normal map then ``G`` under fixed latents),
``log.jsonl`` (one JSON line per step: losses, seconds).

``--init WEIGHTS``: a new run starts from a ``generator.pt`` (G_ema's weights for G and
G_ema, D's), with fresh Adam states under a linear learning-rate warm-up of ``--init-warmup``
steps: one GPU run continues the last one's committed GAR (docs/gpu_runs.md).
"""
from __future__ import annotations

import argparse
import copy
import json
import logging
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from morphable.errors import InputError, MorphableError
from morphable.logs import add_verbosity_arguments, configure, verbosity

from ..augment import DEFAULT_POLICY, diff_augment, parse_policy
from .auxnets import NAMES, load_aux
from .paths import default_aux_path
from .config import GARConfig, get_config
from .networks import Discriminator, Generator
from .losses import discriminator_loss, generator_losses, r1_penalty
from ..training import AMP_DTYPES, TrainingRun, cpu_state, parse_set, step_generator

__all__ = ["Trainer", "main", "normal_to_rgb", "save_grid", "landmark_index"]

log = logging.getLogger("neural.gar.train")


def normal_to_rgb(normals: torch.Tensor) -> torch.Tensor:
    """(B, 3, H, W) normals -> (B, 3, H, W) in [-1, 1] for display (zero background stays
    black)."""
    fg = (normals.abs().sum(1, keepdim=True) > 0).to(normals.dtype)
    return ((normals + 1) / 2 * fg) * 2 - 1


def save_grid(images: torch.Tensor, path, ncol: int) -> None:
    """(N, 3, H, W) images in [-1, 1] -> a PNG grid of ``ncol`` columns (atomic write)."""
    from PIL import Image

    from morphable.io.atomic import atomic_path

    x = ((images.detach().clamp(-1, 1) + 1) * 127.5).round().to(torch.uint8).cpu().numpy()
    N, _, H, W = x.shape
    nrow = -(-N // ncol)
    grid = np.zeros((nrow * H, ncol * W, 3), dtype=np.uint8)
    for i in range(N):
        r, c = divmod(i, ncol)
        grid[r * H:(r + 1) * H, c * W:(c + 1) * W] = x[i].transpose(1, 2, 0)
    with atomic_path(path) as tmp:
        Image.fromarray(grid).save(tmp, format="PNG")


class _Batches(torch.utils.data.IterableDataset):
    """Synthetic batches for steps ``start, start + 1, ...``, step k seeded by (seed, k)."""

    def __init__(self, data, batch_size, seed, start):
        self.data, self.batch_size, self.seed, self.start = data, batch_size, seed, start

    def __iter__(self):
        # worker k of W renders steps start + k, start + k + W, ...; the DataLoader takes
        # the workers in turn, so batches arrive in step order whatever W is
        info = torch.utils.data.get_worker_info()
        k, W = (info.id, info.num_workers) if info is not None else (0, 1)
        step = self.start + k
        while True:
            yield self.data.sample(self.batch_size, rng=[self.seed, step], pair=True)
            step += W


def landmark_index(config: GARConfig, L, real: bool) -> np.ndarray:
    """(K,) ids of the landmarks L_ldmk compares (``config.landmark_set``, its docstring in
    :class:`~neural.gar.config.GARConfig`): ``real`` says whether the normal maps come from real
    photos; ``L`` is the landmark network (its ``meta`` may state its landmarks)."""
    choice = config.landmark_set
    if choice == "auto":
        meta = getattr(L, "meta", None) or {}
        if real and "landmark_index" in meta:
            return np.asarray(meta["landmark_index"], dtype=np.int64)
        synthetic_l = str(meta.get("training_data", "")).startswith("SyntheticFaces")
        choice = "model" if not real or synthetic_l else "all"
    if choice == "all":
        return np.arange(68)
    from morphable import load_model

    return np.flatnonzero(load_model(config.model).landmark_ids >= 0)


class Trainer(TrainingRun):
    """The GAR training state: networks, optimisers, data, step (the loop, checkpoints and
    summary are :class:`neural.training.TrainingRun`'s).

    Parameters
    ----------
    config : GARConfig
    out : output folder
    aux : dict name -> frozen network, or None to load the committed aux weights
        (``neural/gar/weights/aux_*.pt``, or ``aux_dir/aux_*.pt``)
    images : optional folder of face photos for the discriminator's real images
        (otherwise the synthetic renders are the real images)
    data : optional pack of real photos (:mod:`neural.gar.real_faces`): G's normal maps are its
        train split's fits, D's real images other photos of it (held on ``device``)
    amp : ``"bf16"`` for bfloat16 autocast of every forward pass, None for float32
    channels_last : networks and images in channels-last memory format
    sync_every : steps between reads of the loss terms (:class:`neural.training.TrainingRun`)
    compile : compile G and D (:meth:`neural.training.TrainingRun.compiled`)
    """

    WEIGHTS_FILE = "generator.pt"
    REPORT_KEYS = ("n", "ldmk", "id", "adv", "d", "r1", "g_total")

    def __init__(self, config: GARConfig, out, aux=None, aux_dir=None, images=None,
                 aligned=False, workers: int = 0, device="cpu", data=None, amp=None,
                 channels_last: bool = False, sync_every=None, compile: bool = False):
        from .data import AlignedImageFolder
        from ..faces.renders import SyntheticFaces
        from .real_faces import RealFaces

        if data is not None and images is not None:
            raise InputError("--data and --images both give the discriminator real photos; "
                             "pass one")
        if data is not None and workers:
            raise InputError("--data batches are drawn on the device; drop --workers")
        super().__init__(out, device=device, amp=amp, channels_last=channels_last,
                         sync_every=sync_every, compile=compile)
        real = None if data is None else RealFaces(data, "train", device=self.device,
                                                   resolution=config.resolution)
        policy = config.augment
        if policy is None:
            policy = DEFAULT_POLICY if real is not None else ""
        try:
            parse_policy(policy)
        except ValueError as e:
            raise InputError(f"--set augment: {e}") from None
        config = self.config = replace(config, augment=policy)
        torch.manual_seed(config.seed)
        self.G = self.layout(Generator(config))
        self.D = self.layout(Discriminator(config))
        self.G_ema = copy.deepcopy(self.G).eval().requires_grad_(False)
        self.compiled(self.G), self.compiled(self.D)
        self.opt_g = torch.optim.Adam(self.G.parameters(), lr=config.g_lr, betas=config.betas)
        # lazy R1: scale the D optimiser's momentum as StyleGAN2 does
        c = config.r1_every / (config.r1_every + 1)
        self.opt_d = torch.optim.Adam(self.D.parameters(), lr=config.d_lr * c,
                                      betas=tuple(b ** c for b in config.betas))
        if aux is None:
            aux = {n: load_aux(n, None if aux_dir is None else Path(aux_dir) / f"aux_{n}.pt",
                               resolution=config.aux_size) for n in NAMES}
        self.aux = {n: self.layout(net) for n, net in aux.items()}
        # the source of G's normal maps (and, without --data or --images, of D's reals)
        self.real = real
        self.data = SyntheticFaces.from_config(config) if real is None else real
        self.images = None
        if images is not None:
            self.images = AlignedImageFolder(images, config.resolution, aligned=aligned,
                                             model=config.model)
        self.workers = workers
        self.init = None       # the weights a run started from (--init): path, images, warm-up
        self.landmark_index = torch.as_tensor(
            landmark_index(config, self.aux["L"], real=real is not None), device=self.device)

    # --- checkpoints --------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {"config": self.config.to_dict(), "step": self.step, "G": self.G.state_dict(),
                "D": self.D.state_dict(), "G_ema": self.G_ema.state_dict(),
                "opt_g": self.opt_g.state_dict(), "opt_d": self.opt_d.state_dict(),
                "init": self.init}

    def weights(self) -> dict:
        """What ``generator.pt`` holds: the config, the step, ``images_seen`` (since the first
        run of an ``--init`` chain), ``init`` (the weights this run started from, or None),
        G_ema (with its mapping network M) as ``"G"`` and the discriminator ``"D"`` (to
        fine-tune or continue adversarially), as CPU tensors."""
        before = self.init["images_seen"] if self.init else 0
        return {"config": self.config.to_dict(), "step": self.step,
                "images_seen": before + self.step * self.config.batch_size, "init": self.init,
                "G": cpu_state(self.G_ema), "D": cpu_state(self.D)}

    def _same_architecture(self, ckpt: dict, path, advice: str) -> None:
        saved = GARConfig.from_dict(ckpt["config"])
        arch = ("resolution", "z_dim", "w_dim", "mapping_layers", "channel_base", "channel_max",
                "nim_background")
        k = next((k for k in arch if getattr(saved, k) != getattr(self.config, k)), None)
        if k is not None:
            raise InputError(f"{path}: checkpoint of a different architecture ({k} "
                             f"{getattr(saved, k)}, not {getattr(self.config, k)}); {advice}"
                             f"--set {k}={json.dumps(getattr(saved, k))}")

    def load_state(self, ckpt: dict, path) -> None:
        self._same_architecture(ckpt, path, "use another --out folder, or ")
        for key in ("G", "D", "G_ema", "opt_g", "opt_d"):
            getattr(self, key).load_state_dict(ckpt[key])
        self.init = ckpt.get("init")

    def init_from(self, path, warmup: int = 100) -> dict:
        """Start this (new) run from ``path``, a ``generator.pt``: G and G_ema from its G_ema,
        D from its D; fresh Adam states, the learning rates ramped up linearly over the first
        ``warmup`` steps -> ``self.init`` (path, images seen before, warm-up)."""
        path = Path(path)
        try:
            ckpt = torch.load(path, map_location=self.device, weights_only=True)
            self._same_architecture(ckpt, path, "")
            for net, key in ((self.G, "G"), (self.G_ema, "G"), (self.D, "D")):
                net.load_state_dict(ckpt[key])
        except (OSError, RuntimeError, EOFError, KeyError, TypeError) as e:
            raise InputError(f"{path}: cannot read GAR weights ({str(e).splitlines()[0]})") from None
        cfg = GARConfig.from_dict(ckpt["config"])
        images = ckpt.get("images_seen", int(ckpt.get("step", 0)) * cfg.batch_size)
        self.init = {"path": str(path), "images_seen": int(images), "warmup": int(warmup)}
        return self.init

    def _warm_up(self) -> None:
        """The learning rates of a run started by :meth:`init_from`: a linear ramp over its
        warm-up steps (the fresh Adam moments are noisy), then the config's."""
        if not self.init:
            return
        ramp = min(1.0, (self.step + 1) / max(self.init["warmup"], 1))
        c = self.config.r1_every / (self.config.r1_every + 1)
        self.opt_g.param_groups[0]["lr"] = self.config.g_lr * ramp
        self.opt_d.param_groups[0]["lr"] = self.config.d_lr * c * ramp

    def batches(self, start: int):
        """Batches of steps ``start, start + 1, ...`` (``workers`` processes render them)."""
        return torch.utils.data.DataLoader(
            _Batches(self.data, self.config.batch_size, self.config.seed, start), batch_size=None,
            num_workers=self.workers, persistent_workers=False)

    # --- one step -----------------------------------------------------------------------
    def real_images(self, batch, gen=None) -> torch.Tensor:
        """(B, 3, R, R) real images for the discriminator in this step (``gen``: the step's
        generator, :func:`neural.training.step_generator`, used by the --images draws)."""
        B = batch["image"].shape[0]
        if self.real is not None:
            # independent draws (with flips) of the pack's photos of other people than
            # those whose normal maps G got in this step, so D never sees G's own photo
            rng = np.random.default_rng([self.config.seed, self.step, 1])
            person = self.real.arrays["person"]
            allowed = np.flatnonzero(~np.isin(person, batch["identity_id"].numpy()))
            if not len(allowed):
                raise InputError(f"{self.real.path}: every train photo's person is in one "
                                 f"batch of {B}; use a smaller --batch-size")
            index = allowed[rng.integers(len(allowed), size=B)]
            return self.real.batch(index, rng.random(B) < 0.5)["image"]
        if self.images is None:
            return batch["image"]
        idx = torch.randint(len(self.images), (B,), generator=gen, device=gen.device).tolist()
        return torch.stack([self.images[i] for i in idx]).to(self.device)

    def _augment(self):
        """The step's DiffAugment (None when off), its draws seeded by (seed, step)."""
        if not self.config.augment:
            return None
        seed = int(np.random.SeedSequence([self.config.seed, self.step, 2]).generate_state(1)[0])
        gen = step_generator(seed, self.device)
        return lambda images: diff_augment(images, self.config.augment, gen)

    def train_step(self, batch) -> dict:
        cfg, dev = self.config, self.device
        # identity_id stays on the host: real_images reads it there, with no wait
        batch = {k: v if k == "identity_id" else self.layout(v) for k, v in batch.items()}
        # drawn where they are used: a CPU draw copied to a GPU would make the host wait
        gen = step_generator(cfg.seed * 1_000_003 + self.step, dev)
        torch.manual_seed(cfg.seed * 1_000_003 + self.step)   # the per-layer noise
        B = batch["normals"].shape[0]
        z1 = torch.randn(B, cfg.z_dim, generator=gen, device=dev)
        z2 = torch.randn(B, cfg.z_dim, generator=gen, device=dev)
        augment = self._augment()

        self._warm_up()
        # generator; the contrastive terms lazily, every contrastive_every steps, weighted
        # by the interval
        k = cfg.contrastive_every
        lambdas = dict(cfg.lambdas)
        for key in ("ldmk", "id"):
            lambdas[key] *= k if self.step % k == 0 else 0
        self.G.train()
        self.D.requires_grad_(False)
        with self.autocast():
            total, terms, fake = generator_losses(self.G, self.D, self.aux, batch["normals"],
                                                  batch["normals_b"], z1, z2, lambdas,
                                                  landmark_index=self.landmark_index,
                                                  augment=augment, aux_size=cfg.aux_size)
        self.opt_g.zero_grad(set_to_none=True)
        total.backward()
        self.opt_g.step()
        self.D.requires_grad_(True)

        # discriminator, with lazy R1 on real images
        # with augmentation, R1's gradient is taken through it, w.r.t. the photos (as
        # DiffAugment's and StyleGAN2-ADA's code do)
        real = self.layout(self.real_images(batch, gen))
        r1_step = cfg.r1_gamma > 0 and self.step % cfg.r1_every == 0
        real.requires_grad_(r1_step)
        with self.autocast():
            real_logits = self.D(real if augment is None else augment(real)).float()
            fake_logits = self.D(fake if augment is None else augment(fake)).float()
        d_loss = discriminator_loss(real_logits, fake_logits)
        loss = d_loss
        if r1_step:
            r1 = r1_penalty(real, real_logits)
            loss = loss + cfg.r1_gamma / 2 * r1 * cfg.r1_every
            terms["r1"] = r1.detach()
        self.opt_d.zero_grad(set_to_none=True)
        loss.backward()
        self.opt_d.step()

        # G_ema: half-life of 10k images, ramped up over the first images (StyleGAN2-ADA's
        # ema_rampup = 0.05) so that short runs do not sit at the initial weights
        half_life = min(10_000, 0.05 * (self.step + 1) * B)
        beta = 0.5 ** (B / half_life)
        # one multi-tensor kernel per list instead of one per parameter (launch-bound on a GPU)
        with torch.no_grad():
            torch._foreach_lerp_(list(self.G_ema.parameters()), list(self.G.parameters()),
                                 1 - beta)
            for be, b in zip(self.G_ema.buffers(), self.G.buffers()):
                be.copy_(b)
        # 0-d tensors, read every sync_every steps by the loop (no per-step wait on a GPU)
        terms.update(g_total=total.detach(), d=d_loss.detach())
        self.step += 1
        return terms

    # --- samples ------------------------------------------------------------------------
    def sample_grid(self, path, n_normals: int = 4, n_latents: int = 6) -> Path:
        """Rows: a fixed normal map, then G_ema under ``n_latents`` fixed latents."""
        fixed = self.data.sample(n_normals, rng=[self.config.seed, 10**9])
        gen = torch.Generator().manual_seed(12345)
        z = torch.randn(n_latents, self.config.z_dim, generator=gen).to(self.device)
        noise = [e.to(self.device) for e in self.G_ema.make_noise(n_latents, gen)]
        rows = []
        with torch.no_grad():
            for n in fixed["normals"].to(self.device):
                imgs = self.G_ema(n[None].expand(n_latents, -1, -1, -1), z, noise=noise)
                rows += [normal_to_rgb(n[None]), imgs]
        save_grid(torch.cat(rows), path, ncol=n_latents + 1)
        return Path(path)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m neural.gar.train", description=__doc__.splitlines()[0])
    p.add_argument("--config", default="tiny",
                   help="tiny (64 px, CPU), tiny-gpu (tiny's network, one GPU) or base (256 px, GPU)")
    p.add_argument("--out", required=True, help="output folder (resumes from its checkpoint)")
    p.add_argument("--steps", type=int, help="total steps (default: the config's)")
    p.add_argument("--batch-size", type=int)
    p.add_argument("--seed", type=int)
    p.add_argument("--set", nargs="*", metavar="KEY=VALUE",
                   help="override config fields, e.g. lambda_n=0 sample_every=50")
    p.add_argument("--aux-dir", help="folder with aux_N.pt, aux_P.pt, aux_L.pt, aux_R.pt "
                                     f"(default {default_aux_path('N').parent})")
    p.add_argument("--untrained-aux", action="store_true",
                   help="use randomly initialised aux networks (smoke tests only)")
    p.add_argument("--data", metavar="PACK",
                   help="real-photo pack (neural.gar.real_faces, e.g. gar_data/real64.npz): G's "
                        "normal maps from its fits, D's real images its photos")
    p.add_argument("--images", help="folder of face photos for the discriminator (FFHQ-style)")
    p.add_argument("--aligned", action="store_true", help="--images are already aligned")
    p.add_argument("--no-resume", action="store_true", help="fail if --out has a checkpoint")
    p.add_argument("--init", metavar="WEIGHTS", help="a new run starts from this generator.pt "
                   "(fresh optimisers, learning-rate warm-up)")
    p.add_argument("--init-warmup", type=int, default=100, metavar="STEPS",
                   help="warm-up steps after --init")
    p.add_argument("--workers", type=int, default=0, help="data-loading processes")
    p.add_argument("--threads", type=int, help="torch CPU threads")
    p.add_argument("--compile", action="store_true", help="torch.compile G and D (GPU)")
    p.add_argument("--device", default="cpu", help="torch device, e.g. cuda")
    p.add_argument("--max-minutes", type=float, help="stop (with a checkpoint) after this time")
    p.add_argument("--checkpoint-minutes", type=float, metavar="M",
                   help="also write a checkpoint every M minutes of this run")
    p.add_argument("--max-steps", type=int, metavar="N",
                   help="stop (with a checkpoint) after N steps of this run")
    p.add_argument("--amp", default="none", choices=sorted(AMP_DTYPES),
                   help="autocast dtype of the forward passes (bf16 on GPUs that have it)")
    p.add_argument("--channels-last", action="store_true",
                   help="networks and images in channels-last memory format")
    add_verbosity_arguments(p)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure(verbosity(args))
    try:
        overrides = parse_set(args.set)
        for key in ("steps", "batch_size", "seed"):
            if getattr(args, key) is not None:
                overrides[key] = getattr(args, key)
        try:
            cfg = get_config(args.config, **overrides)
        except (TypeError, ValueError) as e:
            raise InputError(f"--config/--set: {e}") from None
        if args.threads:
            torch.set_num_threads(args.threads)
        aux = None
        if args.untrained_aux:
            log.warning("untrained aux networks: the losses L_n, L_ldmk, L_id are meaningless")
            torch.manual_seed(cfg.seed + 1)
            aux = {n: load_aux(n, pretrained=False, width=cfg.aux_width) for n in NAMES}
        trainer = Trainer(cfg, args.out, aux=aux, aux_dir=args.aux_dir, images=args.images,
                          aligned=args.aligned, workers=args.workers, device=args.device,
                          data=args.data, amp=args.amp, channels_last=args.channels_last,
                          compile=args.compile)
        if trainer.checkpoint_path.exists():
            if args.no_resume:
                raise InputError(f"{trainer.checkpoint_path}: exists (drop --no-resume to resume)")
            log.info("resuming from %s at step %d", trainer.checkpoint_path, trainer.load())
        elif args.init:
            log.info("starting from %s (%d images seen)", args.init,
                     trainer.init_from(args.init, args.init_warmup)["images_seen"])
        trainer.fit(progress=not args.quiet, max_minutes=args.max_minutes,
                    max_steps=args.max_steps, checkpoint_minutes=args.checkpoint_minutes)
        log.info("done: step %d, weights in %s", trainer.step, trainer.out / "generator.pt")
        return 0
    except MorphableError as e:
        print(f"neural.gar.train: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("neural.gar.train: interrupted (checkpoint saved; rerun the command to resume)",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
