"""Differentiable augmentation of the discriminator's inputs (DiffAugment, Zhao et al.,
*Differentiable Augmentation for Data-Efficient GAN Training*, NeurIPS 2020).

The same random transforms are applied to real and generated images before D (and in the R1
penalty, whose gradient is taken through them), so D cannot memorise a small set of photos
and G still gets gradients: every transform is differentiable in the image. Policies, as in
the paper's code (images in [-1, 1]):

- ``color``: brightness ``+ U(-0.5, 0.5)``, saturation ``x (U(0, 2))`` around the pixel's
  channel mean, contrast ``x (U(0.5, 1.5))`` around the image mean;
- ``translation``: an integer shift of up to 1/8 of the side in x and y, zero padded;
- ``cutout``: one square of half the side, at a random place, set to zero.

Random draws come from the :class:`torch.Generator` given, on its device (a CPU generator
gives the same transforms on any device; a GPU's own, :func:`neural.training.step_generator`,
needs no copy to it), and are the same for every channel of an image, different per image.

Examples
--------
>>> import torch
>>> x = torch.rand(2, 3, 8, 8) * 2 - 1
>>> bool((diff_augment(x, "") == x).all())
True
>>> y = diff_augment(x, "color,translation,cutout", torch.Generator().manual_seed(0))
>>> y.shape
torch.Size([2, 3, 8, 8])
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["POLICIES", "DEFAULT_POLICY", "parse_policy", "diff_augment"]

POLICIES = ("color", "translation", "cutout")
"""The augmentations a policy can name (:func:`parse_policy`)."""
DEFAULT_POLICY = "color,translation,cutout"


def parse_policy(policy: str) -> tuple:
    """``"color,translation"`` -> ``("color", "translation")``; ``""`` -> ``()``.
    Raises ValueError naming an unknown policy."""
    names = tuple(p.strip() for p in (policy or "").split(",") if p.strip())
    unknown = [p for p in names if p not in POLICIES]
    if unknown:
        raise ValueError(f"unknown augmentation {', '.join(unknown)}; choose from "
                         f"{', '.join(POLICIES)}")
    return names


def _home(gen):
    """Where ``gen`` draws (torch's global generator: the CPU)."""
    return gen.device if gen is not None else torch.device("cpu")


def _uniform(shape, gen, device, dtype):
    return torch.rand(shape, generator=gen, device=_home(gen)).to(device=device, dtype=dtype)


def _color(x, gen):
    B = x.shape[0]
    x = x + (_uniform((B, 1, 1, 1), gen, x.device, x.dtype) - 0.5)
    mean = x.mean(dim=1, keepdim=True)
    x = (x - mean) * (_uniform((B, 1, 1, 1), gen, x.device, x.dtype) * 2) + mean
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    return (x - mean) * (_uniform((B, 1, 1, 1), gen, x.device, x.dtype) + 0.5) + mean


def _translation(x, gen, ratio=0.125):
    B, _, H, W = x.shape
    sh, sw = int(H * ratio + 0.5), int(W * ratio + 0.5)
    dy = torch.randint(-sh, sh + 1, (B, 1, 1), generator=gen, device=_home(gen)).to(x.device)
    dx = torch.randint(-sw, sw + 1, (B, 1, 1), generator=gen, device=_home(gen)).to(x.device)
    b, gy, gx = torch.meshgrid(torch.arange(B, device=x.device), torch.arange(H, device=x.device),
                               torch.arange(W, device=x.device), indexing="ij")
    # out[y, x] = in[y + dy, x + dx], zero outside (the 1-pixel zero border of the padding)
    gy = (gy + dy + 1).clamp(0, H + 1)
    gx = (gx + dx + 1).clamp(0, W + 1)
    padded = F.pad(x, [1, 1, 1, 1]).permute(0, 2, 3, 1)
    return padded[b, gy, gx].permute(0, 3, 1, 2)


def _cutout(x, gen, ratio=0.5):
    B, _, H, W = x.shape
    ch, cw = int(H * ratio + 0.5), int(W * ratio + 0.5)
    oy = torch.randint(0, H + (1 - ch % 2), (B, 1, 1), generator=gen, device=_home(gen)).to(x.device)
    ox = torch.randint(0, W + (1 - cw % 2), (B, 1, 1), generator=gen, device=_home(gen)).to(x.device)
    b, gy, gx = torch.meshgrid(torch.arange(B, device=x.device), torch.arange(ch, device=x.device),
                               torch.arange(cw, device=x.device), indexing="ij")
    gy = (gy + oy - ch // 2).clamp(0, H - 1)
    gx = (gx + ox - cw // 2).clamp(0, W - 1)
    mask = torch.ones(B, H, W, device=x.device, dtype=x.dtype)
    mask[b, gy, gx] = 0
    return x * mask[:, None]


_TRANSFORMS = {"color": _color, "translation": _translation, "cutout": _cutout}


def diff_augment(images: torch.Tensor, policy: str | tuple, generator=None) -> torch.Tensor:
    """Augment (B, 3, H, W) images in [-1, 1] by ``policy`` (a comma-separated string or a
    tuple of :data:`POLICIES`, applied in the order given); an empty policy returns
    ``images`` itself. ``generator``: :class:`torch.Generator` of the random draws, on the
    CPU or on the images' device (default torch's global one)."""
    names = parse_policy(policy) if isinstance(policy, str) else tuple(policy)
    for name in names:
        images = _TRANSFORMS[name](images, generator)
    return images
