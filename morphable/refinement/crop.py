"""The face crop a renderer is inverted in: its square (FFHQ framing), camera and image."""
from __future__ import annotations

import dataclasses

import numpy as np

from ..camera import Camera
from ..errors import InputError

__all__ = ["face_frame", "face_crop", "crop_camera", "crop_image", "pad_like_ffhq"]


def face_frame(landmarks) -> tuple[np.ndarray, float]:
    """The FFHQ framing of a face: (68, D) iBUG landmarks (2D pixels or 3D mm) -> (centre (D,),
    width) in their unit: a square 4 x the inter-ocular distance wide (at least 3.6 x the
    eye-mouth distance), centred 0.1 of the way from the eye midpoint to the mouth centre. The
    neural plugin frames its training faces by it (the mean face's 3D landmarks), the
    refinement its crops (a photo's).

    >>> lm = np.zeros((68, 2))
    >>> lm[36:42], lm[42:48], lm[48:68] = (20, 30), (44, 30), (32, 50)
    >>> centre, width = face_frame(lm)
    >>> centre.tolist(), width
    ([32.0, 32.0], 96.0)
    """
    lm = np.asarray(landmarks, dtype=np.float64)
    eyes = _mean_of_given(lm[36:42]), _mean_of_given(lm[42:48])
    mouth = _mean_of_given(lm[48:68])
    if not (np.isfinite(eyes).all() and np.isfinite(mouth).all()):
        raise InputError("face crop: eye and mouth landmarks are missing")
    mid = (eyes[0] + eyes[1]) / 2
    centre = mid + 0.1 * (mouth - mid)
    width = 2.0 * max(2.0 * np.linalg.norm(eyes[1] - eyes[0]), 1.8 * np.linalg.norm(mouth - mid))
    return centre, float(width)


def _mean_of_given(points) -> np.ndarray:
    """(N, D) with missing rows NaN -> (D,) mean of the given rows (NaN when none is given;
    np.nanmean would warn "Mean of empty slice")."""
    given = np.isfinite(points).all(1)
    return points[given].mean(0) if given.any() else np.full(points.shape[1], np.nan)


def face_crop(landmarks) -> tuple[float, float, float]:
    """(68, 2) pixels -> square crop ``(left, top, side)`` in pixel-edge coordinates (the
    image spans [0, W] x [0, H]) of the :func:`face_frame`.

    >>> lm = np.zeros((68, 2))
    >>> lm[36:42], lm[42:48], lm[48:68] = (20, 30), (44, 30), (32, 50)
    >>> face_crop(lm)           # 4 x 24 px wide, centred 2 px below the eyes
    (-15.5, -15.5, 96.0)
    """
    centre, side = face_frame(landmarks)
    centre = centre + 0.5                                          # to pixel-edge coordinates
    if side < 4:
        raise InputError(f"face crop: the face is only {side:.1f} px wide")
    return float(centre[0] - side / 2), float(centre[1] - side / 2), float(side)


def crop_camera(camera: Camera, crop, resolution: int) -> Camera:
    """The camera that sees ``crop`` = (left, top, side) of ``camera``'s image as a
    ``resolution`` x ``resolution`` image (pixel centre u' = (u + 0.5 - left) k - 0.5)."""
    left, top, side = crop
    k = resolution / side
    principal = (camera.principal + 0.5 - np.array([left, top])) * k - 0.5
    return dataclasses.replace(camera, scale=camera.scale * k, focal=camera.focal * k,
                               image_size=(resolution, resolution), principal=principal)


def pad_like_ffhq(image, box) -> tuple[np.ndarray, tuple[int, int]]:
    """Extend a photo so that a crop reaching past it shows background rather than black, the
    way FFHQ's alignment does (Karras et al. 2019, ``recreate_aligned_images``): the photo is
    mirrored at its edges, and the mirror is blurred more and faded towards the photo's median
    colour the further out it lies.

    image : (H, W, 3) uint8; box : (left, top, right, bottom) of the crop in pixel-edge
    coordinates (the photo spans [0, W] x [0, H]) -> (padded (H', W', 3) uint8, (dx, dy)):
    photo pixel (x, y) is padded pixel (x + dx, y + dy). A box inside the photo returns the
    photo itself and (0, 0).

    >>> img = np.full((40, 30, 3), 200, np.uint8)
    >>> out, (dx, dy) = pad_like_ffhq(img, (-10, -10, 50, 50))
    >>> out.shape, (dx, dy), int(out[0, 0, 0])
    ((76, 74, 3), (18, 18), 200)
    """
    a = np.asarray(image)[..., :3]
    H, W = a.shape[:2]
    left, top, right, bottom = (float(v) for v in box)
    need = np.array([-left, -top, right - W, bottom - H])
    if need.max() <= 0:
        return a, (0, 0)
    side = max(right - left, bottom - top)
    # FFHQ's margins: 0.1 of the crop beyond what it needs, every side at least 0.3 of it, so
    # that the fade to the median is gradual
    border = max(int(round(0.1 * side)), 3)
    pl, pt, pr, pb = (int(v) for v in np.maximum(np.ceil(need).astype(int) + border,
                                                 int(round(0.3 * side))))
    f = np.pad(a.astype(np.float32), ((pt, pb), (pl, pr), (0, 0)), mode="reflect")
    h, w = f.shape[:2]
    x = np.arange(w, dtype=np.float32)[None, :]
    y = np.arange(h, dtype=np.float32)[:, None]
    # 0 on the photo's edge, 1 on the padding's outer edge, negative inside the photo
    out = np.maximum(1.0 - np.minimum(x / pl, (w - 1 - x) / pr),
                     1.0 - np.minimum(y / pt, (h - 1 - y) / pb))[..., None]
    f += (_wide_blur(f, 0.02 * side) - f) * np.clip(out * 3.0 + 1.0, 0.0, 1.0)
    f += (np.median(f, axis=(0, 1)) - f) * np.clip(out, 0.0, 1.0)
    return np.round(np.clip(f, 0.0, 255.0)).astype(np.uint8), (pl, pt)


def _wide_blur(f, sigma: float) -> np.ndarray:
    """(h, w, C) float32 blurred by a Gaussian of ``sigma`` px. A wide one (sigma >= 8 px) is
    computed on a copy reduced k = sigma // 4 times (block means) and interpolated back: at 4 or
    more reduced pixels per sigma the reduction is invisible, and it costs 1 / k^3 (a 1600-px
    photo's padding for an 1100-px crop took 2 s with the full-resolution blur)."""
    from PIL import Image
    from scipy.ndimage import gaussian_filter

    k = int(sigma // 4)
    if k < 2:
        return gaussian_filter(f, [sigma, sigma, 0])
    h, w, C = f.shape
    H, W = -(-h // k) * k, -(-w // k) * k
    small = np.pad(f, ((0, H - h), (0, W - w), (0, 0)), mode="edge")
    small = small.reshape(H // k, k, W // k, k, C).mean((1, 3))
    small = gaussian_filter(small, [sigma / k, sigma / k, 0]).astype(np.float32)
    # PIL resizes pixels as areas: reduced pixel q's centre lands on its block's centre
    return np.stack([np.asarray(Image.fromarray(np.ascontiguousarray(small[..., c]), "F").resize(
        (W, H), Image.Resampling.BILINEAR))[:h, :w] for c in range(C)], -1)


def crop_image(image, crop, resolution: int) -> np.ndarray:
    """(H, W, 3) uint8 or float [0, 1] -> (resolution, resolution, 3) float [0, 1] of the
    crop (area-averaged; where it leaves the image, :func:`pad_like_ffhq`'s background, as in
    the renderers' training crops)."""
    from PIL import Image

    a = np.asarray(image)
    if a.dtype != np.uint8:
        a = np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)
    left, top, side = crop
    # PIL's box must lie inside the image
    a, (dx, dy) = pad_like_ffhq(a, (left, top, left + side, top + side))
    im = Image.fromarray(np.ascontiguousarray(a)).resize(
        (resolution, resolution), Image.BOX, box=(left + dx, top + dy, left + dx + side, top + dy + side))
    return np.asarray(im, dtype=np.float32) / 255.0
