"""Barycentric interpolation of vertex attributes over a fixed visibility.

The torch path is the differentiable core of the renderers: visibility (which triangle,
which weights) is a constant, the attributes carry the gradient. Gradients therefore flow to
whatever the attributes were computed from (vertex normals -> vertices -> alpha, beta, theta),
but not through the silhouette.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .visibility import Visibility

__all__ = ["interpolate"]


def _is_torch(x) -> bool:
    return type(x).__module__.split(".")[0] == "torch"


def _interpolate_numpy(vis: Visibility, attributes, triangles):
    a = np.asarray(attributes)
    flat = a.ndim == 1
    a = a[:, None] if flat else a
    if a.ndim != 2:
        raise InputError(f"numpy attributes must be (V, C) or (V,), got {a.shape}")
    idx = vis.corners(triangles)
    if idx.size and idx.max() >= len(a):
        raise InputError(f"attributes have {len(a)} rows, the triangles index up to {idx.max()}")
    dtype = np.result_type(a.dtype, np.float32)
    vals = np.einsum("nk,nkc->nc", vis.weights.astype(dtype), a[idx].astype(dtype, copy=False))
    out = np.zeros((vis.triangle_id.size, a.shape[1]), dtype=dtype)
    out[vis.pixels] = vals
    out = out.reshape(vis.shape + (a.shape[1],))
    return out[..., 0] if flat else out


def _interpolate_torch(vis: Visibility, attributes, triangles):
    import torch

    a = attributes
    if a.ndim not in (2, 3):
        raise InputError(f"torch attributes must be (V, C) or (B, V, C), got {tuple(a.shape)}")
    idx = torch.as_tensor(vis.corners(triangles), device=a.device)
    if idx.numel() and int(idx.max()) >= a.shape[-2]:
        raise InputError(f"attributes have {a.shape[-2]} rows, the triangles index up to "
                         f"{int(idx.max())}")
    w = torch.as_tensor(vis.weights, device=a.device, dtype=a.dtype)
    g = a[..., idx.reshape(-1), :].reshape(a.shape[:-2] + tuple(idx.shape) + (a.shape[-1],))
    vals = (g * w[..., None]).sum(-2)  # (..., N, C)
    pix = torch.as_tensor(vis.pixels, device=a.device)
    out = a.new_zeros(a.shape[:-2] + (vis.triangle_id.size, a.shape[-1]))
    out = out.index_copy(out.ndim - 2, pix, vals)
    return out.reshape(a.shape[:-2] + tuple(vis.shape) + (a.shape[-1],))


def interpolate(vis, attributes, triangles=None):
    """Interpolate per-vertex attributes at every sample of a visibility.

    Parameters
    ----------
    vis : Visibility, or a list of B Visibility (torch (B, V, C) attributes, one per item)
    attributes : (V, C) or (V,) numpy array, or (V, C) / (B, V, C) torch tensor
        One row per vertex (or per id of ``triangles``).
    triangles : (F, 3) int or None
        Corner ids to look the rows up with; default ``vis.triangles``. Pass a
        ``triangle_uv`` table to interpolate per-corner texture coordinates.

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
        if not _is_torch(attributes) or attributes.ndim != 3 or attributes.shape[0] != len(vis):
            raise InputError("a list of visibilities needs a torch (B, V, C) tensor with B = "
                             "len(list)")
        import torch

        return torch.stack([_interpolate_torch(v, a, triangles) for v, a in zip(vis, attributes)])
    if not isinstance(vis, Visibility):
        raise InputError(f"vis must be a Visibility, got {type(vis).__name__}")
    if _is_torch(attributes):
        return _interpolate_torch(vis, attributes, triangles)
    return _interpolate_numpy(vis, attributes, triangles)
