"""The face crop a renderer is inverted in: its square (FFHQ framing), camera and image."""
from __future__ import annotations

import dataclasses

import numpy as np

from ..camera import Camera
from ..errors import InputError

__all__ = ["face_frame", "face_crop", "crop_camera", "crop_image"]


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
    eyes = np.nanmean(lm[36:42], 0), np.nanmean(lm[42:48], 0)
    mouth = np.nanmean(lm[48:68], 0)
    if not (np.isfinite(eyes).all() and np.isfinite(mouth).all()):
        raise InputError("face crop: eye and mouth landmarks are missing")
    mid = (eyes[0] + eyes[1]) / 2
    centre = mid + 0.1 * (mouth - mid)
    width = 2.0 * max(2.0 * np.linalg.norm(eyes[1] - eyes[0]), 1.8 * np.linalg.norm(mouth - mid))
    return centre, float(width)


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


def crop_image(image, crop, resolution: int) -> np.ndarray:
    """(H, W, 3) uint8 or float [0, 1] -> (resolution, resolution, 3) float [0, 1] of the
    crop (area-averaged; outside the image is black)."""
    from PIL import Image

    a = np.asarray(image)
    if a.dtype != np.uint8:
        a = np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)
    left, top, side = crop
    H, W = a.shape[:2]
    # pad where the crop leaves the image (PIL's box must lie inside it)
    pl, pt = max(0, int(np.ceil(-left))), max(0, int(np.ceil(-top)))
    pr = max(0, int(np.ceil(left + side - W)))
    pb = max(0, int(np.ceil(top + side - H)))
    if pl or pt or pr or pb:
        a = np.pad(a[..., :3], ((pt, pb), (pl, pr), (0, 0)))
    im = Image.fromarray(a[..., :3]).resize((resolution, resolution), Image.BOX,
                                            box=(left + pl, top + pt, left + pl + side,
                                                 top + pt + side))
    return np.asarray(im, dtype=np.float32) / 255.0
