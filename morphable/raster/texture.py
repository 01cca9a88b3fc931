"""Bilinear texture look-up at UV coordinates (numpy, or torch through grid_sample).

UV convention: u in [0, 1] runs from the image's left edge to its right edge, v in [0, 1]
from the bottom edge to the top (v up); texel centres sit at ``((j + 0.5) / w, 1 - (i + 0.5) / h)``.
Look-ups outside the texture clamp to the border.
"""
from __future__ import annotations

import numpy as np

from ..arrays import is_torch
from ..errors import InputError

__all__ = ["as_texture", "sample_texture"]


def as_texture(image) -> np.ndarray:
    """An image (h, w), (h, w, 3|4) uint8/uint16/float, or a path -> (h, w, 3) float32 in [0, 1]."""
    if isinstance(image, (str, bytes)) or hasattr(image, "__fspath__"):
        from PIL import Image

        try:
            with Image.open(image) as im:
                image = np.asarray(im.convert("RGB"))
        except (OSError, ValueError, Image.DecompressionBombError) as e:
            raise InputError(f"{image}: cannot read image ({e})") from None
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, -1)
    if a.ndim != 3 or a.shape[-1] not in (3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise InputError(f"texture must be an (h, w, 3) image, got shape {a.shape}")
    a = a[..., :3]
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float32) / 65535.0
    a = a.astype(np.float32)
    if not np.isfinite(a).all():
        raise InputError("texture contains NaN or inf")
    return a


def sample_texture(texture, uv):
    """Bilinear samples of ``texture`` at ``uv``.

    Parameters
    ----------
    texture : (h, w, C) float array, or torch tensor (h, w, C) / (B, h, w, C)
    uv : (..., 2) float (numpy), or torch (..., 2) / (B, ..., 2) matching the texture batch

    Returns
    -------
    (..., C), same type as ``texture``; the torch form is differentiable with respect to
    both the texture and the UVs.

    Examples
    --------
    >>> tex = np.array([[[0.], [1.]]])  # 1 x 2 texels: black left, white right
    >>> sample_texture(tex, np.array([[0.25, 0.5], [0.5, 0.5], [1.0, 0.5]]))
    array([[0. ],
           [0.5],
           [1. ]])
    """
    if is_torch(texture):
        import torch
        import torch.nn.functional as F

        batched = texture.ndim == 4
        tex = texture if batched else texture[None]
        g = torch.as_tensor(uv, dtype=tex.dtype, device=tex.device)
        g = g if batched else g[None]
        lead = g.shape[1:-1]
        grid = torch.stack([2 * g[..., 0] - 1, 1 - 2 * g[..., 1]], -1).reshape(g.shape[0], 1, -1, 2)
        out = F.grid_sample(tex.permute(0, 3, 1, 2), grid, mode="bilinear",
                            padding_mode="border", align_corners=False)  # (B, C, 1, N)
        out = out[:, :, 0].permute(0, 2, 1).reshape((g.shape[0],) + tuple(lead) + (tex.shape[-1],))
        return out if batched else out[0]
    tex = np.asarray(texture)
    uv = np.asarray(uv, dtype=np.float64)
    h, w = tex.shape[:2]
    x = np.clip(uv[..., 0] * w - 0.5, 0, w - 1)
    y = np.clip((1 - uv[..., 1]) * h - 0.5, 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 1)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 1)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    top = tex[y0, x0] * (1 - fx) + tex[y0, x1] * fx
    bottom = tex[y1, x0] * (1 - fx) + tex[y1, x1] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.result_type(tex.dtype, np.float32), copy=False)
