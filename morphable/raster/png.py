"""PNG export of normal maps, depth maps, masks and images (written atomically).

- normal map: 8-bit RGB ``round(255 * (n + 1) / 2)``; background (zero normals) is black
  (0, 0, 0), which decodes to no unit vector and so cannot be mistaken for a normal.
- depth: 16-bit grey; background 0, the surface linearly from 1 (``near`` mm) to 65535
  (``far`` mm). near and far are stored in the PNG's text chunks ``depth_near_mm`` and
  ``depth_far_mm``; :func:`read_depth_png` decodes back to millimetres.
- mask: 8-bit grey, 255 on the mesh, 0 elsewhere.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..io.atomic import atomic_path

__all__ = ["save_normal_png", "save_depth_png", "save_mask_png", "save_image_png",
           "read_depth_png", "check_png_path"]


def check_png_path(path):
    """``path`` as a Path, or an InputError unless it names a .png in an existing folder (to
    call before any work, so that a bad output path leaves no partial outputs)."""
    from pathlib import Path

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: output must be a .png file")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"{path}: output folder {folder} does not exist")
    return path


def _write(path, array, pnginfo=None):
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(array).save(tmp, format="PNG", pnginfo=pnginfo)
    return path


def _image(a, name, channels):
    if hasattr(a, "detach"):
        a = a.detach().cpu().numpy()
    a = np.asarray(a)
    ok = a.ndim == 3 and a.shape[-1] == channels if channels else a.ndim == 2
    if not ok or a.shape[0] == 0 or a.shape[1] == 0:
        raise InputError(f"{name} must be (H, W{', %d' % channels if channels else ''}), got {a.shape}")
    return a


def save_normal_png(path, normals, mask=None):
    """Write an (H, W, 3) normal map (unit vectors, zero background) as RGB (n + 1) / 2.

    ``mask`` (H, W) bool overrides which pixels are background (default: zero vectors).
    """
    n = _image(normals, "normal map", 3).astype(np.float64)
    if not np.isfinite(n).all():
        raise InputError(f"{path}: normal map contains NaN or inf; nothing written")
    fg = (np.abs(n).sum(-1) > 0) if mask is None else np.asarray(mask, dtype=bool)
    rgb = np.clip(np.round(255 * (n + 1) / 2), 0, 255).astype(np.uint8)
    rgb[~fg] = 0
    return _write(path, rgb)


def save_depth_png(path, depth, near=None, far=None):
    """Write an (H, W) depth map in mm (inf, NaN or 0 = background) as 16-bit PNG.

    ``near``/``far`` (mm) default to the foreground's min and max; values outside clamp.
    Returns (near, far).
    """
    from PIL import PngImagePlugin

    d = _image(depth, "depth map", 0).astype(np.float64)
    fg = np.isfinite(d) & (d != 0)
    if fg.any():
        near = float(d[fg].min()) if near is None else float(near)
        far = float(d[fg].max()) if far is None else float(far)
    else:
        near = 0.0 if near is None else float(near)
        far = near + 1.0 if far is None else float(far)
    if not (np.isfinite(near) and np.isfinite(far)) or far < near:
        raise InputError(f"{path}: depth range near={near}, far={far} is not valid")
    span = max(far - near, 1e-9)
    q = np.zeros(d.shape, dtype=np.uint16)
    q[fg] = np.round(1 + np.clip((d[fg] - near) / span, 0, 1) * 65534).astype(np.uint16)
    info = PngImagePlugin.PngInfo()
    info.add_text("depth_near_mm", repr(near))
    info.add_text("depth_far_mm", repr(far))
    _write(path, q, pnginfo=info)
    return near, far


def read_depth_png(path) -> np.ndarray:
    """Inverse of :func:`save_depth_png`: (H, W) float64 mm, inf on background."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            q = np.asarray(im).astype(np.float64)
            near, far = float(im.text["depth_near_mm"]), float(im.text["depth_far_mm"])
    except (OSError, KeyError, ValueError) as e:
        raise InputError(f"{path}: not a depth PNG written by morphable ({e})") from None
    return np.where(q > 0, near + (q - 1) / 65534 * max(far - near, 1e-9), np.inf)


def save_mask_png(path, mask):
    """Write an (H, W) bool mask (or a coverage in [0, 1]) as 8-bit grey."""
    m = _image(mask, "mask", 0)
    if m.dtype == bool:
        m = m.astype(np.float64)
    m = np.nan_to_num(m.astype(np.float64), nan=0.0)
    return _write(path, np.round(255 * np.clip(m, 0, 1)).astype(np.uint8))


def save_image_png(path, image):
    """Write an (H, W, 3) float image in [0, 1] as 8-bit RGB."""
    a = _image(image, "image", 3).astype(np.float64)
    if not np.isfinite(a).all():
        raise InputError(f"{path}: image contains NaN or inf; nothing written")
    return _write(path, np.round(255 * np.clip(a, 0, 1)).astype(np.uint8))
