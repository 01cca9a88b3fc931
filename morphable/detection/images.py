"""Photos as the detectors see them: (H, W, 3) uint8 RGB, upright.

Grayscale, grayscale + alpha, palette, RGBA, CMYK, 16-bit and EXIF-rotated files all become
the same upright 8-bit RGB picture, so that detected points land on the face whatever the
file's encoding, and :func:`image_size` gives the size of that upright picture.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["read_image", "as_image", "image_size", "upright_size"]

# EXIF orientations 5-8 turn the picture by 90 degrees: width and height swap
_TRANSPOSED = {5, 6, 7, 8}
_ORIENTATION_TAG = 0x0112


def upright_size(im) -> tuple[int, int]:
    """(W, H) of an open PIL image once turned upright by its EXIF orientation."""
    W, H = im.size
    try:
        turned = im.getexif().get(_ORIENTATION_TAG) in _TRANSPOSED
    except (OSError, ValueError, SyntaxError):  # an unreadable EXIF block counts as none
        turned = False
    return (H, W) if turned else (W, H)


def image_size(path) -> tuple[int, int]:
    """(W, H) pixels of an image file once upright, from its header only (no decoding, so a
    huge image costs nothing).

    Raises InputError naming the file when it is missing, unreadable or not an image.
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    try:
        with Image.open(path) as im:
            # checks the PNG chunks' CRCs to the end of the file without decoding: a
            # truncated or corrupt image is refused here, not after a minute of fitting
            im.verify()
        with Image.open(path) as im:  # verify() leaves the file unusable: again for the EXIF
            W, H = upright_size(im)
    except FileNotFoundError:
        raise InputError(f"{path}: no such image") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not an image") from None
    except Image.DecompressionBombError as e:
        raise InputError(f"{path}: image too large ({e})") from None
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError) as e:
        raise InputError(f"{path}: cannot read image ({e})") from None
    if W <= 0 or H <= 0:
        raise InputError(f"{path}: image has no pixels ({W}x{H})")
    return int(W), int(H)


def _to_rgb(im) -> np.ndarray:
    """An open PIL image in any mode -> (H, W, 3) uint8 RGB (transparency over white)."""
    from PIL import Image

    if im.mode in ("I;16", "I;16B", "I;16L", "I;16N", "I", "F"):
        # 16-bit and 32-bit grey: PIL's convert("RGB") clips at 255 (a white picture)
        a = np.asarray(im, dtype=np.float64)
        top = 1.0 if im.mode == "F" and a.max(initial=0.0) <= 1.0 else 65535.0
        g = np.clip(np.round(a * (255.0 / top)), 0, 255).astype(np.uint8)
        return np.repeat(g[..., None], 3, axis=-1)
    if im.mode == "P" and "transparency" in im.info:
        im = im.convert("RGBA")
    if im.mode in ("RGBA", "LA", "PA", "La", "RGBa"):
        im = im.convert("RGBA")
        white = Image.new("RGBA", im.size, (255, 255, 255, 255))
        im = Image.alpha_composite(white, im)
    return np.asarray(im.convert("RGB"))


def read_image(path) -> np.ndarray:
    """A photo file -> (H, W, 3) uint8 RGB, turned upright by its EXIF orientation.

    Grayscale, palette, RGBA (composited over white), CMYK and 16-bit files are converted;
    anything unreadable is one InputError naming the file.
    """
    from PIL import Image, ImageOps, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            try:
                im = ImageOps.exif_transpose(im)
            except (OSError, ValueError, SyntaxError):
                pass  # an unreadable EXIF block: the picture as stored
            return _to_rgb(im)
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError, Image.DecompressionBombError) as e:
        raise InputError(f"{path}: cannot read image ({e})") from None


def as_image(image, name: str = "image") -> tuple[np.ndarray, str]:
    """A path or an array -> ((H, W, 3) uint8 RGB, the name to put in messages: the path, or
    ``name`` for an array).

    Arrays: (H, W) grey or (H, W, 3|4) colour; uint8 as is, uint16 scaled from 0-65535,
    floats from [0, 1] (or 0-255 when larger).
    """
    if isinstance(image, (str, Path)):
        return read_image(image), str(image)
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    if a.ndim != 3 or a.shape[-1] not in (3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise InputError(f"{name}: expected (H, W, 3) pixels, got {a.shape}")
    if a.dtype.kind not in "uif" or (a.dtype.kind == "f" and not np.isfinite(a).all()):
        raise InputError(f"{name}: expected finite numbers, got {a.dtype}")
    if a.dtype == np.uint16:
        a = np.round(a / 257.0)
    elif a.dtype.kind == "f" and a.max(initial=0.0) <= 1.0:
        a = a * 255.0
    if a.dtype != np.uint8:
        a = np.clip(a, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(a[..., :3]), name
