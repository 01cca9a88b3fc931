"""Lambertian shading: 9-coefficient spherical-harmonics environments and directional lights.

Every function takes numpy arrays or torch tensors (then differentiable); the torch form is
the classical differentiable face renderer that the neural renderer is compared against.

Spherical-harmonics convention
------------------------------
``shade = albedo * sum_k sh[k] * B_k(n)`` where ``B_k = (A_l / pi) Y_k(n) / Y_0`` are the real
SH basis functions ``Y_k`` of band ``l`` (order (0,0), (1,-1), (1,0), (1,1), (2,-2), (2,-1),
(2,0), (2,1), (2,2), i.e. 1, y, z, x, xy, yz, 3z^2-1, xz, x^2-y^2) convolved with the clamped
cosine (``A_0 = pi``, ``A_1 = 2 pi / 3``, ``A_2 = pi / 4``) and scaled so that ``B_0 = 1``:
``sh = [1, 0, ..., 0]`` is a uniform white environment that shades every point with its
albedo. :func:`sh_from_lights` converts ambient + directional lights into coefficients.
Normals and light directions are in the same frame (the renderer uses the camera frame).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arrays import is_torch
from ..errors import InputError

__all__ = ["DirectionalLight", "sh_basis", "shade_sh", "shade_sh_torch", "shade_directional",
           "sh_from_lights"]

_Y0 = 0.5 / np.sqrt(np.pi)
_C1 = np.sqrt(3.0 / (4 * np.pi))
_C2 = 0.5 * np.sqrt(15.0 / np.pi)
_C3 = 0.25 * np.sqrt(5.0 / np.pi)
_C4 = 0.25 * np.sqrt(15.0 / np.pi)
# (A_l / pi) / Y_0 per band
_A = np.array([1.0, 2.0 / 3.0, 0.25]) / _Y0


@dataclass
class DirectionalLight:
    """A light at infinity.

    Attributes
    ----------
    direction : (3,) float
        Towards the light (from the surface), in the frame of the normals; normalised here.
    color : (3,) float or float
        RGB intensity; a surface facing the light gets ``albedo * color``.
    """

    direction: tuple = (0.3, 0.4, 1.0)
    color: tuple = (1.0, 1.0, 1.0)

    def __post_init__(self):
        d = np.asarray(self.direction, dtype=np.float64).reshape(-1)
        c = np.broadcast_to(np.asarray(self.color, dtype=np.float64), (3,)).copy()
        if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) < 1e-12:
            raise InputError(f"light direction must be a non-zero 3-vector, got {self.direction}")
        if not np.isfinite(c).all():
            raise InputError(f"light color must be finite, got {self.color}")
        self.direction = d / np.linalg.norm(d)
        self.color = c


def _sh_terms(normals):
    """The 9 basis functions of :func:`sh_basis` as a list of (...) arrays; the constant
    first term is the scalar 1."""
    x, y, z = normals[..., 0], normals[..., 1], normals[..., 2]
    return [_A[0] * _Y0,
            _A[1] * _C1 * y, _A[1] * _C1 * z, _A[1] * _C1 * x,
            _A[2] * _C2 * x * y, _A[2] * _C2 * y * z, _A[2] * _C3 * (3 * z * z - 1),
            _A[2] * _C2 * x * z, _A[2] * _C4 * (x * x - y * y)]


def sh_basis(normals):
    """(..., 3) unit normals -> (..., 9) Lambertian SH irradiance basis (``B_0 = 1``)."""
    terms = _sh_terms(normals)
    terms[0] = terms[0] + normals[..., 0] * 0
    if is_torch(normals):
        import torch

        return torch.stack(terms, -1)
    return np.stack(terms, -1)


def _sh_coefficients(sh, like):
    """(9,) grey, (9, C), or (B, 9, C) -> an array/tensor shaped to broadcast to
    (..., 9, C) against ``like`` (..., 3)."""
    if is_torch(like):
        import torch

        sh = torch.as_tensor(sh, dtype=like.dtype, device=like.device)
    else:
        sh = np.asarray(sh, dtype=like.dtype)
        if not np.isfinite(sh).all():
            raise InputError("SH coefficients contain NaN or inf")
    if sh.ndim == 1:
        sh = sh[:, None]
    if sh.ndim not in (2, 3) or sh.shape[-2] != 9:
        raise InputError(f"SH coefficients must be (9,), (9, C) or (B, 9, C), got {tuple(sh.shape)}")
    if sh.ndim == 3:  # one environment per batch item: insert the spatial dims
        sh = sh.reshape((sh.shape[0],) + (1,) * (like.ndim - 2) + sh.shape[1:])
    return sh


def shade_sh(normals, albedo, sh):
    """Lambertian shading under a 9-coefficient SH environment (numpy or torch).

    Parameters
    ----------
    normals : (..., 3) unit normals (zero on background gives the ambient term only)
    albedo : (..., C) or broadcastable (e.g. (3,)) reflectance in [0, 1]
    sh : (9,) grey, (9, C) coloured, or (B, 9, C) per batch item (normals (B, ..., 3))

    Returns
    -------
    (..., C) radiance, same type as ``normals``; differentiable for torch inputs.

    Examples
    --------
    >>> n = np.array([[0., 0, 1], [0, 0, -1]])
    >>> shade_sh(n, np.ones(3), [1, 0, 0, 0, 0, 0, 0, 0, 0])  # uniform environment
    array([[1., 1., 1.],
           [1., 1., 1.]])
    """
    coef = _sh_coefficients(sh, normals)
    B = sh_basis(normals)
    # einsum rather than B @ coef: BLAS threads make such skinny products many times
    # slower on a busy machine
    if is_torch(normals):
        import torch

        irradiance = torch.einsum("...k,...kc->...c", B, coef)
    else:
        irradiance = np.einsum("...k,...kc->...c", B, coef)
    return albedo * irradiance


shade_sh_torch = shade_sh
"""Alias of :func:`shade_sh` for torch tensors (the classical differentiable renderer)."""


def shade_directional(normals, albedo, lights, ambient=0.0, visible=None):
    """Lambertian shading: ``albedo * (ambient + sum_i color_i * max(0, n . l_i) * visible_i)``.

    Parameters
    ----------
    normals : (..., 3) unit normals (numpy or torch)
    albedo : (..., 3) or broadcastable
    lights : DirectionalLight or a list of them (directions in the normals' frame)
    ambient : float or (3,) RGB
    visible : list of (...) bool/float arrays, one per light (shadow masks), or None

    Returns
    -------
    (..., 3) radiance, same type as ``normals``.
    """
    lights = [lights] if isinstance(lights, DirectionalLight) else list(lights)
    torch_in = is_torch(normals)
    if torch_in:
        import torch

        def as_t(a):
            return torch.as_tensor(np.array(a), dtype=normals.dtype, device=normals.device)
    else:
        def as_t(a):
            return np.asarray(a, dtype=normals.dtype)
    total = as_t(np.broadcast_to(np.asarray(ambient, dtype=np.float64), (3,)))
    total = total + normals[..., :1] * 0  # broadcast to (..., 3)
    for i, light in enumerate(lights):
        cos = (normals * as_t(light.direction)).sum(-1, keepdims=True)
        cos = cos.clamp_min(0) if torch_in else np.maximum(cos, 0)
        if visible is not None:
            cos = cos * as_t(visible[i])[..., None]
        total = total + cos * as_t(light.color)
    return albedo * total


def sh_from_lights(lights=(), ambient=0.0) -> np.ndarray:
    """SH coefficients (9, 3) approximating ambient + directional lights for :func:`shade_sh`.

    Band-2 SH cannot hold a clamped cosine exactly: facing the light the approximation gives
    ``1.0625 * color`` instead of ``color``, and a little light leaks past 90 degrees.

    Examples
    --------
    >>> sh = sh_from_lights([DirectionalLight((0, 0, 1), 1.0)], ambient=0.2)
    >>> shade_sh(np.array([0., 0, 1]), 1.0, sh).round(4)
    array([1.2625, 1.2625, 1.2625])
    """
    lights = [lights] if isinstance(lights, DirectionalLight) else list(lights)
    sh = np.zeros((9, 3))
    sh[0] += np.broadcast_to(np.asarray(ambient, dtype=np.float64), (3,))
    for light in lights:
        # radiance pi * color * delta(direction) projected on Y_k, then in units of Y_0
        y = sh_basis(light.direction) / _A[[0, 1, 1, 1, 2, 2, 2, 2, 2]]
        sh += np.pi * _Y0 * y[:, None] * light.color[None, :]
    return sh
