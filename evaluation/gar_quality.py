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
- ``face_fd`` (``--data`` only): the same distance in dlib's 128-D face-descriptor space
  (:func:`face_fd`), also not Inception FID;
- ``fid_inception`` with ``--inception FILE``: the same distance in the 2048-d pool features
  of a user-supplied Inception-v3 TorchScript file (e.g. the ``pt_inception-2015-12-05``
  network that clean-fid and torch-fidelity download), images resized to 299 px.

With ``--data PACK`` (a :mod:`neural.gar.real_faces` pack) the faces are the pack's held-out real
photos instead: the normal maps are their fits', the second view is another photo of the
person or the mirror image, and the reference images of ``fid_aux`` / ``face_fd`` are the
photos of one half of the held-out split while every renderer draws the other half's normal
maps. The baselines are then ``photos`` (the other half's photos themselves: the floor of
each metric, as far as the aux networks and the fits allow) and ``classical`` (the fits'
normal maps Lambert-shaded with one skin colour and one light on grey: geometry alone).

The JSON is metric-major: ``{"normal_consistency_deg": {"gar", "gar_no_norm_cycle",
"classical"}, "landmark_consistency_px": {...}, ...}``. Also a Figure-3-like grid
(:func:`sample_grid`: four normal maps, six latents). The numbers are only as good as the aux
networks; their own validation metrics are copied into the report.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from morphable.errors import InputError, MorphableError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity
from neural.gar.auxnets import NAMES, load_aux
from neural.gar.paths import GENERATOR_FILE, default_no_norm_cycle_path
from neural.gar.networks import load_generator

__all__ = ["normal_consistency", "landmark_consistency", "lambert", "synthetic_faces", "real_faces",
           "identity_consistency", "frechet_distance", "face_fd", "sample_grid", "load_inception",
           "inception_features", "evaluate", "main"]

METRICS = ("normal_consistency_deg", "landmark_consistency_px", "identity_consistency_cos",
           "fid_aux", "face_fd", "fid_inception")
"""The report's metrics, in its order."""

SKIN_RGB = (0.78, 0.57, 0.45)
"""Albedo of the ``classical`` renders of real photos' normal maps (linear RGB)."""


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


def sample_grid(G, normals, path, n_latents: int = 6, seed: int = 0) -> Path:
    """The paper's Figure-3 layout: a row per normal map of ``normals`` (F, 3, R, R), the map
    then ``G`` under the same ``n_latents`` latents (and noise) in every row; a PNG."""
    from neural.gar.train import normal_to_rgb, save_grid

    gen = torch.Generator().manual_seed(seed)
    z = torch.randn(n_latents, G.config.z_dim, generator=gen)
    noise = G.make_noise(n_latents, gen)
    rows = []
    with torch.no_grad():
        for n in normals:
            images = G(n[None].expand(n_latents, -1, -1, -1), z, noise=noise)
            # a G of another resolution than the normal maps: the map shown at G's size
            shown = torch.nn.functional.interpolate(normal_to_rgb(n[None]), size=images.shape[-2:],
                                                    mode="bilinear", align_corners=False)
            rows += [shown, images]
    save_grid(torch.cat(rows), path, ncol=n_latents + 1)
    return Path(path)


def lambert(normals, albedo=SKIN_RGB, light=(-0.3, 0.4, 1.0), ambient: float = 0.35,
            background: float = 0.0) -> torch.Tensor:
    """(B, 3, H, W) camera-frame normals -> (B, 3, H, W) images in [-1, 1]: one albedo under
    one directional light plus ambient, ``background`` (in [-1, 1]) where the normals are
    zero."""
    d = torch.nn.functional.normalize(torch.tensor(light, dtype=normals.dtype), dim=0)
    shade = ambient + (1 - ambient) * (normals * d[None, :, None, None]).sum(1, keepdim=True).clamp(min=0)
    img = torch.tensor(albedo, dtype=normals.dtype)[None, :, None, None] * shade * 2 - 1
    face = normals.norm(dim=1, keepdim=True) > 0.5
    return torch.where(face, img, torch.full_like(img, background)).clamp(-1, 1)


def synthetic_faces(config, n_faces: int, seed: int, batch_size: int = 16) -> tuple:
    """Held-out synthetic faces: (``faces`` {normals, normals_b (B, 3, R, R)}, baselines
    {"classical": (images, images_b)}, reference images for the Frechet distances, the
    landmark ids the 3DMM defines)."""
    from neural.faces.renders import SyntheticFaces

    data = SyntheticFaces.from_config(config)
    batches = [data.sample(min(batch_size, n_faces - i), rng=[seed, i], pair=True)
               for i in range(0, n_faces, batch_size)]
    reference = torch.cat([data.sample(min(batch_size, n_faces - i), rng=[seed + 1, i])["image"]
                           for i in range(0, n_faces, batch_size)])
    cat = lambda k: torch.cat([b[k] for b in batches])  # noqa: E731
    faces = {"normals": cat("normals"), "normals_b": cat("normals_b")}
    index = torch.as_tensor(np.flatnonzero(data.model.landmark_ids >= 0))
    return faces, {"classical": (cat("image"), cat("image_b"))}, reference, index


def real_faces(data, n_faces: int, seed: int, model: str = "sfm") -> tuple:
    """The held-out photos of a pack, as :func:`synthetic_faces` gives synthetic ones: the
    first half of the split is the reference, the faces are up to ``n_faces`` of the
    other half, the baselines are those photos and the :func:`lambert` renders of their fits."""
    from morphable import load_model
    from neural.gar.real_faces import RealFaces

    test = RealFaces(data, split="test", flip=False)
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(test))
    half = len(order) // 2
    ref, rest = np.sort(order[:half]), np.sort(order[half:][:n_faces])
    a = test.batch(rest)
    other, mirrored = test.partner(rest, rng)
    b = test.batch(other, flipped=mirrored)
    faces = {"normals": a["normals"], "normals_b": b["normals"]}
    baselines = {"photos": (a["image"], b["image"]),
                 "classical": (lambert(a["normals"]), lambert(b["normals"]))}
    index = torch.as_tensor(np.flatnonzero(load_model(model).landmark_ids >= 0))
    return faces, baselines, test.batch(ref)["image"], index


@torch.no_grad()
def evaluate(generators: dict, aux: dict, n_faces: int = 64, n_latents: int = 8, seed=12345,
             grid=None, batch_size: int = 16, inception=None, data=None, aux_size=None) -> dict:
    """Metrics of each generator in ``generators`` (name -> Generator) and of the baselines
    on ``n_faces`` held-out faces (pairs) — synthetic (:func:`synthetic_faces`), or a real pack's
    photos with ``data`` (:func:`real_faces`, which adds ``face_fd``):
    ``{metric: {renderer: value}}`` for the metrics of :data:`METRICS`; ``inception`` (a
    feature network, see :func:`load_inception`) adds ``fid_inception``.

    Generators of several resolutions compare at the faces' resolution R (the pack's, or the
    first generator's): each takes the R-px normal maps (G resizes them per block) and its
    renders are area-downsampled to R. The aux networks' metrics see images and normal maps
    area-downsampled to ``aux_size`` px (default R; 64 for the 64-px aux networks judging
    128-px faces)."""
    from neural.gar.losses import area_downsample

    cfg = next(iter(generators.values())).config
    if data is None:
        faces, baselines, real, index = synthetic_faces(cfg, n_faces, seed, batch_size)
    else:
        faces, baselines, real, index = real_faces(data, n_faces, seed, cfg.model)
    normals, normals_b = faces["normals"], faces["normals_b"]
    n_faces, R = len(normals), normals.shape[-1]
    aux_size = aux_size or R
    small_normals = area_downsample(normals, aux_size, unit=True)

    def small(images):
        return area_downsample(images, aux_size)

    emb = lambda x: torch.cat([aux["R"](small(c)) for c in x.split(batch_size)]).numpy()  # noqa: E731
    real_feats = inception_features(inception, real, batch_size) if inception is not None else None

    def distances(images) -> dict:
        out = {"fid_aux": frechet_distance(emb(images), emb(real))}
        if data is not None:
            out["face_fd"] = face_fd(images, real, cfg.model)
        if inception is not None:
            out["fid_inception"] = frechet_distance(inception_features(inception, images, batch_size),
                                                    real_feats)
        return out

    per = {name: {"normal_consistency_deg": normal_consistency(small(images), small_normals, aux),
                  "identity_consistency_cos": identity_consistency(small(images), small(images_b), aux),
                  **distances(images)}
           for name, (images, images_b) in baselines.items()}
    for name, G in generators.items():
        # the same latents and noise for every generator: differences come from the weights
        gen = torch.Generator().manual_seed(seed)
        z = torch.randn(n_faces, cfg.z_dim, generator=gen)
        noise = G.make_noise(batch_size, gen)

        def run(n, zz):
            return area_downsample(G(n, zz, noise=[e[: len(n)] for e in noise]), R)

        fake = torch.cat([run(n, zz) for n, zz in zip(normals.split(batch_size), z.split(batch_size))])
        fake_b = torch.cat([run(n, zz) for n, zz in zip(normals_b.split(batch_size), z.split(batch_size))])
        k_faces = min(n_faces, batch_size)
        zs = torch.randn(n_latents, k_faces, cfg.z_dim, generator=gen)
        per_latent = torch.stack([small(run(normals[:k_faces], zk)) for zk in zs])
        per[name] = {
            "normal_consistency_deg": normal_consistency(small(fake), small_normals, aux),
            "landmark_consistency_px": landmark_consistency(per_latent, aux, index),
            "identity_consistency_cos": identity_consistency(small(fake), small(fake_b), aux),
            **distances(fake),
        }
    report = {"n_faces": n_faces, "n_latents": n_latents, "resolution": R, "aux_resolution": aux_size,
              "generator_resolutions": {k: G.config.resolution for k, G in generators.items()},
              "faces": "synthetic" if data is None else f"held-out photos of {data}",
              "n_reference": len(real)}
    for metric in METRICS:
        values = {r: m[metric] for r, m in per.items() if metric in m}
        if values:
            report[metric] = values
    if grid is not None:
        sample_grid(next(iter(generators.values())), normals[:4], grid)
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
    p.add_argument("--aux-dir", help="folder with aux_*.pt (default: neural/gar/weights)")
    p.add_argument("--grid", help="Figure-3-like PNG (default: beside the report)")
    p.add_argument("--raw", action="store_true",
                   help="checkpoints: evaluate the raw generator, not its moving average")
    p.add_argument("--faces", type=int, default=64,
                   help="held-out faces (with --data: at most half the pack's test split)")
    p.add_argument("--data", help="a neural.gar.real_faces pack: measure on its held-out photos")
    p.add_argument("--baseline", action="append", default=[], metavar="NAME=PATH",
                   help="another generator to report beside gar, e.g. gar_synthetic=neural/gar/weights/gar_tiny.pt")
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
    for item in args.baseline:
        name, sep, path = item.partition("=")
        if not sep or not name or name in gens:
            raise InputError(f"--baseline expects a new NAME=PATH, got {item!r}")
        gens[name] = load_generator(path, not args.raw)
    inception = load_inception(args.inception) if args.inception else None
    aux_size = gens["gar"].config.aux_size
    aux = {n: load_aux(n, None if args.aux_dir is None else Path(args.aux_dir) / f"aux_{n}.pt",
                       resolution=aux_size) for n in NAMES}
    out = Path(args.report)
    grid = Path(args.grid) if args.grid else out.with_suffix(".png")
    report = evaluate(gens, aux, n_faces=args.faces, seed=args.seed, grid=grid,
                      inception=inception, data=args.data, aux_size=aux_size)
    # the validation metrics our checkpoints store (None for other networks)
    report["aux_validation"] = {n: getattr(aux[n], "meta", {}).get("metrics") for n in NAMES}
    report["generators"] = {"gar": str(args.generator),
                            "gar_no_norm_cycle": str(ablation) if "gar_no_norm_cycle" in gens else None,
                            **dict(b.partition("=")[::2] for b in args.baseline)}
    from morphable.io.atomic import atomic_path

    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
