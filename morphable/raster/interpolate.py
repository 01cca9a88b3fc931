"""Barycentric interpolation of vertex attributes over a fixed visibility.

The torch path is the differentiable core of the renderers: visibility (which triangle,
which weights) is a constant, the attributes carry the gradient. Gradients therefore flow to
whatever the attributes were computed from (vertex normals -> vertices -> alpha, beta, theta),
but not through the silhouette.

Interpolation is a product with a sparse (samples x vertices) matrix of barycentric weights,
built once per visibility (scipy CSR for numpy, torch CSR for torch, whose backward pass is the
product with the transposed matrix).
"""
from __future__ import annotations

import numpy as np

from ..arrays import is_torch
from ..errors import InputError
from .visibility import Visibility, array_key

__all__ = ["interpolate"]


def _interpolate_numpy(vis: Visibility, attributes, triangles, foreground):
    a = np.asarray(attributes)
    flat = a.ndim == 1
    a = a[:, None] if flat else a
    if a.ndim != 2:
        raise InputError(f"numpy attributes must be (V, C) or (V,), got {a.shape}")
    dtype = np.result_type(a.dtype, np.float32)
    out = vis.matrix(len(a), triangles, dtype, foreground) @ a.astype(dtype, copy=False)
    if not foreground:
        out = out.reshape(vis.shape + (a.shape[1],))
    return out[..., 0] if flat else out


def _torch_matrices(vis: Visibility, n_rows, triangles, dtype, device, foreground=False):
    key = ("torch", n_rows, None if triangles is None else array_key(np.asarray(triangles)),
           str(dtype), str(device), foreground)

    def make():
        import warnings

        import torch

        m = vis.matrix(n_rows, triangles, np.float64, foreground)
        with warnings.catch_warnings():  # sparse CSR support is flagged beta in torch
            warnings.simplefilter("ignore")
            pair = []
            for s in (m, m.T.tocsr()):
                pair.append(torch.sparse_csr_tensor(
                    torch.as_tensor(s.indptr, dtype=torch.int64),
                    torch.as_tensor(s.indices, dtype=torch.int64),
                    torch.as_tensor(s.data, dtype=dtype), size=s.shape, device=device))
        return tuple(pair)

    return vis.cached(key, make)


def _sparse_apply():
    import torch

    class SparseApply(torch.autograd.Function):
        """y = M @ x with a constant sparse M; the gradient is M^T @ dy (itself differentiable)."""

        @staticmethod
        def forward(ctx, x, m, mt):
            ctx.pair = (m, mt)
            return m @ x

        @staticmethod
        def backward(ctx, grad):
            m, mt = ctx.pair
            return SparseApply.apply(grad.contiguous(), mt, m), None, None

    return SparseApply


_SPARSE_APPLY = []


def _interpolate_torch(vis: Visibility, attributes, triangles, foreground):
    a = attributes
    if a.ndim not in (2, 3):
        raise InputError(f"torch attributes must be (V, C) or (B, V, C), got {tuple(a.shape)}")
    if not _SPARSE_APPLY:
        _SPARSE_APPLY.append(_sparse_apply())
    m, mt = _torch_matrices(vis, a.shape[-2], triangles, a.dtype, a.device, foreground)
    grid = (len(vis.pixels),) if foreground else tuple(vis.shape)
    if a.ndim == 3:  # (B, V, C) -> (V, B * C): one sparse product for the whole batch
        B, V, C = a.shape
        x = a.permute(1, 0, 2).reshape(V, B * C)
        y = _SPARSE_APPLY[0].apply(x, m, mt).reshape(grid + (B, C))
        return y.permute(len(grid), *range(len(grid)), len(grid) + 1)
    return _SPARSE_APPLY[0].apply(a.contiguous(), m, mt).reshape(grid + (a.shape[-1],))


def interpolate(vis, attributes, triangles=None, foreground: bool = False):
    """Interpolate per-vertex attributes at every sample of a visibility.

    Parameters
    ----------
    vis : Visibility, or a list of B Visibility (torch (B, V, C) attributes, one per item)
    attributes : (V, C) or (V,) numpy array, or (V, C) / (B, V, C) torch tensor
        One row per vertex (or per id of ``triangles``).
    triangles : (F, 3) int or None
        Corner ids to look the rows up with; default ``vis.triangles``. Pass a
        ``triangle_uv`` table to interpolate per-corner texture coordinates.
    foreground : bool
        Return only the foreground samples, in the order of ``vis.pixels``: (N, C) or
        (B, N, C) instead of the whole grid (not with a list of visibilities).

    Returns
    -------
    (Hs, Ws, C) numpy array (``(Hs, Ws)`` for a (V,) input), or (Hs, Ws, C) / (B, Hs, Ws, C)
    torch tensor, zero on background samples. The torch result is differentiable with respect
    to ``attributes`` (the visibility is a constant).

    Examples
    --------
    >>> from morphable.raster.visibility import uv_visibility
    >>> table = uv_visibility([[0, 1, 2]], [[0., 0], [1, 0], [0, 1]], size=4)
    >>> interpolate(table, np.array([0., 1, 0]))[-1].round(3)  # bottom row: value = u
    array([0.125, 0.375, 0.625, 0.875])
    """
    if isinstance(vis, (list, tuple)):
        if not is_torch(attributes) or attributes.ndim != 3 or attributes.shape[0] != len(vis):
            raise InputError("a list of visibilities needs a torch (B, V, C) tensor with B = "
                             "len(list)")
        if foreground:
            raise InputError("foreground=True needs one visibility, not a list")
        import torch

        return torch.stack([_interpolate_torch(v, a, triangles, False)
                            for v, a in zip(vis, attributes)])
    if not isinstance(vis, Visibility):
        raise InputError(f"vis must be a Visibility, got {type(vis).__name__}")
    if is_torch(attributes):
        return _interpolate_torch(vis, attributes, triangles, foreground)
    return _interpolate_numpy(vis, attributes, triangles, foreground)
