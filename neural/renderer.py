"""The ``gar`` renderer plugin: the Generative Adversarial Renderer behind the interface of
:mod:`morphable.renderers` (entry point ``morphable.renderers: gar``).

Weights: ``weights=`` (a ``generator.pt`` / ``checkpoint.pt`` of :mod:`neural.train`), else
``$MORPHABLE_GAR_WEIGHTS``, else the committed ``neural/weights/gar_tiny.pt``. Without any,
construction fails with an InputError unless ``allow_untrained=True`` (then an untrained
generator of ``config``, useful for tests and shapes only).

Appearance: ``z`` (B, z_dim) latent, ``noise`` list of per-layer maps eps (B, 1, r, r) as
from ``Generator.make_noise`` (zeros by default).

Examples
--------
>>> import torch
>>> r = GARRenderer(allow_untrained=True)
>>> n = torch.zeros(1, 3, 64, 64); n[:, 2] = 1.0
>>> r.render(n, r.default_appearance(1)).shape
torch.Size([1, 3, 64, 64])
"""
from __future__ import annotations

import os
from pathlib import Path

import torch

from morphable.errors import InputError

from .config import get_config
from .gar import Generator

__all__ = ["GARRenderer", "default_generator_path", "WEIGHTS_ENV"]

WEIGHTS_ENV = "MORPHABLE_GAR_WEIGHTS"


def default_generator_path() -> Path | None:
    """``$MORPHABLE_GAR_WEIGHTS`` if set, else ``neural/weights/gar_tiny.pt`` if present."""
    env = os.environ.get(WEIGHTS_ENV)
    if env:
        return Path(env)
    p = Path(__file__).resolve().parent / "weights" / "gar_tiny.pt"
    return p if p.is_file() else None


class GARRenderer:
    """G(n, z, eps) as a renderer: images in [0, 1] at ``resolution`` pixels."""

    def __init__(self, weights=None, allow_untrained: bool = False, config: str = "tiny",
                 seed: int = 0):
        from .evaluate import load_generator

        path = Path(weights) if weights else default_generator_path()
        if path is not None:
            self.generator = load_generator(path)
            self.weights = str(path)
        elif allow_untrained:
            torch.manual_seed(seed)
            self.generator = Generator(get_config(config)).eval().requires_grad_(False)
            self.weights = None
        else:
            raise InputError(f"gar renderer: no generator weights (pass weights=, set "
                             f"${WEIGHTS_ENV}, or train one: python -m neural.train --config tiny)")
        self.resolution = self.generator.config.resolution
        self.seed = seed

    @property
    def z_dim(self) -> int:
        return self.generator.config.z_dim

    def default_appearance(self, batch_size: int = 1) -> dict:
        """``z`` (B, z_dim) from a fixed seed, ``noise`` all zero."""
        g = torch.Generator().manual_seed(self.seed)
        return {"z": torch.randn(batch_size, self.z_dim, generator=g),
                "noise": [torch.zeros_like(e) for e in self.generator.make_noise(batch_size)]}

    def render(self, normal_map, appearance: dict):
        """(B, 3, H, W) normals -> (B, 3, R, R) image in [0, 1] (differentiable in the
        normals, ``z`` and ``noise``)."""
        if normal_map.dim() != 4 or normal_map.shape[1] != 3:
            raise InputError(f"normal map must be (B, 3, H, W), got {tuple(normal_map.shape)}")
        img = self.generator(normal_map.float(), appearance["z"], noise=appearance.get("noise"))
        return ((img + 1) / 2).clamp(0, 1)
