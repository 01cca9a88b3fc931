"""Train the auxiliary networks N, P, L, R on synthetic renders with exact labels:
``python -m neural.gar.auxnets.train --out neural/weights --steps 2000``.

Losses: N ``1 - cos`` on face pixels (coverage > 0.5); P binary cross-entropy against the
pixel coverage; L mean pixel distance of the soft-argmax landmarks to the projected model
landmarks (those the 3DMM defines); R mean squared error of the regressed skin tone and
leading identity coefficients (std units) of faces whose pose, expression, light and
background vary.
Every sample is a new identity unless ``--identities N`` draws them from a pool. Validation
metrics on a held-out batch (fresh identities for R)
are stored in each checkpoint's ``meta["metrics"]``: normal error (degrees), mask IoU,
landmark error (px), identity verification AUC and the fraction of identity-coefficient
variance R explains. ``--nets R`` trains a subset.

**Real crops** (``--data PACK``, a :mod:`neural.gar.real_faces` pack): fine-tunes from the
committed weights (``--init``) on the pack's train split, crops mirrored at random. Labels:
N and P the fit's normal map and mask, L every finite landmark of the pack (ground truth or
detected); each N, P, L batch also holds ``--synthetic-share`` synthetic renders. R learns
real identity with a contrastive (InfoNCE) loss: the positives are another photo of the same
person (the London set's pairs) or else the mirror image, the other crops of the batch the
negatives. ``meta["metrics"]`` then holds the metrics of the pack's held-out crops
(:func:`neural.gar.auxnets.metrics.real_metrics`), the synthetic ones under ``"synthetic"``::

    python -m neural.gar.auxnets.train --data gar_data/real64.npz --out runs/aux-real --nets NPL \
        --steps 600 --batch-size 12 --threads 1 --max-minutes 9
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from morphable.errors import MorphableError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity

from . import NAMES, build_aux, save_aux
from .metrics import identity_labels, pair_rows, pair_verification, real_metrics, synthetic_metrics

__all__ = ["AuxTrainer", "main"]

log = logging.getLogger("neural.gar.auxnets.train")


class AuxTrainer:
    """Joint training of N, P, L, R on one stream of batches: synthetic renders, or with
    ``pack`` the train split of a real pack (see the module docstring).

    ``init`` : folder of ``aux_<name>.pt`` checkpoints to start from (their widths are kept);
    None starts from fresh networks of ``width``. ``synthetic_share`` (real packs only): the
    fraction of synthetic renders added to each N, P, L batch, so that the networks keep what
    the exact synthetic labels taught them.
    """

    def __init__(self, resolution=64, width=16, n_identities=None, batch_size=16, lr=2e-3,
                 seed=0, model="sfm", nets=NAMES, pack=None, init=None, synthetic_share=0.0,
                 r_exclude_every=0):
        from ...faces.renders import SyntheticFaces

        torch.manual_seed(seed)
        self.width, self.batch_size, self.seed = width, batch_size, seed
        self.names = tuple(nets)
        self.widths = {}
        self.nets = {n: self.start(n, init) for n in self.names}
        params = [p for net in self.nets.values() for p in net.parameters()]
        self.opt = torch.optim.Adam(params, lr=lr)
        self.real = self.test = None
        if pack is not None:
            from ..real_faces import RealFaces

            self.real = RealFaces(pack, split="train", flip=True)
            self.test = RealFaces(pack, split="test", flip=False)
            resolution = self.real.resolution
            person = self.real.arrays["person"]
            group = np.unique(person, return_inverse=True)[1]
            counts = np.bincount(group)
            # every k-th person with two photos stays out of R's training: the pack holds out
            # too few such people (the London set's 5 %) to measure R on
            self.r_excluded = pair_rows(self.real)[::r_exclude_every] if r_exclude_every else \
                np.zeros((0, 2), np.int64)
            left_out = np.isin(person, person[self.r_excluded[:, 0]])
            # crops of people with another photo: the real positives of R besides mirrors
            self.multi = np.flatnonzero((counts[group] > 1) & ~left_out)
            self.r_rows = np.flatnonzero(~left_out)
        self.synthetic_share = float(synthetic_share) if pack is not None else 1.0
        self.init, self.pack = init, pack
        self.data = SyntheticFaces(model=model, resolution=resolution, n_identities=n_identities,
                                   seed=seed)
        self.fresh = SyntheticFaces(model=model, resolution=resolution, n_identities=64,
                                    seed=seed + 7919)
        self.landmark_index = torch.as_tensor(np.flatnonzero(self.data.model.landmark_ids >= 0))
        self.step = 0

    def start(self, name, init):
        """Network ``name``: fresh of ``self.width``, or read from ``init/aux_<name>.pt``."""
        if init is None:
            self.widths[name] = self.width
            return build_aux(name, self.width)
        path = Path(init) / f"aux_{name}.pt"
        if not path.is_file():
            raise MorphableError(f"{path}: no aux weights to start from")
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        self.widths[name] = int(ckpt["width"])
        net = build_aux(name, self.widths[name])
        net.load_state_dict(ckpt["state_dict"])
        return net

    def losses(self, batch) -> dict:
        img, mask = batch["image"], batch["mask"]
        out = {}
        if "N" in self.nets:
            face = mask > 0.5
            if self.real is not None:
                # a fit's mask and normal map may disagree at its rim
                face = face & (batch["normals"].norm(dim=1, keepdim=True) > 0.5)
            face = face.to(img.dtype)
            cos = (self.nets["N"](img) * batch["normals"]).sum(1, keepdim=True)
            out["N"] = ((1 - cos) * face).sum() / face.sum().clamp_min(1)
        if "P" in self.nets:
            out["P"] = F.binary_cross_entropy_with_logits(self.nets["P"].logits(img), mask)
        if "L" in self.nets:
            if self.real is None:
                lm = self.nets["L"].landmarks(img)[:, self.landmark_index]
                target = batch["landmarks"][:, self.landmark_index]
                out["L"] = ((lm - target).pow(2).sum(-1) + 1e-8).sqrt().mean()
            else:
                # real crops: every finite landmark (detected sets lack some, synthetic
                # renders the ones the 3DMM does not define)
                target = batch["landmarks"]
                ok = torch.isfinite(target).all(-1)
                d = ((self.nets["L"].landmarks(img) - target.nan_to_num()).pow(2).sum(-1) + 1e-8).sqrt()
                out["L"] = (d * ok).sum() / ok.sum().clamp_min(1)
        if "R" in self.nets and self.real is None:
            pred = self.nets["R"].predict(img)
            out["R"] = F.mse_loss(pred, identity_labels(batch, pred.shape[1]))
        return out

    def identity_loss(self, rng, temperature: float = 0.1) -> torch.Tensor:
        """R on real identity: a contrastive (InfoNCE) loss over the batch, each crop's
        positive its second view (another photo of the person, else its mirror image), the
        other crops of other people its negatives. Half the batch is drawn from people with
        more than one photo, who would otherwise rarely appear."""
        B = self.batch_size
        index = self.r_rows[rng.integers(len(self.r_rows), size=B)]
        if len(self.multi):
            index[: B // 2] = self.multi[rng.integers(len(self.multi), size=B // 2)]
        flipped = rng.random(B) < 0.5
        other, mirrored = self.real.partner(index, rng)
        a = self.real.batch(index, flipped)
        b = self.real.batch(other, np.where(mirrored, ~flipped, rng.random(B) < 0.5))
        R = self.nets["R"]
        ea, eb = R(a["image"]), R(b["image"])
        person = a["identity_id"]
        logits = ea @ eb.T / temperature
        # another crop of the same person is not a negative
        clash = (person[:, None] == person[None, :]) & ~torch.eye(B, dtype=torch.bool)
        logits = logits.masked_fill(clash, float("-inf"))
        target = torch.arange(B)
        return 0.5 * (F.cross_entropy(logits, target) + F.cross_entropy(logits.T, target))

    def batch(self, rng_seed) -> dict:
        """The N, P, L batch of one step."""
        if self.real is None:
            return self.data.sample(self.batch_size, rng=rng_seed)
        n_syn = int(round(self.batch_size * self.synthetic_share))
        batch = self.real.sample(self.batch_size - n_syn, rng=rng_seed)
        if n_syn:
            syn = self.data.sample(n_syn, rng=rng_seed + [1])
            batch = {k: torch.cat([batch[k], syn[k]]) for k in ("image", "normals", "mask", "landmarks")}
        return batch

    def train_step(self) -> dict:
        for net in self.nets.values():
            net.train()
        seed = [self.seed, self.step]
        terms = self.losses(self.batch(seed)) if set(self.names) - {"R"} or self.real is None else {}
        if "R" in self.nets and self.real is not None:
            terms["R"] = self.identity_loss(np.random.default_rng(seed + [2]))
        # the landmark term is in pixels: divide by 10 to put it on the others' scale
        total = sum(0.1 * v if k == "L" else v for k, v in terms.items())
        self.opt.zero_grad(set_to_none=True)
        total.backward()
        self.opt.step()
        self.step += 1
        return {k: float(v.detach()) for k, v in terms.items()}

    @torch.no_grad()
    def validate(self, n: int = 32) -> dict:
        """Metrics per network on held-out renders (unseen seeds; R on unseen identities);
        with a real pack, on its held-out crops, the synthetic ones under ``"synthetic"``."""
        syn = synthetic_metrics(self.nets, self.data, self.fresh, self.landmark_index,
                                self.seed, n)
        if self.real is None:
            return syn
        out = real_metrics(self.nets, self.test, landmark_index=self.landmark_index)
        for name in out:
            out[name]["synthetic"] = syn[name]
        if "R" in out and len(self.r_excluded):
            out["R"]["excluded_people"] = self.excluded_verification()
        return out

    def excluded_verification(self) -> dict:
        """R's verification on the train-split people kept out of its training."""
        return pair_verification(self.nets["R"], self.real, self.r_excluded)

    def save(self, out, metrics=None) -> list:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        meta = {"steps": self.step, "batch_size": self.batch_size,
                "resolution": self.data.resolution, "model": self.data.model.name,
                "training_data": "SyntheticFaces (SFM, procedural albedo, SH light)"}
        if self.real is not None:
            meta.update(training_data=f"real pack {self.pack} (train split, flips) + "
                        f"{self.synthetic_share:.0%} SyntheticFaces renders in N, P, L batches",
                        init=None if self.init is None else str(self.init))
        # L states the landmarks it learnt, which the GAR's L_ldmk then compares: the model's
        # on synthetic renders, all 68 on real crops (where they are finite)
        index = self.landmark_index.tolist() if self.real is None else list(range(68))
        extra = {"L": {"landmark_index": index}}
        return [save_aux(self.nets[n], n, out / f"aux_{n}.pt", self.widths[n],
                         metrics=(metrics or {}).get(n, {}), **meta, **extra.get(n, {}))
                for n in self.names]


@one_line_errors("neural.gar.auxnets.train")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m neural.gar.auxnets.train", description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="folder for aux_N.pt, aux_P.pt, aux_L.pt, aux_R.pt")
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--width", type=int, default=16)
    p.add_argument("--identities", type=int, help="draw identities from a pool of this size "
                   "(default: a new identity per sample)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--save-every", type=int, default=200)
    p.add_argument("--nets", default="NPLR", help="which networks to train, e.g. R")
    p.add_argument("--threads", type=int)
    p.add_argument("--data", help="a real pack (neural.gar.real_faces): fine-tune on its train split")
    p.add_argument("--init", help="folder of aux_*.pt to start from (default with --data: the "
                   "committed neural/weights; without: fresh networks)")
    p.add_argument("--lr", type=float, help="Adam step (default 2e-3, with --data 5e-4)")
    p.add_argument("--synthetic-share", type=float, default=0.25,
                   help="with --data: fraction of synthetic renders in each N, P, L batch")
    p.add_argument("--max-minutes", type=float, help="stop after this much wall time")
    p.add_argument("--val-size", type=int, default=32, help="synthetic renders of the validation")
    p.add_argument("--r-exclude-every", type=int, default=0,
                   help="with --data: keep every k-th train-split person with two photos out of "
                        "R's training and report R on them (meta: R.excluded_people, _start)")
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    from tqdm import tqdm

    if args.threads:
        torch.set_num_threads(args.threads)
    unknown = set(args.nets) - set(NAMES)
    if unknown or not args.nets:
        raise MorphableError(f"--nets: choose letters from {''.join(NAMES)}, got {args.nets!r}")
    init = args.init
    if init is None and args.data:
        from ..paths import WEIGHTS_DIR

        init = WEIGHTS_DIR
    lr = args.lr if args.lr is not None else (5e-4 if args.data else 2e-3)
    t = AuxTrainer(args.resolution, args.width, args.identities, args.batch_size, lr=lr,
                   seed=args.seed, nets=tuple(dict.fromkeys(args.nets)), pack=args.data,
                   init=init, synthetic_share=args.synthetic_share,
                   r_exclude_every=args.r_exclude_every)
    start = t.excluded_verification() if "R" in t.nets and t.real is not None and \
        len(t.r_excluded) else None
    t0 = time.time()
    with tqdm(total=args.steps, disable=args.quiet, unit="step") as bar:
        while t.step < args.steps:
            if args.max_minutes is not None and time.time() - t0 > 60 * args.max_minutes:
                log.info("stopped at step %d after %.1f minutes", t.step, args.max_minutes)
                break
            terms = t.train_step()
            bar.update(1)
            bar.set_postfix({k: f"{v:.3f}" for k, v in terms.items()})
            if t.step % args.save_every == 0 and t.step < args.steps:
                t.save(args.out)
    metrics = t.validate(args.val_size)
    if start is not None:
        metrics["R"]["excluded_people_start"] = start
    for m in metrics.values():
        m["train_seconds"] = round(time.time() - t0, 1)
    t.save(args.out, metrics)
    print(json.dumps(metrics, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
