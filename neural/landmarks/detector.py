"""The landmark network as a detector of :mod:`morphable.detection`: ``landmark_detector=
"network"``, registered as ``network = neural.landmarks.detector:NetworkDetector`` in the
entry-point group ``morphable.landmark_detectors``.

A face in a photo, step by step (pixels x right, y down, 0-based pixel centres):

1. a face box: given (``box``: the face's box, its 68 points' extent, as dlib's and the face
   mesh's boxes roughly are, or a video's previous :attr:`Detection.box`), or a face
   detector's (mediapipe's short-range or full-range, dlib's HOG or CNN), each mapped to the
   network's framing (:func:`neural.faces.points.face_box`, a square 1.4 x the 68 points'
   extent, lifted) by its measured :data:`BOX_FRAMING`; with ``face_detector="auto"``,
   mediapipe's short-range then full-range detector when installed, else dlib's HOG
   (:meth:`NetworkDetector.face_detectors_for`), and when they find no face the network's
   own face score over a multi-scale grid of windows (:func:`windows`), the best window's
   face read again in the framing of its own points (:meth:`NetworkDetector.search`), so
   that faces the face detectors miss at large poses are still found;
2. a first pass on the crop of that framing, then (``passes=2``; :data:`PASSES` says why
   not by default) a second on the crop re-centred from the first pass's 68 points through
   ``face_box``; with ``mirror=True`` (:data:`MIRROR` says whether by default) each pass also
   reads the crop mirrored and averages the two answers (:func:`merge_mirrored`);
3. points and σ back to the photo's pixels (σ x framing side / 128).

A box whose network score stays below :data:`FACE_THRESHOLD` is not a face: the next
candidate is tried, and when none is left a :class:`~morphable.errors.FitError` says so.

Crops are cut from the photo reduced by an integer factor (box averaging) so that each crop
pixel covers at most two photo pixels: bilinear sampling alone would alias a large face.

Weights: ``weights=``, else ``$MORPHABLE_LANDMARK_WEIGHTS``, else the committed
``neural/landmarks/weights/landmarks.pt`` (:func:`weights_path`); the network runs as its
exported ONNX graph on onnxruntime where both are here (the committed ``landmarks.onnx``),
else on torch (``backend=``, :mod:`neural.landmarks.runtime`). Crops, mirroring and the way
back to the photo are numpy (:mod:`neural.landmarks.cropping`) whichever runs it, so that a
detection imports no torch where onnxruntime runs the network.
"""
from __future__ import annotations

import importlib.util
import math
import os
from pathlib import Path

import numpy as np

from morphable.detection import FACE_DETECTORS as ALL_FACE_DETECTORS
from morphable.detection.result import FACE_PROBABILITY, Detection
from morphable.errors import FitError, InputError

from ..faces.points import IBUG_ROWS, N_FACEMESH, box_from_points, box_side, face_box, mirror_index
from . import runtime
from .cropping import crop_theta, crop_to_image, sample_crops

__all__ = ["WEIGHTS_ENV", "WEIGHTS_FILE", "BOX_FRAMING", "MIN_BOX_PX", "FACE_THRESHOLD",
           "WINDOW_SIDES", "WINDOW_STEP", "MAX_CANDIDATES", "PASSES", "MIRROR", "weights_path", "framing_box", "extent_box",
           "windows", "crops", "merge_mirrored", "NetworkDetector"]

WEIGHTS_ENV = "MORPHABLE_LANDMARK_WEIGHTS"
# a plain path beside this module, found without importing torch: "auto" asks unavailable() on
# every detection command
WEIGHTS_FILE = Path(__file__).resolve().parent / "weights" / "landmarks.pt"
GET_WEIGHTS = (f"the weights are committed as neural/landmarks/weights/{WEIGHTS_FILE.name} and its "
               "export landmarks.onnx (see neural/landmarks/weights/MODEL_CARD.md), or train them with "
               f"python -m neural.landmarks.train --out DIR and set ${WEIGHTS_ENV}=DIR/landmarks.pt")

BOX_FRAMING = {
    "full-range": (1.264, -0.009, -0.008),   # found 183 of 200
    "short-range": (1.349, -0.014, -0.043),  # found 200 of 200
    "hog": (1.348, -0.003, -0.003),          # found 160 of 200
    "cnn": (1.0, 0.0, 0.0),
}
"""Each face detector's box -> the network's framing: ``(scale, dx, dy)``, the framing's side
``scale x`` the box's side (the mean of its width and height) and its centre moved by
``(dx, dy) x`` that side. Medians over AFLW2000-3D photos 100-299 (research use only):
``python -m evaluation.detector_boxes --start 100 --n 200``."""
MIN_BOX_PX = 16.0
"""Smallest face box (its larger side, px) the network reads: below it a 128-px crop is a
blur of a few pixels."""
FACE_THRESHOLD = FACE_PROBABILITY
"""The face probability (sigmoid of the network's score) from which a crop holds a face
(:data:`morphable.detection.result.FACE_PROBABILITY`)."""
WINDOW_SIDES = (1.0, 0.75, 0.56, 0.42, 0.32, 0.24)
"""Sides of the candidate windows, in units of the photo's shorter side (steps of 3/4,
about twice the training's box-scale jitter)."""
WINDOW_STEP = 0.35
"""Distance of neighbouring windows, in units of their side."""
MAX_CANDIDATES = 3
"""Face-detector boxes tried, largest first, before the windows."""
PASSES = 1
"""Passes by default. The second pass (the crop re-centred on the first pass's 68 points)
does not pay: on the held-out packs with the committed weights it is worse than one pass on
the synthetic and profiled faces and equal on the AFLW ones (docs/landmark_net.md, "Detector
options": ``python -m evaluation.bench_network --set validation``), as it was at steps 1000,
2000 and 9000 of the first run."""
MIRROR = True
"""Whether each pass also reads its crop mirrored by default: on the same held-out packs it
takes the error from 5.05 to 4.80 % (synthetic), 4.13 to 4.00 % (AFLW) and 4.24 to 3.99 %
(profiled) of the 68 points' extent, for 8.9 instead of 6.0 ms per face on one thread
(docs/landmark_net.md, "Detector options")."""
BATCH = 64


def weights_path(weights=None) -> Path:
    """``weights`` if given, else ``$MORPHABLE_LANDMARK_WEIGHTS``, else the committed file."""
    if weights is not None:
        return Path(weights)
    env = os.environ.get(WEIGHTS_ENV)
    return Path(env) if env else WEIGHTS_FILE


def framing_box(box, face_detector: str) -> np.ndarray:
    """A face detector's box (..., 4) px -> the network's framing (..., 4) px, square
    (:data:`BOX_FRAMING`); ``face_detector="box"``: a given box, the face's 68 points' extent,
    framed as :func:`neural.faces.points.face_box` frames the points."""
    b = np.asarray(box, dtype=np.float64)
    if face_detector == "box":
        return box_from_points(b[..., :2], b[..., 2:])
    scale, dx, dy = BOX_FRAMING[face_detector]
    side = box_side(b)
    cx = (b[..., 0] + b[..., 2]) / 2 + dx * side
    cy = (b[..., 1] + b[..., 3]) / 2 + dy * side
    half = scale * side / 2
    return np.stack([cx - half, cy - half, cx + half, cy + half], axis=-1)


def extent_box(framing) -> np.ndarray:
    """The inverse of ``framing_box(., "box")``: framing boxes (..., 4) px -> the square
    68-point extents (..., 4) px that :func:`neural.faces.points.face_box` frames so."""
    from ..faces.points import BOX_LIFT, BOX_SCALE

    f = np.asarray(framing, dtype=np.float64)
    size = box_side(f) / BOX_SCALE
    cx = (f[..., 0] + f[..., 2]) / 2
    cy = (f[..., 1] + f[..., 3]) / 2 + BOX_LIFT * size
    return np.stack([cx - size / 2, cy - size / 2, cx + size / 2, cy + size / 2], axis=-1)


def windows(width: int, height: int, sides=WINDOW_SIDES, step: float = WINDOW_STEP) -> np.ndarray:
    """Candidate framing windows of a ``width`` x ``height`` photo -> (K, 4) px: squares of
    each side in ``sides`` (x the shorter side; none under :data:`MIN_BOX_PX`), ``step`` x
    side apart, spread evenly to cover the photo edge to edge.

    >>> windows(100, 100, sides=(1.0, 0.5), step=0.5).shape
    (10, 4)
    """
    out = []
    for f in sides:
        s = f * min(width, height)
        if s < MIN_BOX_PX:
            continue
        xs = np.linspace(0, width - s, max(1, math.ceil((width - s) / (step * s)) + 1))
        ys = np.linspace(0, height - s, max(1, math.ceil((height - s) / (step * s)) + 1))
        x, y = np.meshgrid(xs, ys)
        x, y = x.ravel() - 0.5, y.ravel() - 0.5        # pixel-edge squares in centre coordinates
        out.append(np.column_stack([x, y, x + s, y + s]))
    return np.concatenate(out) if out else np.zeros((0, 4))


def crops(image: np.ndarray, boxes, resolution: int) -> np.ndarray:
    """(B, 3, R, R) float32 crops in [-1, 1] of the square ``boxes`` (B, 4) px of ``image``
    (H, W, 3) uint8, zero outside the photo, as the trainer crops its packs
    (:func:`neural.landmarks.network.crop_images`; here :func:`neural.landmarks.cropping.sample_crops`).
    Boxes are cut from the photo reduced by ``k = side // (2 R)`` (box averaging), those of one
    ``k`` together from the part of the photo they cover."""
    from PIL import Image

    H, W = image.shape[:2]
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    side = box_side(boxes)
    ks = np.maximum(1, side // (2 * resolution)).astype(int)
    out = np.zeros((len(boxes), 3, resolution, resolution), np.float32)
    for k in np.unique(ks):
        rows = np.flatnonzero(ks == k)
        b = boxes[rows]
        x0, y0 = max(0, math.floor(b[:, 0].min()) - k), max(0, math.floor(b[:, 1].min()) - k)
        x1, y1 = min(W, math.ceil(b[:, 2].max()) + k + 1), min(H, math.ceil(b[:, 3].max()) + k + 1)
        if x1 <= x0 or y1 <= y0:
            continue                                   # wholly outside the photo: zeros
        sub = image[y0:y1, x0:x1]
        if k > 1:
            sub = np.asarray(Image.fromarray(np.ascontiguousarray(sub)).reduce(int(k)))
        # pixel centres: p -> (p + 0.5) / k - 0.5 in the reduced part
        local = (b - [x0, y0, x0, y0] + 0.5) / k - 0.5
        theta = crop_theta(local, (sub.shape[1], sub.shape[0]))
        out[rows] = sample_crops(np.asarray(sub, np.float32) / 127.5 - 1, theta, resolution)
    return out


def merge_mirrored(out: dict, mirrored: dict) -> dict:
    """The network's answers on crops and on the same crops mirrored (the last axis reversed)
    -> one answer: the mirrored crop's points put back (x -> -x in crop-normalised
    coordinates, each row swapped with its mirror row, :func:`neural.faces.points.mirror_index`)
    and averaged with the plain ones; log σ the log of the root mean square of the two σ (the
    two readings of one crop are not independent: σ is not shrunk by √2); the face logits
    averaged.

    out, mirrored : dicts of ``points`` (B, P, 2) crop-normalised, ``log_sigma`` (B, P),
    ``score`` (B,) arrays."""
    m = mirror_index()
    back = mirrored["points"][:, m] * np.array([-1.0, 1.0], dtype=out["points"].dtype)
    ls = mirrored["log_sigma"][:, m]
    return {"points": (out["points"] + back) / 2,
            "log_sigma": 0.5 * (np.logaddexp(2 * out["log_sigma"], 2 * ls) - math.log(2)),
            "score": (out["score"] + mirrored["score"]) / 2}


class NetworkDetector:
    """The landmark network (:mod:`neural.landmarks.network`) as a landmark detector.

    Parameters
    ----------
    weights : path of a :func:`neural.landmarks.network.save_landmark_net` file (or a training
        checkpoint), or None: :func:`weights_path`
    passes : 1 or 2: the second pass re-centres the crop on the first pass's 68 points
        (default :data:`PASSES`)
    mirror : read every crop also mirrored and average (:func:`merge_mirrored`; one batch of
        two crops: about 1.5 x the network's time on one thread; default :data:`MIRROR`)
    backend : "auto", "onnxruntime" or "torch": what runs the network
        (:func:`neural.landmarks.runtime.choose_backend`; "auto": onnxruntime where it is
        installed and the weights' exported graph is beside them, else torch)

    InputError (one line naming the file and how to get the weights) when the file is missing
    or not landmark-network weights.
    """

    FACE_DETECTORS = ALL_FACE_DETECTORS["network"]

    @classmethod
    def unavailable(cls) -> str | None:
        """Why the network cannot run here (neither onnxruntime with the exported graph nor
        torch with the weights), or None; imports nothing."""
        try:
            runtime.choose_backend(weights_path())
        except InputError as e:
            return str(e)
        return None

    def __init__(self, weights=None, passes: int = None, mirror: bool = None, backend: str = "auto"):
        passes = PASSES if passes is None else passes
        self.mirror = MIRROR if mirror is None else bool(mirror)
        if passes not in (1, 2):
            raise InputError(f"passes: 1 or 2, got {passes}")
        path = weights_path(weights)
        try:
            self.network = runtime.load(path, backend)
        except InputError as e:
            raise InputError(f"{e}; {GET_WEIGHTS}") from None
        except Exception as e:       # whatever else an unpickler meets in a foreign file
            raise InputError(f"{path}: not a landmark network file ({type(e).__name__}); "
                             f"{GET_WEIGHTS}") from None
        self.path, self.passes = path, passes
        self.resolution = self.network.resolution

    # --- the network on boxes -----------------------------------------------------------------
    def run(self, image: np.ndarray, boxes) -> dict:
        """The network on the framing ``boxes`` (B, 4) px of ``image`` (H, W, 3) uint8 ->
        ``points`` (B, 546, 2) px, ``sigma_px`` (B, 546) px, ``probability`` (B,) in [0, 1]."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        H, W = image.shape[:2]
        pts, sig, prob = [], [], []
        for i in range(0, len(boxes), BATCH):
            b = boxes[i:i + BATCH]
            x = crops(image, b, self.resolution)
            if self.mirror:
                both = self.network(np.concatenate([x, x[..., ::-1]]))
                out = merge_mirrored(*({k: v[j * len(b):(j + 1) * len(b)] for k, v in both.items()}
                                       for j in (0, 1)))
            else:
                out = self.network(x)
            pts.append(crop_to_image(out["points"], crop_theta(b, (W, H)), (W, H)))
            sig.append(np.exp(out["log_sigma"].astype(np.float64)) * (box_side(b) / self.resolution)[:, None])
            prob.append(1 / (1 + np.exp(-out["score"].astype(np.float64))))
        P = self.network.n_points
        return {"points": np.concatenate(pts) if pts else np.zeros((0, P, 2)),
                "sigma_px": np.concatenate(sig) if sig else np.zeros((0, P)),
                "probability": np.concatenate(prob) if prob else np.zeros(0)}

    def refine(self, image: np.ndarray, framing) -> dict:
        """:meth:`run` on ``framing`` (B, 4) px, then (``passes=2``) again on the framing of the
        first pass's 68 points; also ``framing`` (B, 4), the last pass's."""
        framing = np.asarray(framing, dtype=np.float64).reshape(-1, 4)
        out = self.run(image, framing)
        if self.passes == 2 and len(framing):
            again = face_box(out["points"][:, IBUG_ROWS])
            # a first pass that collapsed its points (not a face) keeps its own crop
            ok = np.max(again[:, 2:] - again[:, :2], axis=1) >= MIN_BOX_PX
            if ok.any():
                second = self.run(image, again[ok])
                for k in out:
                    out[k][ok] = second[k]
                framing = np.where(ok[:, None], again, framing)
        return {**out, "framing": framing}

    # --- faces ----------------------------------------------------------------------------------
    @staticmethod
    def face_detectors_for(face_detector: str) -> tuple:
        """The face detectors ``face_detector`` runs, in order: ``"auto"``, mediapipe's
        short-range then full-range detector where mediapipe is installed (the short-range one
        first: on AFLW2000-3D photos 100-299 it found all 200 faces, the full-range one 183, and
        the full-range one's largest box was another region on 5 of the first 100), else dlib's
        HOG, else none (the windows only); ``"windows"`` none; others themselves."""
        if face_detector == "windows":
            return ()
        if face_detector != "auto":
            return (face_detector,)
        if importlib.util.find_spec("mediapipe") is not None:
            return ("short-range", "full-range")
        if importlib.util.find_spec("dlib") is not None:
            return ("hog",)
        return ()

    @staticmethod
    def detector_boxes(image: np.ndarray, face_detector: str) -> np.ndarray:
        """(F, 4) px boxes of a face detector of :mod:`morphable.detection`, largest first."""
        if face_detector in ("hog", "cnn"):
            from morphable.detection.dlib_detector import detect_faces
        else:
            from morphable.detection.facemesh import detect_faces
        return detect_faces(image, face_detector=face_detector)

    def search(self, image: np.ndarray) -> dict:
        """The network's own face search: every :func:`windows` window scored at once, the best
        one read again in the framing of its own 68 points -> :meth:`refine`'s dict for that
        framing (one row; its probability is the re-framed crop's), ``window`` (4,) px.

        The best of hundreds of windows is the far tail of the score on non-faces: on noise
        photos a window scores as a face now and then (6 % of 64 held-out noise photos with
        the committed weights, docs/landmark_net.md), while a face framed by the points
        read from it stays a face and noise does not (none of the 64)."""
        H, W = image.shape[:2]
        cand = windows(W, H)
        if not len(cand):
            return {"probability": np.zeros(0)}
        every = self.run(image, cand)
        best = int(np.argmax(every["probability"]))
        first = {k: v[best:best + 1] for k, v in every.items()}
        again = face_box(first["points"][:, IBUG_ROWS])
        if np.max(again[0, 2:] - again[0, :2]) < MIN_BOX_PX:     # points collapsed: no face
            return {**first, "probability": np.zeros(1), "framing": cand[best:best + 1],
                    "window": cand[best]}
        return {**self.refine(image, again), "window": cand[best]}

    def detect_faces(self, image: np.ndarray, face_detector: str = "auto") -> np.ndarray:
        """(F, 4) px face boxes as :meth:`detect` takes them (``box=``: the 68 points' extent
        that the network's framing frames), largest first: every face detector of
        :meth:`face_detectors_for`, framed by :data:`BOX_FRAMING`, a later detector's box kept
        where it overlaps none of the earlier ones by IoU 0.3 or more (the short-range detector
        misses the small faces of a group photo, which the full-range one finds); with
        ``"auto"`` and ``"windows"``, the network's window search's face when none finds any."""
        from morphable.detection.boxes import iou, largest_first

        found_boxes = np.zeros((0, 4))
        for kind in self.face_detectors_for(face_detector):
            boxes = self.detector_boxes(image, kind)
            for b in (extent_box(framing_box(boxes, kind)) if len(boxes) else ()):
                if not len(found_boxes) or float(iou(found_boxes, b).max()) < 0.3:
                    found_boxes = np.vstack([found_boxes, b])
        if len(found_boxes):
            return largest_first(found_boxes)
        if face_detector not in ("auto", "windows"):
            return np.zeros((0, 4))
        found = self.search(image)
        if not len(found["probability"]) or found["probability"][0] < FACE_THRESHOLD:
            return np.zeros((0, 4))
        return _extent(found["points"][0, IBUG_ROWS])[None]

    def detect(self, image: np.ndarray, *, box=None, face_detector: str = "auto",
               name: str = "image") -> Detection:
        """The largest face of ``image`` (H, W, 3) uint8 that the network scores as a face, or the
        face in ``box`` (4,) px (its 68 points' extent) -> :class:`Detection` (see the module's
        docstring); FitError when none is found, InputError for a box too small or outside the
        photo."""
        H, W = image.shape[:2]
        if box is not None:
            box = np.asarray(box, dtype=np.float64)
            _check_box(box, W, H, name)
            found = self.refine(image, framing_box(box, "box")[None])
            return self._detection(found, 0, "box")
        tried = []
        for kind in self.face_detectors_for(face_detector):
            boxes = self.detector_boxes(image, kind)[:MAX_CANDIDATES]
            boxes = boxes[np.maximum(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]) >= MIN_BOX_PX]
            if not len(boxes):
                tried.append(f"{kind} found none")
                continue
            found = self.refine(image, framing_box(boxes, kind))
            faces = np.flatnonzero(found["probability"] >= FACE_THRESHOLD)
            if len(faces):
                return self._detection(found, int(faces[0]), kind)   # the largest face
            tried.append(f"{kind} found {len(boxes)} box{'es' * (len(boxes) > 1)}, best face "
                         f"score {found['probability'].max():.2f}")
        if face_detector in ("auto", "windows"):
            found = self.search(image)
            if len(found["probability"]) and found["probability"][0] >= FACE_THRESHOLD:
                return self._detection(found, 0, "windows")
            best = f"{found['probability'][0]:.2f}" if len(found["probability"]) else "none"
            tried.append(f"the network's window search's best face score {best}")
        raise FitError(f"{name}: no face found by the landmark network ({'; '.join(tried)}; "
                       f"a face needs {FACE_THRESHOLD})")

    def _detection(self, found: dict, i: int, kind: str) -> Detection:
        pts, sig = found["points"][i], found["sigma_px"][i]
        return Detection(points=pts[:N_FACEMESH], sigma_px=sig[:N_FACEMESH], ibug68=pts[IBUG_ROWS],
                         ibug68_sigma_px=sig[IBUG_ROWS], scheme="facemesh478", convention="3d",
                         detector=f"network {kind}", score=float(found["probability"][i]),
                         box=_extent(pts[IBUG_ROWS]))


def _extent(points68) -> np.ndarray:
    """(68, 2) px -> (4,) their bounding box ``(left, top, right, bottom)`` px."""
    return np.concatenate([points68.min(0), points68.max(0)])


def _check_box(box: np.ndarray, width: int, height: int, name: str) -> None:
    side = max(box[2] - box[0], box[3] - box[1])
    if side < MIN_BOX_PX:
        raise InputError(f"{name}: face box {side:.0f} px is smaller than the {MIN_BOX_PX:.0f} px "
                         "the landmark network reads")
    if box[2] < -0.5 or box[3] < -0.5 or box[0] > width - 0.5 or box[1] > height - 0.5:
        raise InputError(f"{name}: face box ({', '.join(f'{v:.0f}' for v in box)}) lies outside "
                         f"the {width}x{height} image")
