"""Face descriptors: who a face is, as a point of a space where one person's faces lie close.

dlib's face recognition network (a ResNet, ``dlib_face_recognition_resnet_model_v1.dat`` of
the ``face-recognition-models`` package, the ``detect`` extra) maps a face, aligned by its
68 iBUG points, to a 128-D vector; two photos of one person lie less than about 0.6 apart
(Euclidean), of two people further (dlib's own threshold, 99.38 % on LFW; ours is
calibrated below). The tracker
(:mod:`morphable.tracking`) joins the tracks of one person across a video's shots by it;
its threshold here, :data:`SAME_PERSON_DISTANCE`, is calibrated on real photos
(``python -m evaluation.bench_footage --calibrate``, docs/video.md).

dlib is imported when a descriptor is first computed; the network loads once per process.

>>> from morphable.detection import detect_all, read_image
>>> photos = [read_image(f"../shared/data/images/{n}") for n in ("image_0010.png", "einstein.jpg")]
>>> photos.append(photos[0][:, 40:])                 # the first photo cut: the same face
>>> d = np.concatenate([face_descriptors(p, [detect_all(p)[0].ibug68]) for p in photos])
>>> d.shape, bool(descriptor_distance(d[0], d[2])[0, 0] < 0.2 < 0.6 < descriptor_distance(d[0], d[1])[0, 0])
((3, 128), True)
"""
from __future__ import annotations

import functools

import numpy as np

from .errors import InputError

__all__ = ["SAME_PERSON_DISTANCE", "DESCRIPTOR_SIZE", "face_descriptors", "descriptor_distance"]

DESCRIPTOR_SIZE = 128
SAME_PERSON_DISTANCE = 0.49
"""Descriptor distance below which two faces are taken for one person: the middle between the
same-person distances' 95th percentile (0.31) and the different-person distances' 5th (0.67)
on the London set (102 people, a neutral and a smiling photo each) and 200 AFLW crops
(research use only): ``python -m evaluation.bench_footage --calibrate`` (docs/video.md,
"Footage: several people and shot cuts"). There no same-person pair lies further apart and
0.08 % of the different-person pairs nearer; at dlib's own 0.6, 1.2 % of them."""


@functools.lru_cache(maxsize=None)
def _network():
    from .detection.dlib_detector import model_file

    try:
        import dlib
    except ImportError:
        raise InputError("face descriptors need the 'detect' extra: pip install dlib-bin") from None
    return dlib, dlib.face_recognition_model_v1(str(model_file("dlib_face_recognition_resnet_model_v1.dat")))


def face_descriptors(image, ibug68) -> np.ndarray:
    """The descriptors of faces of one picture.

    Parameters
    ----------
    image : (H, W, 3) uint8 RGB
    ibug68 : list of (68, 2) px arrays (or an (N, 68, 2) array), each face's iBUG points
        (0-based, x right, y down), which align it for the network

    Returns
    -------
    (N, 128) float32; compare with :func:`descriptor_distance`.
    """
    dlib, net = _network()
    pts = np.asarray(ibug68, dtype=np.float64).reshape(-1, 68, 2)
    if not len(pts):
        return np.zeros((0, DESCRIPTOR_SIZE), np.float32)
    if not np.isfinite(pts).all():
        raise InputError("face descriptors: landmarks contain NaN or inf")
    img = np.ascontiguousarray(image, dtype=np.uint8)
    shapes = dlib.full_object_detections()
    for p in pts:
        lo, hi = np.floor(p.min(0)), np.ceil(p.max(0))
        rect = dlib.rectangle(int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1]))
        shapes.append(dlib.full_object_detection(rect, [dlib.point(int(round(x)), int(round(y))) for x, y in p]))
    return np.asarray(net.compute_face_descriptor(img, shapes), dtype=np.float32).reshape(-1, DESCRIPTOR_SIZE)


def descriptor_distance(a, b) -> np.ndarray:
    """Euclidean distances of descriptors: ``a`` (N, 128) and ``b`` (M, 128) -> (N, M).

    >>> descriptor_distance(np.eye(128)[:2], np.eye(128)[:1]).round(3).tolist()
    [[0.0], [1.414]]
    """
    a = np.asarray(a, dtype=np.float64).reshape(-1, DESCRIPTOR_SIZE)
    b = np.asarray(b, dtype=np.float64).reshape(-1, DESCRIPTOR_SIZE)
    return np.sqrt(np.maximum(0.0, (a * a).sum(1)[:, None] + (b * b).sum(1)[None] - 2 * a @ b.T))
