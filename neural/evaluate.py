"""Quality report of a trained GAR: ``python -m neural.evaluate --report gar.json``.

On held-out synthetic faces (seeds never used in training) it measures, for each renderer
(the GAR, optionally the GAR trained with lambda_n = 0, and the classical Lambertian renderer
— the synthetic renders themselves):

- ``normal_consistency_deg``: mean angle between the input normal map and ``N(image)`` over
  pixels that are face in both the input and ``P(image)``;
- ``landmark_consistency_px`` (GARs): mean distance of ``L(G(n, z_i))`` to their mean over
  8 latents ``z_i``, on the landmarks the 3DMM defines;
- ``identity_consistency_cos``: mean cosine of ``R`` embeddings of one identity in two
  poses/expressions (same latent);
- ``fid_aux``: Frechet distance between ``R``-embedding statistics of the renderer's images
  and of held-out synthetic renders (for the classical renderer: two disjoint sets).

and writes a Figure-3-like grid (one normal map, 8 latents). The numbers are only as good
as the aux networks; their own validation metrics are copied into the report.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from morphable.errors import MorphableError

from .auxnets import NAMES, load_aux
from .checkpoint import load_network
from .config import GARConfig
from .gar import Generator

__all__ = ["load_generator", "normal_consistency", "landmark_consistency",
           "identity_consistency", "frechet_distance", "evaluate", "main"]


def load_generator(path, ema: bool = True) -> Generator:
    """A Generator (eval mode) from ``generator.pt`` or ``checkpoint.pt`` of neural.train;
    from a checkpoint, ``ema=False`` takes the raw generator instead of its moving average."""
    def build(ckpt):
        G = Generator(GARConfig.from_dict(ckpt["config"]))
        G.load_state_dict(ckpt["G_ema"] if ema and "G_ema" in ckpt else ckpt["G"])
        return G

    return load_network(path, build, "generator weights not found", "not a GAR checkpoint")


@torch.no_grad()
def normal_consistency(images, normals, aux) -> float:
    """Mean angle (degrees) between ``normals`` (B, 3, R, R) and ``N(images)`` where both the
    input (non-zero normal) and ``P(images) > 0.5`` say face."""
    pred = aux["N"](images)
    face = (normals.norm(dim=1) > 0.5) & (aux["P"](images)[:, 0] > 0.5)
    if not face.any():
        raise MorphableError("normal consistency: no pixel is face in both the input and P(image)")
    cos = (pred * torch.nn.functional.normalize(normals, dim=1)).sum(1).clamp(-1, 1)
    return float(torch.rad2deg(torch.acos(cos[face])).mean())


@torch.no_grad()
def landmark_consistency(images_per_latent, aux, index=None) -> float:
    """``images_per_latent`` (K, B, 3, R, R): the same B normal maps under K latents ->
    mean pixel distance of each latent's landmarks to their mean over latents."""
    K, B = images_per_latent.shape[:2]
    lm = aux["L"].landmarks(images_per_latent.flatten(0, 1)).reshape(K, B, -1, 2)
    if index is not None:
        lm = lm[:, :, index]
    return float((lm - lm.mean(0, keepdim=True)).norm(dim=-1).mean())


@torch.no_grad()
def identity_consistency(images_a, images_b, aux) -> float:
    """Mean cosine similarity of ``R`` embeddings of paired images (B, 3, R, R)."""
    ea, eb = aux["R"](images_a), aux["R"](images_b)
    return float(torch.nn.functional.cosine_similarity(ea, eb, dim=-1).mean())


def frechet_distance(feats_a, feats_b) -> float:
    """Frechet distance between Gaussians fitted to (N, D) feature sets:
    ``|mu_a - mu_b|^2 + tr(S_a + S_b - 2 (S_a S_b)^(1/2))``."""
    from scipy import linalg

    a = np.asarray(feats_a, dtype=np.float64)
    b = np.asarray(feats_b, dtype=np.float64)
    mu = a.mean(0) - b.mean(0)
    sa, sb = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
    root = linalg.sqrtm(sa @ sb)
    if not np.isfinite(root).all():
        eps = 1e-6 * np.eye(len(sa))
        root = linalg.sqrtm((sa + eps) @ (sb + eps))
    return float(mu @ mu + np.trace(sa + sb - 2 * root.real))


def _grid(G, normals, path, n_latents=8, seed=0):
    from .train import normal_to_rgb, save_grid

    gen = torch.Generator().manual_seed(seed)
    z = torch.randn(n_latents, G.config.z_dim, generator=gen)
    with torch.no_grad():
        imgs = G(normals[None].expand(n_latents, -1, -1, -1), z, noise=G.make_noise(n_latents, gen))
    save_grid(torch.cat([normal_to_rgb(normals[None]), imgs]), path, ncol=n_latents + 1)


@torch.no_grad()
def evaluate(generators: dict, aux: dict, n_faces: int = 64, n_latents: int = 8, seed=12345,
             grid=None, batch_size: int = 16) -> dict:
    """Metrics of each generator in ``generators`` (name -> Generator) and of the classical
    Lambertian renders on ``n_faces`` held-out synthetic faces (pairs)."""
    from .data import SyntheticFaces

    cfg = next(iter(generators.values())).config
    data = SyntheticFaces.from_config(cfg)
    index = torch.as_tensor(np.flatnonzero(data.model.landmark_ids >= 0))
    batches = [data.sample(min(batch_size, n_faces - i), rng=[seed, i], pair=True)
               for i in range(0, n_faces, batch_size)]
    real = torch.cat([data.sample(min(batch_size, n_faces - i), rng=[seed + 1, i])["image"]
                      for i in range(0, n_faces, batch_size)])
    cat = lambda k: torch.cat([b[k] for b in batches])  # noqa: E731
    normals, normals_b, images, images_b = cat("normals"), cat("normals_b"), cat("image"), cat("image_b")
    emb = lambda x: torch.cat([aux["R"](c) for c in x.split(batch_size)]).numpy()  # noqa: E731
    report = {"n_faces": n_faces, "n_latents": n_latents, "resolution": cfg.resolution,
              "classical_lambertian": {
                  "normal_consistency_deg": normal_consistency(images, normals, aux),
                  "identity_consistency_cos": identity_consistency(images, images_b, aux),
                  "fid_aux": frechet_distance(emb(images), emb(real))}}
    for name, G in generators.items():
        # the same latents and noise for every generator: differences come from the weights
        gen = torch.Generator().manual_seed(seed)
        z = torch.randn(n_faces, cfg.z_dim, generator=gen)
        noise = G.make_noise(batch_size, gen)

        def run(n, zz):
            return G(n, zz, noise=[e[: len(n)] for e in noise])

        fake = torch.cat([run(n, zz) for n, zz in zip(normals.split(batch_size), z.split(batch_size))])
        fake_b = torch.cat([run(n, zz) for n, zz in zip(normals_b.split(batch_size), z.split(batch_size))])
        k_faces = min(n_faces, batch_size)
        zs = torch.randn(n_latents, k_faces, cfg.z_dim, generator=gen)
        per_latent = torch.stack([run(normals[:k_faces], zk) for zk in zs])
        report[name] = {
            "normal_consistency_deg": normal_consistency(fake, normals, aux),
            "landmark_consistency_px": landmark_consistency(per_latent, aux, index),
            "identity_consistency_cos": identity_consistency(fake, fake_b, aux),
            "fid_aux": frechet_distance(emb(fake), emb(real)),
        }
    if grid is not None:
        _grid(next(iter(generators.values())), normals[0], grid, n_latents)
        report["grid"] = str(grid)
    return report


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m neural.evaluate", description=__doc__.splitlines()[0])
    p.add_argument("--report", required=True, help="output JSON")
    p.add_argument("--generator", default=str(Path(__file__).parent / "weights" / "gar_tiny.pt"))
    p.add_argument("--ablation", help="generator trained with lambda_n = 0 (reported as gar_lambda_n0)")
    p.add_argument("--aux-dir", help="folder with aux_*.pt (default: neural/weights)")
    p.add_argument("--grid", help="Figure-3-like PNG (default: beside the report)")
    p.add_argument("--raw", action="store_true",
                   help="checkpoints: evaluate the raw generator, not its moving average")
    p.add_argument("--faces", type=int, default=64)
    p.add_argument("--seed", type=int, default=12345)
    args = p.parse_args(argv)
    try:
        gens = {"gar": load_generator(args.generator, not args.raw)}
        if args.ablation:
            gens["gar_lambda_n0"] = load_generator(args.ablation, not args.raw)
        aux = {n: load_aux(n, None if args.aux_dir is None else Path(args.aux_dir) / f"aux_{n}.pt",
                           resolution=gens["gar"].config.resolution) for n in NAMES}
        out = Path(args.report)
        grid = Path(args.grid) if args.grid else out.with_suffix(".png")
        report = evaluate(gens, aux, n_faces=args.faces, seed=args.seed, grid=grid)
        meta_path = Path(args.aux_dir or Path(__file__).parent / "weights") / "aux_N.pt"
        if meta_path.is_file():
            report["aux_validation"] = torch.load(meta_path, weights_only=True).get("meta", {})
        from morphable.io.atomic import atomic_path

        with atomic_path(out) as tmp:
            tmp.write_text(json.dumps(report, indent=1) + "\n")
        print(json.dumps(report, indent=1))
        return 0
    except MorphableError as e:
        print(f"neural.evaluate: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
