"""The ``classical`` renderer plugin: Lambertian shading of a normal map under a 9-coefficient
spherical-harmonics environment with a uniform albedo, in torch (differentiable).

It implements the interface of :mod:`morphable.renderer_plugins` (with its inversion hooks) and is
registered under the entry point ``morphable.renderers: classical``. torch loads when a
renderer renders.

Appearance parameters (all torch tensors, batch first):

- ``sh`` (B, 9, 3): SH lighting (see :mod:`morphable.raster.shading`; ``[1, 0, ...]`` is a
  uniform white environment),
- ``albedo`` (B, 3): skin reflectance in [0, 1],
- ``background`` (B, 3): colour where the normal map is zero.

Examples
--------
>>> import torch
>>> r = ClassicalRenderer()
>>> n = torch.zeros(1, 3, 8, 8); n[:, 2, 2:6, 2:6] = 1.0     # a frontal square
>>> img = r.render(n, r.default_appearance(1))
>>> img.shape, bool(img[0, 0, 4, 4] > img[0, 0, 0, 0])
(torch.Size([1, 3, 8, 8]), True)
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..renderer_plugins import RendererBase
from .shading import DirectionalLight, sh_from_lights, shade_sh

__all__ = ["ClassicalRenderer"]


class ClassicalRenderer(RendererBase):
    """Lambertian + SH shading of camera-frame normal maps (any resolution).

    Inverted (:func:`morphable.refinement.refine`), it starts from the mean colour of the
    face pixels under a uniform white environment and moves ``sh`` and ``albedo`` (the
    background stays), on the face pixels only.

    Parameters
    ----------
    albedo : (3,) default skin reflectance of :meth:`default_appearance`
    light_direction : (3,) direction towards the default light (camera frame)
    ambient : float, ambient part of the default light
    """

    resolution = None
    learning_rates = {"sh": 0.02, "albedo": 0.01}

    def __init__(self, albedo=(0.7, 0.5, 0.4), light_direction=(0.3, 0.4, 1.0), ambient=0.4,
                 background=(0.0, 0.0, 0.0)):
        self.albedo = np.asarray(albedo, dtype=np.float64)
        self.background = np.asarray(background, dtype=np.float64)
        self.sh = sh_from_lights([DirectionalLight(light_direction, 1.0 - ambient)], ambient=ambient)
        if self.albedo.shape != (3,) or self.background.shape != (3,):
            raise InputError("classical renderer: albedo and background must be RGB triples")

    def default_appearance(self, batch_size: int = 1) -> dict:
        """Starting appearance: ``sh`` (B, 9, 3), ``albedo`` (B, 3), ``background`` (B, 3)."""
        import torch

        def rep(a):
            return torch.tensor(a, dtype=torch.float32).expand(batch_size, *a.shape).clone()
        return {"sh": rep(self.sh), "albedo": rep(self.albedo), "background": rep(self.background)}

    def initial_appearance(self, image, coverage, seed: int = 0) -> tuple[dict, None]:
        """The albedo: the mean colour of the face pixels (coverage > 0.5) of ``image``
        (1, 3, R, R); the light: a uniform white environment."""
        import torch

        app, _ = super().initial_appearance(image, coverage, seed)
        face = coverage[0, 0] > 0.5
        if face.any():
            app["albedo"] = image[0][:, face].mean(1)[None].clamp(0.02, 1)
        app["sh"] = torch.zeros(1, 9, 3)
        app["sh"][:, 0] = 1.0
        return app, None

    def constrain_appearance(self, appearance) -> None:
        """Albedo in [0, 1]."""
        appearance["albedo"].clamp_(0, 1)

    def render(self, normal_map, appearance: dict):
        """(B, 3, H, W) camera-frame normals (zero outside the face; shorter than unit on the
        silhouette, where they are coverage-weighted) -> (B, 3, H, W) image in [0, 1].

        The normal length is used as the face coverage: the shaded face is blended over the
        background by it, which keeps the silhouette anti-aliased."""
        import torch

        if normal_map.dim() != 4 or normal_map.shape[1] != 3:
            raise InputError(f"normal map must be (B, 3, H, W), got {tuple(normal_map.shape)}")
        a = {k: torch.as_tensor(v, dtype=normal_map.dtype) for k, v in appearance.items()}
        n = normal_map.permute(0, 2, 3, 1)                                  # (B, H, W, 3)
        length = n.norm(dim=-1, keepdim=True)
        cover = length.clamp(0, 1)
        unit = n / length.clamp_min(1e-6)
        face = shade_sh(unit, a["albedo"][:, None, None, :], a["sh"])
        bg = a.get("background", torch.zeros_like(a["albedo"]))[:, None, None, :]
        img = cover * face + (1 - cover) * bg
        return img.clamp(0, 1).permute(0, 3, 1, 2)
