"""Closed-form appearance of a Lambertian face: SH light per frame and an albedo texture in the
model's UV space shared by all frames, each the linear least-squares solution given the other
and the geometry (numpy, float64).

The image model is ``I_p = a_{t(p)} * (B(n_p) . l)`` per colour channel: ``a`` the albedo of
the texel ``t(p)`` that pixel ``p`` sees (nearest texel, so that each pixel reads one texel and
the albedo's least squares decouple per texel), ``B`` the 9 SH basis functions of
:mod:`morphable.raster.shading` at the pixel's camera-frame normal, ``l`` the frame's (9, 3)
SH light. Every pixel carries a weight (its robust mask weight). Given the albedo the light of
a frame is a 9-unknown ridge regression per channel (:func:`solve_light`); given the light the
albedo of a texel is a weighted mean of ``I / shading`` over the pixels of every frame that see
it, pulled towards a prior texture (:func:`solve_albedo`); :func:`texture_prior` makes that prior
from the current albedo: a blur (smoothness) averaged with its mirror image across the face's
plane of symmetry (symmetry).

Examples
--------
>>> rng = np.random.default_rng(0)
>>> n = rng.normal(size=(500, 3)); n[:, 2] = abs(n[:, 2]); n /= np.linalg.norm(n, axis=1)[:, None]
>>> light = np.zeros((9, 3)); light[0], light[3] = 0.8, 0.3
>>> albedo = np.full((500, 3), 0.6)
>>> target = albedo * (sh_basis(n) @ light)
>>> bool(np.allclose(solve_light(albedo, sh_basis(n), target, np.ones(500)), light, atol=1e-6))
True
"""
from __future__ import annotations

import numpy as np

from .shading import sh_basis

__all__ = ["texel_index", "solve_light", "solve_albedo", "texture_prior", "mirror_texel_map",
           "shading_of", "UNIFORM_LIGHT"]

UNIFORM_LIGHT = np.outer(np.eye(9)[0], np.ones(3))
"""(9, 3) a uniform white environment: every point shaded by its albedo (the light prior)."""


def texel_index(uv, size: int) -> np.ndarray:
    """(N, 2) UV (u right, v up, in [0, 1]) -> (N,) flat index ``row * size + col`` of the
    nearest texel of a ``size`` x ``size`` texture (row 0 at the top; UVs outside clamp)."""
    uv = np.nan_to_num(np.asarray(uv, dtype=np.float64))
    col = np.clip((uv[:, 0] * size).astype(np.int64), 0, size - 1)
    row = np.clip(((1.0 - uv[:, 1]) * size).astype(np.int64), 0, size - 1)
    return row * size + col


def solve_light(albedo, basis, target, weight, prior=None, strength: float = 1e-3) -> np.ndarray:
    """The SH light of one frame given the albedo its pixels see.

    Per channel ``c``: ``min_l sum_p w_p (a_pc B_p . l - I_pc)^2 + lambda |l - l0_c|^2`` with
    ``lambda = strength * sum_p w_p``.

    Parameters
    ----------
    albedo : (N, 3) the albedo each pixel sees; basis : (N, 9) :func:`sh_basis` of its normal
    target : (N, 3) the pixel colours in [0, 1]; weight : (N,) >= 0
    prior : (9, 3) light the ridge pulls to (default :data:`UNIFORM_LIGHT`)
    strength : float >= 0, the ridge relative to the total pixel weight (keeps a frame with
        few or flat pixels finite, and fixes the albedo/light scale)

    Returns
    -------
    (9, 3) float64 SH coefficients.
    """
    prior = UNIFORM_LIGHT if prior is None else np.asarray(prior, dtype=np.float64)
    w = np.asarray(weight, dtype=np.float64)
    lam = strength * max(float(w.sum()), 1.0)
    out = np.empty((9, 3))
    for c in range(3):
        X = basis * albedo[:, c:c + 1]
        A = X.T @ (X * w[:, None]) + lam * np.eye(9)
        b = X.T @ (w * target[:, c]) + lam * prior[:, c]
        out[:, c] = np.linalg.solve(A, b)
    return out


def solve_albedo(texels, shading, target, weight, prior, strength: float = 1.0) -> np.ndarray:
    """The albedo texture given each pixel's shading, over the pixels of all frames.

    Per texel ``t`` and channel: ``min_a sum_{p: t(p)=t} w_p (a s_p - I_p)^2 + lambda (a -
    a0_t)^2`` -> ``a = (sum w s I + lambda a0) / (sum w s^2 + lambda)``.

    Parameters
    ----------
    texels : (N,) int, each pixel's texel (:func:`texel_index`), pixels of all frames
    shading : (N, 3) each pixel's irradiance ``B(n) . l`` of its frame's light
    target : (N, 3) pixel colours; weight : (N,) >= 0
    prior : (T, 3) the texture the texels are pulled to (:func:`texture_prior`)
    strength : float > 0, ``lambda`` in units of one fully weighted, unit-shaded pixel

    Returns
    -------
    (T, 3) float64 albedo in [0, 2] (a texel no pixel sees is its prior).
    """
    T = len(prior)
    ws = weight[:, None] * shading
    num = np.stack([np.bincount(texels, ws[:, c] * target[:, c], T) for c in range(3)], 1)
    den = np.stack([np.bincount(texels, ws[:, c] * shading[:, c], T) for c in range(3)], 1)
    return np.clip((num + strength * prior) / (den + strength), 0.0, 2.0)


def texture_prior(texture, known, mirror=None, blur_texels: float = 2.0) -> np.ndarray:
    """The smooth, symmetric texture an albedo is pulled towards.

    Parameters
    ----------
    texture : (S, S, 3) albedo; known : (S, S) weight of each texel's estimate (0: unseen)
    mirror : (S * S,) int, each texel's mirror texel (-1: none), or None (no symmetry term)
    blur_texels : Gaussian sigma of the smoothness, texels

    Returns
    -------
    (S * S, 3): the known texels blurred by normalised convolution (unseen ones take their
    neighbours'), then averaged with the mirror texel's value where it has one.
    """
    from scipy.ndimage import gaussian_filter

    S = texture.shape[0]
    k = np.asarray(known, dtype=np.float64)
    num = gaussian_filter(texture * k[..., None], [blur_texels, blur_texels, 0], mode="nearest")
    den = gaussian_filter(k, blur_texels, mode="nearest")[..., None]
    fallback = (texture * k[..., None]).sum((0, 1)) / max(k.sum(), 1e-12)
    smooth = np.where(den > 1e-6, num / np.maximum(den, 1e-12), fallback).reshape(S * S, 3)
    if mirror is None:
        return smooth
    has = mirror >= 0
    out = smooth.copy()
    out[has] = 0.5 * (smooth[has] + smooth[mirror[has]])
    return out


def mirror_texel_map(model, uv, triangle_uv, size: int) -> np.ndarray | None:
    """(size * size,) int: for each texel of ``model``'s UV layout the texel of its mirror point
    across the face's plane of symmetry (:func:`morphable.texture.mirror_texels`), -1 where it
    has none; None when the model is not symmetric."""
    from ..texture import mirror_texels
    from .interpolate import interpolate
    from .normal_maps import layout_faces
    from .visibility import uv_visibility

    table = uv_visibility(model.triangles, uv, triangle_uv, size)
    tuv = model.triangles if triangle_uv is None else np.asarray(triangle_uv)
    twin = mirror_texels(model, table, layout_faces(model))
    if twin is None:
        return None
    out = np.full(size * size, -1, dtype=np.int64)
    out[twin.pixels] = texel_index(interpolate(twin, np.asarray(uv, np.float64), tuv,
                                               foreground=True), size)
    return out


def shading_of(normals, light) -> np.ndarray:
    """(N, 3) irradiance ``B(n) . l`` of unit ``normals`` (N, 3) under SH ``light`` (9, 3)."""
    return sh_basis(np.asarray(normals, dtype=np.float64)) @ light
