"""Train the auxiliary networks N, P, L, R on synthetic renders with exact labels:
``python -m neural.auxnets.train --out neural/weights --steps 2000``.

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

__all__ = ["AuxTrainer", "identity_labels", "main"]

log = logging.getLogger("neural.auxnets.train")


def identity_labels(batch, dim: int) -> torch.Tensor:
    """R's regression target (B, dim): skin tone, then the first ``dim - 1`` identity
    coefficients (std units)."""
    return torch.cat([batch["skin_tone"][:, None], batch["identity"][:, :dim - 1]], 1)


class AuxTrainer:
    """Joint training of N, P, L, R on one stream of synthetic batches."""

    def __init__(self, resolution=64, width=16, n_identities=None, batch_size=16, lr=2e-3,
                 seed=0, model="sfm", nets=NAMES):
        from ..data import SyntheticFaces

        torch.manual_seed(seed)
        self.width, self.batch_size, self.seed = width, batch_size, seed
        self.names = tuple(nets)
        self.nets = {n: build_aux(n, width) for n in self.names}
        params = [p for net in self.nets.values() for p in net.parameters()]
        self.opt = torch.optim.Adam(params, lr=lr)
        self.data = SyntheticFaces(model=model, resolution=resolution, n_identities=n_identities,
                                   seed=seed)
        self.fresh = SyntheticFaces(model=model, resolution=resolution, n_identities=64,
                                    seed=seed + 7919)
        self.landmark_index = torch.as_tensor(np.flatnonzero(self.data.model.landmark_ids >= 0))
        self.step = 0

    def losses(self, batch) -> dict:
        img, mask = batch["image"], batch["mask"]
        out = {}
        if "N" in self.nets:
            face = (mask > 0.5).to(img.dtype)
            cos = (self.nets["N"](img) * batch["normals"]).sum(1, keepdim=True)
            out["N"] = ((1 - cos) * face).sum() / face.sum().clamp_min(1)
        if "P" in self.nets:
            out["P"] = F.binary_cross_entropy_with_logits(self.nets["P"].logits(img), mask)
        if "L" in self.nets:
            lm = self.nets["L"].landmarks(img)[:, self.landmark_index]
            target = batch["landmarks"][:, self.landmark_index]
            out["L"] = ((lm - target).pow(2).sum(-1) + 1e-8).sqrt().mean()
        if "R" in self.nets:
            pred = self.nets["R"].predict(img)
            out["R"] = F.mse_loss(pred, identity_labels(batch, pred.shape[1]))
        return out

    def train_step(self) -> dict:
        for net in self.nets.values():
            net.train()
        batch = self.data.sample(self.batch_size, rng=[self.seed, self.step])
        terms = self.losses(batch)
        # the landmark term is in pixels: divide by 10 to put it on the others' scale
        total = sum(0.1 * v if k == "L" else v for k, v in terms.items())
        self.opt.zero_grad(set_to_none=True)
        total.backward()
        self.opt.step()
        self.step += 1
        return {k: float(v.detach()) for k, v in terms.items()}

    @torch.no_grad()
    def validate(self, n: int = 32) -> dict:
        """Metrics on held-out renders (unseen seeds; R on unseen identities), per network."""
        for net in self.nets.values():
            net.eval()
        b = self.data.sample(n, rng=[self.seed, 2**31])
        face = b["mask"][:, 0] > 0.5
        out = {}
        if "N" in self.nets:
            cos = (self.nets["N"](b["image"]) * b["normals"]).sum(1).clamp(-1, 1)
            out["N"] = {"normal_error_deg": float(torch.rad2deg(torch.acos(cos[face])).mean())}
        if "P" in self.nets:
            pred = self.nets["P"](b["image"])[:, 0] > 0.5
            out["P"] = {"mask_iou": float((pred & face).sum() / (pred | face).sum().clamp_min(1))}
        if "L" in self.nets:
            lm = self.nets["L"].landmarks(b["image"])[:, self.landmark_index]
            err = (lm - b["landmarks"][:, self.landmark_index]).norm(dim=-1).mean()
            out["L"] = {"landmark_error_px": float(err)}
        if "R" in self.nets:
            # verification on unseen identities: the AUC of same-identity pairs (two views)
            # against different-identity pairs
            p = self.fresh.sample(n, rng=[self.seed, 2**31 + 1], pair=True)
            R = self.nets["R"]
            pred = R.predict(p["image"])
            truth = identity_labels(p, pred.shape[1])
            explained = 1 - float((pred - truth).pow(2).mean() / truth.pow(2).mean())
            ea, eb = F.normalize(pred, dim=1), R(p["image_b"])
            same = (ea * eb).sum(1)
            diff = (ea @ eb.T)[~torch.eye(n, dtype=torch.bool)]
            auc = (same[:, None] > diff[None, :]).float().mean()
            out["R"] = {"identity_verification_auc": float(auc),
                        "identity_cos_same": float(same.mean()),
                        "identity_cos_diff": float(diff.mean()),
                        "identity_variance_explained": explained}
        return out

    def save(self, out, metrics=None) -> list:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        meta = {"steps": self.step, "batch_size": self.batch_size,
                "resolution": self.data.resolution, "model": self.data.model.name,
                "training_data": "SyntheticFaces (SFM, procedural albedo, SH light)"}
        # L states the landmarks it learnt (the model's), which the GAR's L_ldmk then compares
        extra = {"L": {"landmark_index": self.landmark_index.tolist()}}
        return [save_aux(self.nets[n], n, out / f"aux_{n}.pt", self.width,
                         metrics=(metrics or {}).get(n, {}), **meta, **extra.get(n, {}))
                for n in self.names]


@one_line_errors("neural.auxnets.train")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m neural.auxnets.train", description=__doc__.splitlines()[0])
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
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    from tqdm import tqdm

    if args.threads:
        torch.set_num_threads(args.threads)
    unknown = set(args.nets) - set(NAMES)
    if unknown or not args.nets:
        raise MorphableError(f"--nets: choose letters from {''.join(NAMES)}, got {args.nets!r}")
    t = AuxTrainer(args.resolution, args.width, args.identities, args.batch_size,
                   seed=args.seed, nets=tuple(dict.fromkeys(args.nets)))
    t0 = time.time()
    with tqdm(total=args.steps, disable=args.quiet, unit="step") as bar:
        while t.step < args.steps:
            terms = t.train_step()
            bar.update(1)
            bar.set_postfix({k: f"{v:.3f}" for k, v in terms.items()})
            if t.step % args.save_every == 0 and t.step < args.steps:
                t.save(args.out)
    metrics = t.validate()
    for m in metrics.values():
        m["train_seconds"] = round(time.time() - t0, 1)
    t.save(args.out, metrics)
    print(json.dumps(metrics, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
