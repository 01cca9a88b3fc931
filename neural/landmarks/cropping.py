"""The landmark network's crops in numpy: the geometry (:func:`crop_theta`, :func:`crop_to_image`,
:func:`image_to_crop`) and the bilinear sampling (:func:`sample_crops`) that the detector runs
without torch, and that the trainer's ``grid_sample`` crops (:func:`neural.landmarks.network.crop_images`)
follow.

A crop: a square face box (``(x0, y0, x1, y1)`` px, :func:`neural.faces.points.face_box`
framing), optionally rotated by ``angle`` (radians, the crop's x axis turned counter-clockwise
in the image) and mirrored, resampled to R x R. Crop-normalised coordinates ``q`` in [-1, 1]
(pixel centres at ``(2j + 1) / R - 1``) map to image pixels by
``p = c + s/2 · Rot(angle) · diag(±1, 1) · q`` (c: box centre, s: side). ``theta`` (B, 2, 3)
is that map in torch's ``affine_grid`` convention (``align_corners=False``): from crop-normalised
to image-normalised coordinates ``u = (2 p + 1) / (W, H) - 1``.

Pixels x right, y down, 0-based pixel centres.

The crop's corners are the box's:

>>> theta = crop_theta(np.array([[10.0, 20.0, 74.0, 84.0]]), (200, 100))
>>> crop_to_image(np.array([[[-1.0, -1.0], [1.0, 1.0]]]), theta, (200, 100)).round(6).tolist()
[[[10.0, 20.0], [74.0, 84.0]]]
"""
from __future__ import annotations

import numpy as np

from ..faces.points import box_side

__all__ = ["crop_theta", "crop_to_image", "image_to_crop", "sample_crops"]


def crop_theta(boxes, image_sizes, angle=None, flip=None) -> np.ndarray:
    """(B, 2, 3) float64 ``affine_grid`` matrices of crops (``align_corners=False``).

    boxes (B, 4) px ``(x0, y0, x1, y1)`` (the side is the mean of width and height);
    image_sizes (2,) or (B, 2) ``(W, H)`` px; angle (B,) radians or None; flip (B,) bool or None."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    n = len(boxes)
    wh = np.broadcast_to(np.asarray(image_sizes, dtype=np.float64).reshape(-1, 2), (n, 2))
    c = (boxes[:, :2] + boxes[:, 2:]) / 2
    if angle is None:
        M = np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    else:
        a = np.asarray(angle, dtype=np.float64).reshape(n)
        cos, sin = np.cos(a), np.sin(a)
        # y points down: a positive angle turns the crop's x axis towards -y (counter-clockwise)
        M = np.stack([np.stack([cos, sin], -1), np.stack([-sin, cos], -1)], -2)
    M = M * (box_side(boxes) / 2)[:, None, None]
    if flip is not None:
        M[:, :, 0] *= np.where(np.asarray(flip, dtype=bool).reshape(n), -1.0, 1.0)[:, None]
    scale = (2 / wh)[:, :, None]
    return np.concatenate([M * scale, (scale[:, :, 0] * c + 1 / wh - 1)[:, :, None]], axis=2)


def crop_to_image(q, theta, image_sizes) -> np.ndarray:
    """Crop-normalised points q (B, P, 2) -> image px (B, P, 2) through the crops' ``theta``
    (B, 2, 3); image_sizes (2,) or (B, 2) ``(W, H)`` px."""
    theta = np.asarray(theta, dtype=np.float64)
    wh = np.asarray(image_sizes, dtype=np.float64).reshape(-1, 1, 2)
    u = np.asarray(q, dtype=np.float64) @ theta[:, :, :2].transpose(0, 2, 1) + theta[:, None, :, 2]
    return ((u + 1) * wh - 1) / 2


def image_to_crop(p, theta, image_sizes) -> np.ndarray:
    """Image px (B, P, 2) -> crop-normalised (B, P, 2): the inverse of :func:`crop_to_image`."""
    theta = np.asarray(theta, dtype=np.float64)
    wh = np.asarray(image_sizes, dtype=np.float64).reshape(-1, 1, 2)
    u = (2 * np.asarray(p, dtype=np.float64) + 1) / wh - 1
    return (u - theta[:, None, :, 2]) @ np.linalg.inv(theta[:, :, :2]).transpose(0, 2, 1)


def sample_crops(image: np.ndarray, theta, resolution: int) -> np.ndarray:
    """(B, C, R, R) float32 crops of one ``image`` (H, W, C) float32 at ``theta`` (B, 2, 3) of
    upright crops (no rotation; mirrored or not): bilinear, zero outside the image; torch's
    ``grid_sample(image, affine_grid(theta), align_corners=False, padding_mode="zeros")`` in
    numpy. An upright crop's x depends on its column only and y on its row only, so the
    sampling positions and weights are worked out per row and per column."""
    H, W, C = image.shape
    theta = np.asarray(theta, dtype=np.float64).reshape(-1, 2, 3)
    if np.any(theta[:, 0, 1] != 0) or np.any(theta[:, 1, 0] != 0):
        raise ValueError("sample_crops: rotated crops are the trainer's (neural.landmarks.network.crop_images)")
    j = (2 * np.arange(resolution) + 1) / resolution - 1
    # each column's x and each row's y, image px: (B, R) each
    x = ((theta[:, 0, 0, None] * j + theta[:, 0, 2, None] + 1) * W - 1) / 2
    y = ((theta[:, 1, 1, None] * j + theta[:, 1, 2, None] + 1) * H - 1) / 2
    x0, y0 = np.floor(x), np.floor(y)
    wx, wy = (x - x0).astype(np.float32), (y - y0).astype(np.float32)
    # one pixel of zeros around the photo: a neighbour outside it reads zero, as grid_sample's;
    # each corner's flat index into it (B, R, R), each channel gathered from its own plane
    xi = [np.clip(x0 + d, -1, W).astype(np.intp) + 1 for d in (0, 1)]
    yi = [(np.clip(y0 + d, -1, H).astype(np.intp) + 1) * (W + 2) for d in (0, 1)]
    xw, yw = (1 - wx, wx), (1 - wy, wy)
    corners = [(yi[a][:, :, None] + xi[b][:, None, :], yw[a][:, :, None] * xw[b][:, None, :])
               for a in (0, 1) for b in (0, 1)]
    out = np.empty((len(theta), C, resolution, resolution), np.float32)
    for c in range(C):
        plane = np.pad(image[:, :, c].astype(np.float32), 1).ravel()
        out[:, c] = sum(plane.take(index) * weight for index, weight in corners)
    return out
