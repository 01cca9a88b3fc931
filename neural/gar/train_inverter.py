"""Train the inverting network V against a frozen GAR:
``python -m neural.gar.train_inverter --config tiny --generator runs/gar/generator.pt --out runs/inv``.

Normal maps come from :class:`neural.faces.renders.SyntheticFaces` (a fixed pool rendered once, since
rendering costs more than a step; a disjoint held-out pool for the report), or with
``--data PACK`` from the fits of real photos (:mod:`neural.gar.real_faces`: the pool from the
train split, the held-out maps from the test split); each step draws fresh latents ``z`` and
noise ``eps``, renders ``I = G(n, z, eps)`` and minimises :func:`neural.gar.inverter.inverter_loss`.

Outputs in ``--out``: ``inverter.pt`` (:func:`neural.gar.inverter.save_inverter`, with the
metrics and the generator path in its meta) and ``metrics.json``:
``z_mse`` = mean squared error of the pixel-normalised latents (what G sees; 0 is exact, a
latent unrelated to z gives 2), ``z_cosine`` (mean cosine of z_hat and z), ``image_l1`` =
mean ``|G(n, V.latent(I)) - G(n, z)|`` in [0, 1] units, ``image_l1_direction`` the same with
``PN(z_hat)`` alone, next to ``image_l1_random_z`` (a random latent), all on held-out
renders; and ``direction_cosine``, the calibration of :meth:`neural.gar.inverter.Inverter.latent`,
measured on renders of training normal maps after training (:func:`calibrate`).

With ``--data``, ``metrics.json`` also holds ``real`` (:func:`evaluate_real`): how well G
reconstructs the held-out real photos themselves from their fits' normal maps, with V's
latent, with the mean latent (``w = w_avg``) and with a latent optimised per photo.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import torch

from morphable.errors import one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity

from .networks import pixel_norm
from .inverter import Inverter, inverter_loss, save_inverter

__all__ = ["normal_pool", "pack_pool", "train", "calibrate", "evaluate_inverter", "evaluate_real",
           "main"]

log = logging.getLogger("neural.gar.train_inverter")


def normal_pool(config, n: int, seed: int) -> torch.Tensor:
    """(n, 3, R, R) camera-frame normal maps of random synthetic faces."""
    from ..faces.renders import SyntheticFaces

    faces = SyntheticFaces.from_config(config)
    return faces.sample(n, rng=seed)["normals"]


def pack_pool(faces, held_out: bool, n: int, seed: int) -> dict:
    """Up to ``n`` crops of the train (``held_out=False``) or test split of ``faces``, a
    :class:`neural.gar.real_faces.RealFaces` of a whole pack (a seeded choice without
    replacement): ``normals`` (n, 3, R, R) and ``image`` (n, 3, R, R) in [-1, 1]."""
    import numpy as np

    candidates = np.flatnonzero(faces.arrays["held_out"] == held_out)
    rng = np.random.default_rng(seed)
    index = rng.choice(len(candidates), size=min(int(n), len(candidates)), replace=False)
    batch = faces.batch(candidates[np.sort(index)])
    return {"normals": batch["normals"], "image": batch["image"]}


def evaluate_real(V, G, normals, images, steps: int = 100, lr: float = 0.05, seed: int = 1) -> dict:
    """Reconstruction of real photos ``images`` (B, 3, R, R) in [-1, 1] from their fits'
    ``normals`` (B, 3, R, R): mean ``|G(n, z) - I|`` in [0, 1] units over the crop (G renders
    the background too), noise zero, for z = V's calibrated latent (``image_l1_v``), the
    mean latent w = w_avg (``image_l1_mean``) and a latent optimised per photo by Adam from
    V's (``steps``, ``lr``; ``image_l1_optimised``), and V's error relative to the other two
    (``v_over_mean``, ``v_over_optimised``)."""
    g = torch.Generator().manual_seed(seed)

    def l1(image):
        return (image - images).abs().mean((1, 2, 3)) / 2

    with torch.no_grad():
        z_v = V.latent(images, generator=g)
        e_v = float(l1(G(normals, z_v, noise="zero")).mean())
        w_mean = G.w_avg[None].expand(len(images), -1)
        e_mean = float(l1(G.synthesis(normals, w_mean, noise="zero")).mean())
    z = z_v.clone().requires_grad_(True)
    opt = torch.optim.Adam([z], lr=lr)
    for _ in range(steps):
        loss = l1(G(normals, z, noise="zero")).sum()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    with torch.no_grad():
        e_opt = float(l1(G(normals, z, noise="zero")).mean())
    return {"image_l1_v": e_v, "image_l1_mean": e_mean, "image_l1_optimised": e_opt,
            "v_over_mean": e_v / e_mean, "v_over_optimised": e_v / e_opt,
            "optimiser_steps": steps, "n_photos": len(images)}


@torch.no_grad()
def evaluate_inverter(V, G, normals, seed: int = 1) -> dict:
    """Latent and image errors of V on renders of ``normals`` (see the module docstring)."""
    g = torch.Generator().manual_seed(seed)
    z = torch.randn(len(normals), G.config.z_dim, generator=g).to(normals.device)
    z_rand = torch.randn(len(normals), G.config.z_dim, generator=g).to(normals.device)
    image = G(normals, z, noise="zero")
    z_hat, _ = V(image)
    mse = float((pixel_norm(z_hat) - pixel_norm(z)).pow(2).mean())
    cos = float(torch.nn.functional.cosine_similarity(z_hat, z, dim=1).mean())

    def l1(latent):
        return float((G(normals, latent, noise="zero") - image).abs().mean() / 2)

    return {"z_mse": mse, "z_cosine": cos, "image_l1": l1(V.latent(image, generator=g)),
            "image_l1_direction": l1(pixel_norm(z_hat)), "image_l1_random_z": l1(z_rand),
            "direction_cosine": float(V.direction_cosine), "n_held_out": len(normals)}


@torch.no_grad()
def calibrate(V, G, normals, seed: int = 2) -> float:
    """Set ``V.direction_cosine`` to the mean cosine of ``PN(z_hat)`` and ``z`` on renders of
    ``normals`` (training normal maps, fresh latents) and return it."""
    z = torch.randn(len(normals), G.config.z_dim, generator=torch.Generator().manual_seed(seed))
    z_hat, _ = V(G(normals, z.to(normals.device), noise="zero"))
    z = z.to(z_hat.device)
    c = float(torch.nn.functional.cosine_similarity(z_hat, z, dim=1).mean())
    V.direction_cosine.fill_(max(c, 0.0))
    return c


def train(G, *, steps: int = 500, batch_size: int = 8, lr: float = 1e-3, pool: int = 96,
          held_out: int = 32, seed: int = 0, max_minutes: float | None = None, progress=True,
          data=None, device="cpu", eval_steps: int = 100):
    """Train V for ``steps`` (or ``max_minutes``) -> (V, metrics dict, loss log list).

    ``data``: a :mod:`neural.gar.real_faces` pack whose fits' normal maps replace the
    synthetic ones (train split for training, test split held out; a pack at a multiple of
    G's resolution is area-downsampled); then the metrics also hold ``real``
    (:func:`evaluate_real` on the held-out photos, ``eval_steps`` optimiser steps). ``device``: where V trains (G is moved
    there); the returned V is on the CPU, and the draws are the same on any device."""
    from ..training import device_from, read_terms, to_device

    cfg = G.config
    device = device_from(device)
    torch.manual_seed(seed)
    if data is None:
        train_n = normal_pool(cfg, pool, seed)
        test_n = normal_pool(cfg, held_out, seed + 10_000)
    else:
        from .real_faces import RealFaces

        faces = RealFaces(data, split="all", flip=False,      # the pack decoded once
                          resolution=cfg.resolution)
        train_n = pack_pool(faces, False, pool, seed)["normals"]
        test = pack_pool(faces, True, held_out, seed + 10_000)
        test_n = test["normals"]
    G = G.to(device)
    train_n, test_n = train_n.to(device), test_n.to(device)
    V = Inverter(cfg).to(device)
    opt = torch.optim.Adam(V.parameters(), lr=lr, betas=(0.9, 0.99))
    rng = torch.Generator().manual_seed(seed)
    history, t0 = [], time.perf_counter()
    bar = range(steps)
    if progress:
        from tqdm import tqdm

        bar = tqdm(bar, desc="inverter", file=sys.stderr)
    for step in bar:
        # CPU draws (the same on any device), copied without a wait for the GPU
        idx = to_device(torch.randint(len(train_n), (batch_size,), generator=rng), device)
        z = to_device(torch.randn(batch_size, cfg.z_dim, generator=rng), device)
        noise = G.make_noise(batch_size, generator=rng)
        loss, parts = inverter_loss(V, G, train_n[idx], z, noise)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        history.append({"step": step, **parts})      # 0-d tensors: read once, at the end
        if max_minutes and time.perf_counter() - t0 > 60 * max_minutes:
            log.info("time budget reached after %d steps", step + 1)
            break
    history = read_terms(history)
    V.eval().requires_grad_(False)
    calibrate(V, G, train_n[:held_out])
    metrics = evaluate_inverter(V, G, test_n)
    metrics.update(steps=len(history), seconds=round(time.perf_counter() - t0, 1))
    if data is not None:
        metrics["real"] = evaluate_real(V, G, test_n, test["image"].to(device), steps=eval_steps)
    return V.cpu(), metrics, history


def build_parser():
    p = argparse.ArgumentParser(prog="python -m neural.gar.train_inverter",
                                description=__doc__.splitlines()[0])
    p.add_argument("--config", default="tiny", help="GAR config of an untrained generator "
                                                    "(ignored with --generator)")
    p.add_argument("--generator", help="generator.pt of neural.gar.train (default: the gar renderer's "
                                       "weights)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--data", help="a neural.gar.real_faces pack: normal maps of real photos' fits "
                                  "instead of synthetic ones (e.g. gar_data/real64.npz)")
    p.add_argument("--pool", type=int, default=96, help="training normal maps")
    p.add_argument("--held-out", type=int, default=32, help="held-out normal maps for the report")
    p.add_argument("--max-minutes", type=float)
    p.add_argument("--threads", type=int)
    p.add_argument("--device", default="cpu", help="torch device, e.g. cuda")
    p.add_argument("--eval-steps", type=int, default=100,
                   help="optimiser steps per held-out photo in the --data report")
    p.add_argument("--seed", type=int, default=0)
    add_verbosity_arguments(p)
    return p


@one_line_errors("neural.gar.train_inverter")
def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure(verbosity(args))
    if args.threads:
        torch.set_num_threads(args.threads)
    from .renderer import GARRenderer
    from ..training import device_from, read_terms, to_device

    device_from(args.device)             # a one-line error before any loading

    r = GARRenderer(weights=args.generator) if args.generator else GARRenderer()
    G = r.generator
    if G.config.name != args.config and not args.generator:
        log.warning("generator config %s differs from --config %s", G.config.name, args.config)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    V, metrics, history = train(G, steps=args.steps, batch_size=args.batch_size, lr=args.lr,
                                pool=args.pool, held_out=args.held_out, seed=args.seed,
                                max_minutes=args.max_minutes, data=args.data,
                                device=args.device, eval_steps=args.eval_steps)
    metrics["generator"] = r.weights
    save_inverter(V, out / "inverter.pt", metrics=metrics)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    with open(out / "log.jsonl", "w") as f:
        f.writelines(json.dumps(h) + "\n" for h in history)
    print(json.dumps(metrics))
    return 0


if __name__ == "__main__":
    sys.exit(main())
