"""GAR training losses (paper Sec. 3.2):

``L_GAR = lambda_n L_n + lambda_ldmk L_ldmk + lambda_id L_id + lambda_adv L_adv``
with the defaults lambda_n = 2, lambda_ldmk = 2, lambda_id = 1, lambda_adv = 1.

- :func:`normal_loss` L_n: masked L1 between the input normal map and ``N(G(n, z))``,
  masked by the face-parsing mask ``P(G(n, z))``;
- :func:`landmark_loss` L_ldmk: same ``n``, latents ``z1``, ``z2``: ``L(G(n, z1))`` and
  ``L(G(n, z2))`` must agree;
- :func:`identity_loss` L_id: same identity and ``z``, another expression/pose: ``R(.)``
  embeddings must agree (1 - cosine);
- :func:`generator_adversarial_loss` L_adv (non-saturating), :func:`discriminator_loss`
  and the :func:`r1_penalty` of the discriminator.

:func:`generator_losses` runs G and the frozen auxiliary networks on one batch and returns
every term and the weighted total.

Examples
--------
>>> import torch
>>> n = torch.zeros(1, 3, 4, 4); n[:, 2] = 1
>>> float(normal_loss(n, n, torch.ones(1, 1, 4, 4)))
0.0
>>> float(identity_loss(torch.tensor([[1.0, 0.0]]), torch.tensor([[0.0, 2.0]])))
1.0
>>> float(total_loss({"n": torch.tensor(1.0), "adv": torch.tensor(0.5)}))
2.5
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["DEFAULT_LAMBDAS", "normal_loss", "landmark_loss", "identity_loss",
           "generator_adversarial_loss", "discriminator_loss", "r1_penalty", "total_loss",
           "generator_losses", "area_downsample"]

DEFAULT_LAMBDAS = {"n": 2.0, "ldmk": 2.0, "id": 1.0, "adv": 1.0}
"""The terms' weights, the paper's: lambda_n = 2, lambda_ldmk = 2, lambda_id = 1, lambda_adv = 1."""


def normal_loss(normals: torch.Tensor, predicted: torch.Tensor, mask: torch.Tensor,
                eps: float = 1e-6) -> torch.Tensor:
    """Masked L1: ``sum(mask * |n - n_hat|) / (3 sum(mask))``.

    normals, predicted : (B, 3, H, W) unit normals (the target is resized to the prediction);
    mask : (B, 1, H, W) weights in [0, 1] (a soft face mask). An empty mask gives 0.
    """
    if normals.shape[-2:] != predicted.shape[-2:]:
        from .networks import resize_normals

        normals = resize_normals(normals, predicted.shape[-1])
    err = (mask * (normals - predicted).abs()).sum()
    return err / (3.0 * mask.sum() + eps)


def landmark_loss(landmarks_a: torch.Tensor, landmarks_b: torch.Tensor,
                  image_size: float = 1.0) -> torch.Tensor:
    """Mean distance between two landmark sets (B, 68, 2), divided by ``image_size``
    (pass the image side in pixels for a resolution-independent loss). The distance is
    ``sqrt(d^2 + 1e-8)`` so that its gradient stays finite at agreement."""
    d2 = (landmarks_a - landmarks_b).pow(2).sum(-1)
    return (d2 + 1e-8).sqrt().mean() / image_size


def identity_loss(embedding_a: torch.Tensor, embedding_b: torch.Tensor) -> torch.Tensor:
    """``1 - cos(R_a, R_b)`` averaged over the batch; embeddings (B, D) need not be unit."""
    return (1.0 - F.cosine_similarity(embedding_a, embedding_b, dim=-1, eps=1e-8)).mean()


def generator_adversarial_loss(fake_logits: torch.Tensor) -> torch.Tensor:
    """Non-saturating generator loss ``mean softplus(-D(G(.)))``."""
    return F.softplus(-fake_logits).mean()


def discriminator_loss(real_logits: torch.Tensor, fake_logits: torch.Tensor) -> torch.Tensor:
    """Logistic discriminator loss ``mean softplus(D(fake)) + mean softplus(-D(real))``."""
    return F.softplus(fake_logits).mean() + F.softplus(-real_logits).mean()


def r1_penalty(real_images: torch.Tensor, real_logits: torch.Tensor) -> torch.Tensor:
    """R1: ``mean_b ||d D(x_b) / d x_b||^2`` on real images (which must require grad).
    Weight it by ``gamma / 2`` (times the lazy-regularisation interval)."""
    (grad,) = torch.autograd.grad(real_logits.sum(), real_images, create_graph=True)
    return grad.pow(2).flatten(1).sum(1).mean()


def total_loss(terms: dict, lambdas: dict | None = None) -> torch.Tensor:
    """``sum_k lambda_k * terms[k]`` over the keys of ``terms`` ("n", "ldmk", "id", "adv");
    ``lambdas`` overrides :data:`DEFAULT_LAMBDAS`."""
    lam = {**DEFAULT_LAMBDAS, **(lambdas or {})}
    unknown = set(terms) - set(lam)
    if unknown:
        raise KeyError(f"no weight for loss terms {sorted(unknown)}")
    return sum(lam[k] * v for k, v in terms.items())


def area_downsample(x: torch.Tensor, size=None, unit: bool = False) -> torch.Tensor:
    """(B, C, H, W) -> (B, C, size, size) by averaging blocks (H a multiple of ``size``);
    ``x`` itself when ``size`` is None or H. ``unit=True`` for normal maps: each averaged
    vector rescaled to unit length, zero where the block holds no normal."""
    if size is None or x.shape[-1] == size:
        return x
    y = F.adaptive_avg_pool2d(x, size)
    if unit:
        length = y.norm(dim=1, keepdim=True)
        y = torch.where(length > 1e-6, y / length.clamp_min(1e-12), torch.zeros_like(y))
    return y


def generator_losses(G, D, aux: dict, normals_a: torch.Tensor, normals_b: torch.Tensor,
                     z1: torch.Tensor, z2: torch.Tensor, lambdas: dict | None = None,
                     landmark_index=None, augment=None, aux_size=None):
    """All GAR generator terms for one batch.

    Parameters
    ----------
    G, D : :class:`neural.gar.networks.Generator`, :class:`neural.gar.networks.Discriminator`
    aux : dict with frozen networks "N", "P", "L", "R" (see :mod:`neural.gar.auxnets`)
    normals_a, normals_b : (B, 3, H, W) normal maps of the same identities under two
        different expressions/poses
    z1, z2 : (B, z_dim) two latents
    lambdas : term weights (default :data:`DEFAULT_LAMBDAS`); a term weighted 0 is neither
        computed nor rendered for (without L_ldmk and L_id, G renders B images, not 3B)
    landmark_index : optional (K,) ids of the landmarks L_ldmk compares (e.g. those the 3DMM
        defines, which are the ones the synthetic L network was trained on); default all
    augment : optional differentiable image transform applied to the fakes before D (the
        discriminator's augmentation, :func:`neural.augment.diff_augment`); default none
    aux_size : side (px) the aux networks take, when smaller than G's: renders and normal
        maps are area-downsampled to it first (:func:`area_downsample`); default G's own

    Returns
    -------
    total : scalar tensor; terms : dict of the detached 0-d tensor terms (left on the device:
    reading them waits for it); fake : (B, 3, R, R)
    ``G(normals_a, z1)`` (detached), for the discriminator step.
    """
    lam = {**DEFAULT_LAMBDAS, **(lambdas or {})}
    B = normals_a.shape[0]
    # one batched pass: (n_a, z1) for L_n and L_adv, (n_a, z2) for L_ldmk, (n_b, z1) for L_id;
    # a term weighted 0 adds no images to it (the lazy steps of Trainer.train_step)
    pairs = {"a1": (normals_a, z1)}
    if lam["ldmk"]:
        pairs["a2"] = (normals_a, z2)
    if lam["id"]:
        pairs["b1"] = (normals_b, z1)
    normals, z = (torch.cat(x) for x in zip(*pairs.values()))
    image = dict(zip(pairs, G(normals, z).split(B)))
    img_a1 = image["a1"]
    small = {k: area_downsample(v, aux_size) for k, v in image.items()}
    terms = {}
    if lam["n"]:
        with torch.no_grad():
            mask = aux["P"](small["a1"])
        terms["n"] = normal_loss(area_downsample(normals_a, aux_size, unit=True),
                                 aux["N"](small["a1"]), mask)
    if lam["ldmk"]:
        lm = aux["L"].landmarks(torch.cat([small["a1"], small["a2"]]))
        if landmark_index is not None:
            lm = lm[:, landmark_index]
        terms["ldmk"] = landmark_loss(*lm.split(B), image_size=small["a1"].shape[-1])
    if lam["id"]:
        emb = aux["R"](torch.cat([small["a1"], small["b1"]]))
        terms["id"] = identity_loss(*emb.split(B))
    if lam["adv"]:
        terms["adv"] = generator_adversarial_loss(
            D(img_a1 if augment is None else augment(img_a1)).float())
    total = total_loss(terms, lam)
    return total, {k: v.detach() for k, v in terms.items()}, img_a1.detach()
