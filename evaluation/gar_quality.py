"""Quality report of a trained GAR: ``python -m evaluation.gar_quality --report gar.json``.

On held-out synthetic faces (seeds never used in training) it measures, for each renderer
(``gar``; ``gar_no_norm_cycle``, the GAR trained with lambda_n = 0; ``classical``, the
Lambertian renderer — the synthetic renders themselves):

- ``normal_consistency_deg``: mean angle between the input normal map and ``N(image)`` over
  pixels that are face in both the input and ``P(image)``;
- ``landmark_consistency_px`` (GARs): mean distance of ``L(G(n, z_i))`` to their mean over
  8 latents ``z_i``, on the landmarks the 3DMM defines;
- ``identity_consistency_cos``: mean cosine of ``R`` embeddings of one identity in two
  poses/expressions (same latent);
- ``fid_aux``: Frechet distance between ``R``-embedding statistics of the renderer's images
  and of held-out synthetic renders (for the classical renderer: two disjoint sets) — **not**
  the Inception FID of the literature, which needs weights that cannot be downloaded here;
- :func:`face_fd` (a function for real crops, not in this report): the same distance in dlib's
  128-D face-descriptor space, also not Inception FID;
- ``fid_inception`` with ``--inception FILE``: the same distance in the 2048-d pool features
  of a user-supplied Inception-v3 TorchScript file (e.g. the ``pt_inception-2015-12-05``
  network that clean-fid and torch-fidelity download), images resized to 299 px.

The JSON is metric-major: ``{"normal_consistency_deg": {"gar", "gar_no_norm_cycle",
"classical"}, "landmark_consistency_px": {...}, ...}``. Also a Figure-3-like grid (one normal
map, 8 latents). The numbers are only as good as the aux networks; their own validation
metrics are copied into the report.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from morphable.errors import MorphableError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity
from neural.auxnets import NAMES, load_aux
from neural.checkpoint import GENERATOR_FILE, default_no_norm_cycle_path, load_generator

__all__ = ["normal_consistency", "landmark_consistency",
           "identity_consistency", "frechet_distance", "face_fd", "load_inception", "inception_features",
           "evaluate", "main"]

METRICS = ("normal_consistency_deg", "landmark_consistency_px", "identity_consistency_cos",
           "fid_aux", "fid_inception")


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


def face_fd(images_a, images_b, model: str = "sfm") -> float:
    """"face-FD": the Frechet distance between dlib's 128-D face descriptors of two sets of
    aligned crops in our framing (:func:`evaluation.face_descriptor.aligned_descriptors`: no
    detection, dlib's chip cut where the framing puts the eyes and nose), e.g. GAR samples
    against held-out real crops. **Not** the Inception FID of the literature (whose weights
    cannot be downloaded here): a distance in an identity space, blind to much of what
    Inception sees (background, colour) and in other units (two disjoint sets of real faces
    are far from 0 when the sets are small: it is biased upwards by few samples, like any FD).

    ``images_a``, ``images_b``: (N, 3, R, R) in [-1, 1] (tensors or arrays) or (N, R, R, 3)
    uint8; N > 1 each, ideally several hundred (128 dimensions)."""
    from .face_descriptor import aligned_descriptors

    return frechet_distance(aligned_descriptors(images_a, model), aligned_descriptors(images_b, model))


def load_inception(path):
    """A user-supplied Inception feature network: a TorchScript file whose output, or whose
    first output, is (B, D) or (B, D, 1, 1) features for (B, 3, 299, 299) images."""
    from morphable.errors import InputError

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: Inception weights not found")
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)   # torch.jit's deprecation notice
            return torch.jit.load(str(path), map_location="cpu").eval()
    except Exception:
        raise InputError(f"{path}: not a TorchScript Inception network") from None


@torch.no_grad()
def inception_features(net, images, batch_size: int = 16) -> np.ndarray:
    """(N, 3, R, R) images in [-1, 1] -> (N, D) features of ``net`` at 299 px.

    clean-fid's and torch-fidelity's TorchScript Inception take uint8-range [0, 255] input
    and resize themselves; we hand them 299 px images in that range."""
    out = []
    for chunk in images.split(batch_size):
        x = torch.nn.functional.interpolate((chunk.clamp(-1, 1) + 1) * 127.5, size=(299, 299),
                                           mode="bilinear", align_corners=False)
        f = net(x)
        f = f[0] if isinstance(f, (tuple, list)) else f
        out.append(f.reshape(len(chunk), -1))
    return torch.cat(out).numpy()


def _grid(G, normals, path, n_latents=8, seed=0):
    from neural.train import normal_to_rgb, save_grid

    gen = torch.Generator().manual_seed(seed)
    z = torch.randn(n_latents, G.config.z_dim, generator=gen)
    with torch.no_grad():
        imgs = G(normals[None].expand(n_latents, -1, -1, -1), z, noise=G.make_noise(n_latents, gen))
    save_grid(torch.cat([normal_to_rgb(normals[None]), imgs]), path, ncol=n_latents + 1)


@torch.no_grad()
def evaluate(generators: dict, aux: dict, n_faces: int = 64, n_latents: int = 8, seed=12345,
             grid=None, batch_size: int = 16, inception=None) -> dict:
    """Metrics of each generator in ``generators`` (name -> Generator) and of the classical
    Lambertian renders (``"classical"``) on ``n_faces`` held-out synthetic faces (pairs):
    ``{metric: {renderer: value}}`` for the metrics of :data:`METRICS`; ``inception`` (a
    feature network, see :func:`load_inception`) adds ``fid_inception``."""
    from neural.data import SyntheticFaces

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
    per = {"classical": {
        "normal_consistency_deg": normal_consistency(images, normals, aux),
        "identity_consistency_cos": identity_consistency(images, images_b, aux),
        "fid_aux": frechet_distance(emb(images), emb(real))}}
    if inception is not None:
        real_feats = inception_features(inception, real, batch_size)
        per["classical"]["fid_inception"] = frechet_distance(
            inception_features(inception, images, batch_size), real_feats)
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
        per[name] = {
            "normal_consistency_deg": normal_consistency(fake, normals, aux),
            "landmark_consistency_px": landmark_consistency(per_latent, aux, index),
            "identity_consistency_cos": identity_consistency(fake, fake_b, aux),
            "fid_aux": frechet_distance(emb(fake), emb(real)),
        }
        if inception is not None:
            per[name]["fid_inception"] = frechet_distance(
                inception_features(inception, fake, batch_size), real_feats)
    report = {"n_faces": n_faces, "n_latents": n_latents, "resolution": cfg.resolution}
    for metric in METRICS:
        values = {r: m[metric] for r, m in per.items() if metric in m}
        if values:
            report[metric] = values
    if grid is not None:
        _grid(next(iter(generators.values())), normals[0], grid, n_latents)
        report["grid"] = str(grid)
    return report


@one_line_errors("evaluation.gar_quality")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.gar_quality",
                                description=__doc__.splitlines()[0])
    p.add_argument("--report", required=True, help="output JSON")
    p.add_argument("--generator", default=str(GENERATOR_FILE))
    p.add_argument("--ablation", default="auto",
                   help="generator trained with lambda_n = 0, reported as gar_no_norm_cycle "
                        "(default: the committed weights/gar_tiny_no_norm_cycle.pt if present; "
                        "'none' to leave it out)")
    p.add_argument("--inception", help="TorchScript Inception-v3 features (clean-fid's / "
                                       "torch-fidelity's file) for fid_inception")
    p.add_argument("--aux-dir", help="folder with aux_*.pt (default: neural/weights)")
    p.add_argument("--grid", help="Figure-3-like PNG (default: beside the report)")
    p.add_argument("--raw", action="store_true",
                   help="checkpoints: evaluate the raw generator, not its moving average")
    p.add_argument("--faces", type=int, default=64)
    p.add_argument("--seed", type=int, default=12345)
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    gens = {"gar": load_generator(args.generator, not args.raw)}
    ablation = args.ablation
    if ablation == "auto":
        ablation = default_no_norm_cycle_path()
    if ablation and str(ablation) != "none":
        gens["gar_no_norm_cycle"] = load_generator(ablation, not args.raw)
    inception = load_inception(args.inception) if args.inception else None
    aux = {n: load_aux(n, None if args.aux_dir is None else Path(args.aux_dir) / f"aux_{n}.pt",
                       resolution=gens["gar"].config.resolution) for n in NAMES}
    out = Path(args.report)
    grid = Path(args.grid) if args.grid else out.with_suffix(".png")
    report = evaluate(gens, aux, n_faces=args.faces, seed=args.seed, grid=grid,
                      inception=inception)
    # the validation metrics our checkpoints store (None for other networks)
    report["aux_validation"] = {n: getattr(aux[n], "meta", {}).get("metrics") for n in NAMES}
    report["generators"] = {"gar": str(args.generator),
                            "gar_no_norm_cycle": str(ablation) if "gar_no_norm_cycle" in gens else None}
    from morphable.io.atomic import atomic_path

    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
