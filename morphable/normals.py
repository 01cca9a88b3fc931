"""Per-vertex normals, area- or angle-weighted, for numpy arrays and torch tensors.

One function serves both: a torch tensor in gives a differentiable, batched torch result
(torch is imported only then). Degenerate and zero-area triangles add nothing; a vertex
with no usable triangle (isolated, or only degenerate ones) gets +z, so the result is always
a finite unit vector.
"""
from __future__ import annotations

import numpy as np

from .arrays import is_torch
from .errors import InputError

__all__ = ["vertex_normals", "face_normals"]

_EPS = 1e-30
_FALLBACK = (0.0, 0.0, 1.0)


def _check(vertices, triangles):
    if vertices.ndim < 2 or vertices.shape[-1] != 3:
        raise InputError(f"vertices must be (..., V, 3), got {tuple(vertices.shape)}")
    if triangles.ndim != 2 or triangles.shape[1] != 3:
        raise InputError(f"triangles must be (F, 3), got {tuple(triangles.shape)}")
    if triangles.shape[0] and (int(triangles.min()) < 0 or int(triangles.max()) >= vertices.shape[-2]):
        raise InputError(f"triangle ids out of range [0, {vertices.shape[-2]})")


def face_normals(vertices, triangles, normalize: bool = True):
    """Triangle normals (right-hand rule, counter-clockwise = front).

    Parameters
    ----------
    vertices : (..., V, 3) array or tensor
    triangles : (F, 3) int array or tensor
    normalize : bool
        False returns the cross products, whose length is twice the triangle area (mm^2).

    Returns
    -------
    (..., F, 3); unit vectors, zero for degenerate triangles when normalised.
    """
    xp = _namespace(vertices)
    _check(vertices, triangles)
    v0, v1, v2 = (vertices[..., triangles[:, i], :] for i in range(3))
    n = xp.cross(v1 - v0, v2 - v0)
    if not normalize:
        return n
    return n / xp.clip_norm(n)


class _Numpy:
    @staticmethod
    def cross(a, b):
        return np.cross(a, b)

    @staticmethod
    def norm(a):
        return np.sqrt((a * a).sum(-1, keepdims=True))

    @classmethod
    def clip_norm(cls, a):
        return np.maximum(cls.norm(a), _EPS)

    @staticmethod
    def scatter_add(values, index, n):
        """Sum rows of values (..., M, 3) into n rows by index (M,)."""
        out = np.zeros(values.shape[:-2] + (n, 3), dtype=values.dtype)
        flat = out.reshape(-1, n, 3)
        vals = values.reshape(-1, values.shape[-2], 3)
        for b in range(flat.shape[0]):
            for k in range(3):
                flat[b, :, k] = np.bincount(index, weights=vals[b, :, k], minlength=n)
        return out

    @staticmethod
    def angle(a, b):
        """Angle between rows of a and b (..., M, 3), robust for tiny and parallel vectors."""
        return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1))

    @staticmethod
    def where_zero(n, norm, fallback):
        return np.where(norm > _EPS, n / np.maximum(norm, _EPS), np.asarray(fallback, n.dtype))


class _Torch:
    def __init__(self):
        import torch

        self.torch = torch

    def cross(self, a, b):
        return self.torch.linalg.cross(a, b, dim=-1)

    def norm(self, a):
        # the +tiny keeps the gradient of sqrt finite at exactly zero
        return self.torch.sqrt((a * a).sum(-1, keepdim=True) + _EPS)

    def clip_norm(self, a):
        return self.norm(a).clamp_min(1e-15)

    def scatter_add(self, values, index, n):
        shape = values.shape[:-2] + (n, 3)
        out = values.new_zeros(shape)
        idx = index.view(*([1] * (values.ndim - 2)), -1, 1).expand_as(values)
        return out.scatter_add(-2, idx, values)

    def angle(self, a, b):
        c = self.torch.linalg.cross(a, b, dim=-1)
        s = self.torch.sqrt((c * c).sum(-1) + _EPS)
        return self.torch.atan2(s, (a * b).sum(-1))

    def where_zero(self, n, norm, fallback):
        fb = n.new_tensor(fallback).expand_as(n)
        ok = norm > 1e-12
        return self.torch.where(ok, n / norm.clamp_min(1e-12), fb)


def _namespace(x):
    return _Torch() if is_torch(x) else _Numpy()


def vertex_normals(vertices, triangles, weighting: str = "area"):
    """Unit normal of every vertex: the weighted sum of its triangles' normals.

    Parameters
    ----------
    vertices : (..., V, 3) float array or torch tensor, mm
        Batch dimensions first; a torch tensor gives a differentiable torch result.
    triangles : (F, 3) int array (or tensor), counter-clockwise seen from outside
    weighting : {"area", "angle"}
        "area": each triangle counts with its area (libigl AREA, trimesh's face-area sum).
        "angle": each triangle counts with its corner angle at the vertex (libigl ANGLE).

    Returns
    -------
    (..., V, 3) unit normals, same type and dtype as ``vertices``; +z where undefined.

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])
    >>> vertex_normals(v, np.array([[0, 1, 2]]))
    array([[0., 0., 1.],
           [0., 0., 1.],
           [0., 0., 1.],
           [0., 0., 1.]])
    """
    if weighting not in ("area", "angle"):
        raise InputError(f"weighting must be 'area' or 'angle', got {weighting!r}")
    xp = _namespace(vertices)
    if not is_torch(vertices):
        vertices = np.asarray(vertices)
        if vertices.dtype.kind != "f":
            vertices = vertices.astype(np.float64)
        triangles = np.asarray(triangles, dtype=np.int64)
    else:
        triangles = xp.torch.as_tensor(triangles, dtype=xp.torch.int64, device=vertices.device)
    _check(vertices, triangles)
    V = vertices.shape[-2]
    corners = [vertices[..., triangles[:, i], :] for i in range(3)]
    cross = xp.cross(corners[1] - corners[0], corners[2] - corners[0])  # |cross| = 2 * area
    if weighting == "area":
        contrib = [cross] * 3
    else:
        unit = cross / xp.clip_norm(cross)
        contrib = []
        for i in range(3):
            a = corners[(i + 1) % 3] - corners[i]
            b = corners[(i + 2) % 3] - corners[i]
            contrib.append(unit * xp.angle(a, b)[..., None])
    if is_torch(vertices):
        values = xp.torch.cat(contrib, dim=-2)
        index = triangles.T.reshape(-1)
    else:
        values = np.concatenate(contrib, axis=-2)
        index = triangles.T.reshape(-1)
    summed = xp.scatter_add(values, index, V)
    return xp.where_zero(summed, xp.norm(summed), _FALLBACK)
