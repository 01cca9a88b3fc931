"""dlib's 128-D face descriptor (``dlib.face_recognition_model_v1``, the ResNet of the
``face-recognition-models`` package) on aligned crops and on photos.

- :func:`aligned_descriptors`: crops in our FFHQ-style framing (:func:`neural.faces.renders.template`),
  e.g. GAR samples or a pack's images. No detection: dlib's five alignment points (outer and
  inner eye corners, the base of the nose: iBUG 46, 43, 37, 40, 34) are where the framing puts
  the mean face's landmarks, and dlib cuts its own 150 px chip around them from the crop
  upsampled (bicubic) to at least 256 px. On six London photos aligned at 64 px, dlib's own
  detector and 5-point predictor put its points 0.3-1.1 px (mean per point) from these
  positions; the descriptors of a photo's crop and of the photo itself are 0.23-0.40 apart
  (four people, eight photos).
- :func:`point_descriptors`: images with their iBUG-68 points known (e.g. synthetic faces'
  exact labels): dlib's chip cut around the five points taken from them.
- :func:`photo_descriptors`: original photos, dlib's way: its HOG face detector (the largest
  face), its 5-point shape predictor and its chip.

Descriptors of one person are about 0.4 apart, of two people about 0.8 (dlib's threshold 0.6).
"""
from __future__ import annotations

import functools

import numpy as np

__all__ = ["DLIB_FIVE", "as_uint8_images", "aligned_descriptors", "point_descriptors", "photo_descriptors"]

DLIB_FIVE = (45, 42, 36, 39, 33)
"""The iBUG-68 points (0-based) at dlib's five alignment points, in its order."""


@functools.lru_cache(maxsize=None)
def _dlib_models():
    import dlib

    from morphable.detection.dlib_detector import model_file

    return (dlib.face_recognition_model_v1(str(model_file("dlib_face_recognition_resnet_model_v1.dat"))),
            dlib.shape_predictor(str(model_file("shape_predictor_5_face_landmarks.dat"))),
            dlib.get_frontal_face_detector())


def as_uint8_images(images) -> np.ndarray:
    """(N, 3, R, R) images in [-1, 1] (torch tensor or array) or (N, R, R, 3) uint8 ->
    (N, R, R, 3) uint8."""
    if hasattr(images, "detach"):
        images = images.detach().cpu().numpy()
    a = np.asarray(images)
    if a.dtype == np.uint8:
        if a.ndim != 4 or a.shape[-1] != 3:
            raise ValueError(f"uint8 images must be (N, R, R, 3), got {a.shape}")
        return a
    if a.ndim != 4 or a.shape[1] != 3:
        raise ValueError(f"float images must be (N, 3, R, R) in [-1, 1], got {a.shape}")
    return np.round((np.clip(a, -1, 1) + 1) * 127.5).astype(np.uint8).transpose(0, 2, 3, 1).copy()


def aligned_descriptors(images, model: str = "sfm", batch_size: int = 64) -> np.ndarray:
    """(N, 128) dlib descriptors of aligned crops (see the module docstring), ``images`` as
    :func:`as_uint8_images` takes them."""
    import dlib
    from PIL import Image

    from neural.faces.renders import template

    imgs = as_uint8_images(images)
    N, R = imgs.shape[:2]
    k = max(1, -(-256 // R))
    five = (template(R, model)[list(DLIB_FIVE)] + 0.5) * k - 0.5
    net = _dlib_models()[0]
    size = R * k
    rect = dlib.rectangle(0, 0, size - 1, size - 1)
    shape = dlib.full_object_detection(rect, [dlib.point(int(round(x)), int(round(y))) for x, y in five])
    out = []
    for i in range(0, N, batch_size):
        up = [np.asarray(Image.fromarray(im).resize((size, size), Image.Resampling.BICUBIC))
              for im in imgs[i:i + batch_size]]
        shapes = [dlib.full_object_detections([shape]) for _ in up]
        out.extend(np.asarray(d[0]) for d in net.compute_face_descriptor(up, shapes))
    return np.array(out, np.float64).reshape(N, 128)


def point_descriptors(images, points68) -> np.ndarray:
    """(N, 128) dlib descriptors of (N, H, W, 3) uint8 images (or a list of them) whose iBUG-68
    points (N, 68, 2) px are known: dlib's 150 px chip is cut around the five points
    :data:`DLIB_FIVE` of each (no detection). Unlike
    :func:`morphable.descriptors.face_descriptors` (all 68 points, finite), it takes labels
    with undefined rows, as SFM's synthetic faces have (two NaN rows)."""
    import dlib

    net = _dlib_models()[0]
    out = []
    for img, pts in zip(images, np.asarray(points68, np.float64)):
        five = pts[list(DLIB_FIVE)]
        lo, hi = five.min(0), five.max(0)
        rect = dlib.rectangle(*(int(round(v)) for v in (lo[0], lo[1], hi[0], hi[1])))
        shape = dlib.full_object_detection(rect, [dlib.point(int(round(x)), int(round(y))) for x, y in five])
        out.append(np.asarray(net.compute_face_descriptor(np.ascontiguousarray(img), shape)))
    return np.array(out, np.float64).reshape(-1, 128)


def photo_descriptors(paths, upsample: int = 1) -> np.ndarray:
    """(N, 128) dlib descriptors of photos (files), each of its largest face as dlib finds
    it (HOG detector upsampling ``upsample`` times, 5-point predictor); NaN rows where no
    face is found."""
    from PIL import Image

    net, shape_predictor, detector = _dlib_models()
    out = np.full((len(paths), 128), np.nan)
    for i, p in enumerate(paths):
        img = np.asarray(Image.open(p).convert("RGB"))
        faces = detector(img, int(upsample))
        if not len(faces):
            continue
        face = max(faces, key=lambda r: r.width() * r.height())
        out[i] = np.asarray(net.compute_face_descriptor(img, shape_predictor(img, face)))
    return out
