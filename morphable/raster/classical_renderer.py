"""The ``classical`` renderer plugin: Lambertian shading of a normal map under a 9-coefficient
spherical-harmonics environment, with a uniform albedo or an albedo map, in torch
(differentiable).

It implements the interface of :mod:`morphable.renderer_plugins` (with its inversion hooks) and is
registered under the entry point ``morphable.renderers: classical``. torch loads when a
renderer renders.

Appearance parameters (all torch tensors, batch first):

- ``sh`` (B, 9, 3): SH lighting (see :mod:`morphable.raster.shading`; ``[1, 0, ...]`` is a
  uniform white environment),
- ``albedo`` (B, 3): skin reflectance in [0, 1], or (B, 3, H, W) one per pixel,
- ``background`` (B, 3): colour where the normal map is zero;

and, when inverted (:func:`morphable.refinement.refine`), ``texture`` (1, S, S, 3): the albedo
in the model's UV space, shared by all frames of a person, from which each frame's per-pixel
``albedo`` is looked up. The inversion solves ``texture`` and ``sh`` in closed form
(:meth:`ClassicalRenderer.solve_appearance`, :mod:`morphable.raster.lambertian_fit`).

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

    Inverted (:func:`morphable.refinement.refine`), its appearance is an albedo texture in
    the model's UV space shared by the frames and an SH light per frame, both solved in closed
    form from the face pixels (:meth:`solve_appearance`), not by gradient steps; the
    perceptual term is off (``default_weights``).

    Parameters
    ----------
    albedo : (3,) default skin reflectance of :meth:`default_appearance`
    light_direction : (3,) direction towards the default light (camera frame)
    ambient : float, ambient part of the default light
    texture_size : int, texels per side of the albedo texture the inversion recovers
    albedo_prior : float > 0, pull of each texel towards the smooth, mirrored albedo
        (:func:`~morphable.raster.lambertian_fit.solve_albedo`'s ``strength``, in pixels);
        0.5 chosen on the validation subjects at photometric weight 100 (mean 1.383 mm with 32,
        1.285 with 4, 1.211 with 0.5, 1.212 with 0.1, 1.213 with 0.02): a strong pull makes
        the geometry move to register the photo on a blurred, symmetric albedo
    albedo_blur : float > 0, texels, the smoothness prior's Gaussian sigma
    light_prior : float >= 0, ridge of the light towards a uniform white environment
        (:func:`~morphable.raster.lambertian_fit.solve_light`'s ``strength``)
    """

    resolution = None
    learning_rates = {"sh": 0.02, "albedo": 0.01}
    default_weights = {"feat": 0.0, "photo": 300.0}
    """The perceptual term off; the photometric term (a mean squared intensity, ~1e-4 when
    fitted) weighted 300 against the landmark term and priors, chosen with ``albedo_prior``
    on the Florence protocol's validation subjects rendered by the physically based renderer
    (4 ICT subjects, ``--renderer pbr``), never on james (held out): mean over the three
    conditions with ``albedo_prior`` 0.5, 1.321 mm with weight 30, 1.211 with 100, 1.148 with
    300, 1.153 with 1000; the landmark fit 1.488, the refinement without the photometric term
    1.490 (docs/photometric.md, "Loss weights and the albedo prior")."""
    pixelwise = True

    def __init__(self, albedo=(0.7, 0.5, 0.4), light_direction=(0.3, 0.4, 1.0), ambient=0.4,
                 background=(0.0, 0.0, 0.0), texture_size: int = 128, albedo_prior: float = 0.5,
                 albedo_blur: float = 2.0, light_prior: float = 1e-3):
        self.albedo = np.asarray(albedo, dtype=np.float64)
        self.background = np.asarray(background, dtype=np.float64)
        self.sh = sh_from_lights([DirectionalLight(light_direction, 1.0 - ambient)], ambient=ambient)
        if self.albedo.shape != (3,) or self.background.shape != (3,):
            raise InputError("classical renderer: albedo and background must be RGB triples")
        if not 8 <= int(texture_size) <= 2048:
            raise InputError(f"classical renderer: texture_size must be 8..2048, got {texture_size}")
        if not (albedo_prior > 0 and albedo_blur > 0 and light_prior >= 0):
            raise InputError("classical renderer: albedo_prior and albedo_blur must be > 0, "
                             "light_prior >= 0")
        self.texture_size = int(texture_size)
        self.albedo_prior, self.albedo_blur = float(albedo_prior), float(albedo_blur)
        self.light_prior = float(light_prior)
        self._mirrors = {}

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

    def solve_appearance(self, appearances, views) -> bool:
        """The albedo texture (shared) and each frame's SH light in closed form.

        On the first call (no ``texture`` yet) the light of each frame is solved for a
        uniform albedo (the face's median colour), then the texture is the photo's colours
        with that shading divided out; each later call solves the lights given the texture,
        then the texture given the lights (:mod:`~morphable.raster.lambertian_fit`), the
        texture pulled towards its blurred, mirrored self. Sets ``texture``, ``sh`` and the
        per-pixel ``albedo`` map of every frame's appearance; returns True.

        Raises InputError when the model has no UV coordinates.
        """
        import torch

        from .lambertian_fit import solve_albedo, solve_light, texel_index, texture_prior
        from .shading import sh_basis

        model, S = views[0].model, self.texture_size
        if model.uv is None:
            raise InputError(f"{getattr(model, 'source', '') or model.name}: the model has no UV "
                             "coordinates, so the photometric fit cannot hold an albedo texture")
        idx = [texel_index(v.uv, S) for v in views]
        basis = [sh_basis(v.normals.astype(np.float64)) for v in views]
        targets = [v.target.astype(np.float64) for v in views]
        weights = [v.weight.astype(np.float64) for v in views]
        all_idx, all_t, all_w = np.concatenate(idx), np.concatenate(targets), np.concatenate(weights)
        known = np.bincount(all_idx, all_w, S * S).reshape(S, S)
        old = appearances[0].get("texture")
        if old is None:
            face = all_w > 0
            colour = np.median(all_t[face], 0) if face.any() else np.full(3, 0.5)
            lights = [solve_light(np.broadcast_to(colour, t.shape), b, t, w, strength=self.light_prior)
                      for b, t, w in zip(basis, targets, weights)]
            texture = np.broadcast_to(colour, (S * S, 3))
        else:
            texture = old[0].double().numpy().reshape(S * S, 3)
            lights = [solve_light(texture[i], b, t, w, strength=self.light_prior)
                      for i, b, t, w in zip(idx, basis, targets, weights)]
        prior = texture_prior(texture.reshape(S, S, 3), known,
                              self._mirror(model, S), self.albedo_blur)
        shading = np.concatenate([b @ light for b, light in zip(basis, lights)])
        texture = solve_albedo(all_idx, shading, all_t, all_w, prior, self.albedo_prior)
        shared = torch.as_tensor(texture.reshape(1, S, S, 3), dtype=torch.float32)
        for app, light, view in zip(appearances, lights, views):
            app["texture"] = shared
            app["sh"] = torch.as_tensor(light, dtype=torch.float32)[None]
            app.update(self.view_appearance(app, view))
        return True

    def view_appearance(self, appearance, view) -> dict:
        """The per-pixel ``albedo`` (1, 3, R, R) of ``view`` looked up in ``texture`` (the
        appearance unchanged when it has no texture)."""
        import torch

        from .lambertian_fit import texel_index

        tex = appearance.get("texture")
        if tex is None:
            return dict(appearance)
        S, R = tex.shape[1], view.resolution
        flat = tex[0].reshape(S * S, 3)
        base = appearance["albedo"]
        fill = base.mean((2, 3)) if base.dim() == 4 else base
        amap = fill.to(flat.dtype).reshape(1, 3, 1).expand(1, 3, R * R).clone()
        amap[0][:, torch.as_tensor(view.pixels)] = flat[torch.as_tensor(texel_index(view.uv, S))].T
        return {**appearance, "albedo": amap.reshape(1, 3, R, R)}

    def _mirror(self, model, size):
        """The model's texel -> mirror texel map (cached per model and size)."""
        from .lambertian_fit import mirror_texel_map

        key = (id(model), size)
        if key not in self._mirrors:
            self._mirrors[key] = mirror_texel_map(model, model.uv, model.triangle_uv, size)
        return self._mirrors[key]

    def render(self, normal_map, appearance: dict):
        """(B, 3, H, W) camera-frame normals (zero outside the face; shorter than unit on the
        silhouette, where they are coverage-weighted) -> (B, 3, H, W) image in [0, 1].

        The normal length is used as the face coverage: the shaded face is blended over the
        background by it, which keeps the silhouette anti-aliased."""
        import torch

        if normal_map.dim() != 4 or normal_map.shape[1] != 3:
            raise InputError(f"normal map must be (B, 3, H, W), got {tuple(normal_map.shape)}")
        a = {k: torch.as_tensor(v, dtype=normal_map.dtype) for k, v in appearance.items()
             if k != "texture"}
        n = normal_map.permute(0, 2, 3, 1)                                  # (B, H, W, 3)
        length = n.norm(dim=-1, keepdim=True)
        cover = length.clamp(0, 1)
        unit = n / length.clamp_min(1e-6)
        albedo = a["albedo"]
        albedo = albedo.permute(0, 2, 3, 1) if albedo.dim() == 4 else albedo[:, None, None, :]
        face = shade_sh(unit, albedo, a["sh"])
        bg = a.get("background", torch.zeros(len(albedo), 3, dtype=n.dtype))[:, None, None, :]
        img = cover * face + (1 - cover) * bg
        return img.clamp(0, 1).permute(0, 3, 1, 2)
