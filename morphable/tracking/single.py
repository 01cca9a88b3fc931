"""Tracking a face through a video: one identity, a pose and an expression per frame.

:func:`track_video` runs these steps, each a function usable alone:

1. the identity: ``identity_frames`` frames spread uniformly over the video (frames without
   a face skipped), each fitted alone and their identities averaged (``identity="average"``,
   the default) or fitted together with one shared identity (``"shared"``), by
   :func:`morphable.pipeline.fit_images`;
2. every frame, streamed (:func:`morphable.video.iter_frames`) in batches of
   :func:`chunk_frames` frames: landmarks detected in the box of the previous frame's points
   (:func:`carried_box`), the face detector run only when there is no box or the face is not
   found in it; then pose and expression of the batch fitted at once with the identity held,
   each frame's detection as ``morphable fit`` fits one (its σ per point, the detector's
   convention: :func:`fit_frames`, :func:`fixed_identity_model`); a frame whose fit misses its points
   (the box held no face) is detected again from scratch. A frame without a face is *lost*
   (NaN rows), never an error;
3. the temporal prior (:func:`smooth_trajectories`): each run of tracked frames is the most
   probable trajectory under a Gaussian prior on the frame-to-frame acceleration of the pose
   angles, translation, log scale and expression, given the per-frame fits as measurements.
   Its strength is a cut-off frequency in Hz (``smoothing_hz``): motion slower than it passes,
   faster detector jitter is removed. 0 turns it off.

Also ``morphable.track_video``; :func:`morphable.pipeline.write_track` writes its result.
``morphable track`` follows every face of a video instead (:mod:`morphable.tracking.footage`).

Units: angles in degrees, translations in mm, image points in pixels (0-based, x right, y down).
"""
from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np

from ..errors import FitError, InputError

__all__ = ["TrackResult", "track_video", "write_track_glb", "fixed_identity_model", "carried_box",
           "fit_frames", "chunk_frames", "smooth_trajectories", "solve_prior", "DEFAULT_SMOOTHING_HZ",
           "LOST_RMSE_FRACTION", "CHUNK_BYTES", "IDENTITY_MODES", "DEFAULT_IDENTITY"]

DEFAULT_SMOOTHING_HZ = 4.0
"""Cut-off of the temporal prior: head motion and speech are mostly slower; a detector's
frame-to-frame jitter is white, most of its power above."""

LOST_RMSE_FRACTION = 0.08
"""A frame whose fit misses its landmarks by more than this fraction of the face's size (RMS,
px over the landmark box's diagonal) has lost the face: a landmark detector run in a box
without a face still returns points."""


@dataclasses.dataclass
class TrackResult:
    """Per-frame tracking of one video; F frames, E expression modes, L detector points.
    Lost frames hold NaN.

    Attributes
    ----------
    identity : (K,) identity coefficients (std units), shared by all frames
    time_s : (F,) presentation time of each frame, s
    tracked : (F,) bool, a face was found and fitted
    detected : (F,) bool, the face detector ran (no box carried, or the face lost in it)
    euler_deg : (F, 3) yaw, pitch, roll, degrees (after the temporal prior)
    translation : (F, 3) mm, camera frame
    scale : (F,) px/mm (affine camera)
    expression : (F, E) coefficients (after the temporal prior)
    landmarks_68_px : (F, 68, 2) the fitted face's iBUG-68 points projected, px (NaN where the
        model has none), as in fit reports
    detector_px : (F, L, 2) float32 the detector's points, px
    detector_std_px : (F,) the detector's σ, px: per frame the one σ of the same total weight
        as its points' own (:func:`morphable.fitting.noise.effective_std`); NaN where it gives
        none (the face mesh and dlib give none)
    raw_euler_deg, raw_expression : the per-frame fits before the temporal prior
    landmark_rmse_px : (F,) RMS distance of the fitted to the detected points, px
    fps : float, average frame rate of the video
    image_size : (W, H) px
    fit : FitResult of the tracked frames after the prior (frame i of it is video frame
        ``np.flatnonzero(tracked)[i]``; no landmarks), or None when no frame was tracked:
        meshes (``fit.vertices(i)``) and overlays (:func:`morphable.overlay.draw_overlay`)
    """

    identity: np.ndarray
    time_s: np.ndarray
    tracked: np.ndarray
    detected: np.ndarray
    euler_deg: np.ndarray
    translation: np.ndarray
    scale: np.ndarray
    expression: np.ndarray
    landmarks_68_px: np.ndarray
    detector_px: np.ndarray
    detector_std_px: np.ndarray
    raw_euler_deg: np.ndarray
    raw_expression: np.ndarray
    landmark_rmse_px: np.ndarray
    fps: float
    image_size: tuple
    fit: object = None

    @property
    def n_frames(self) -> int:
        return len(self.time_s)


def fixed_identity_model(model, identity):
    """The model with ``identity`` (K,) baked into its mean: fitted with ``n_identity=0`` it
    fits pose and expression only (its identity modes are kept, unused)."""
    return dataclasses.replace(model, mean=model.vertices(identity))


def carried_box(points, margin: float = 0.1):
    """The face box of the previous frame's landmarks (L, 2) px, widened by ``margin`` of its
    size each side -> (left, top, right, bottom) px, or None when too few points are finite."""
    p = np.asarray(points, dtype=np.float64)
    p = p[np.isfinite(p).all(1)]
    if len(p) < 3:
        return None
    lo, hi = p.min(0), p.max(0)
    pad = margin * (hi - lo)
    return tuple(float(v) for v in (*(lo - pad), *(hi + pad)))


def smooth_trajectories(values, tracked, fps: float, cutoff_hz: float = DEFAULT_SMOOTHING_HZ):
    """The temporal prior: per run of consecutive tracked frames, the trajectory x minimising
    ``|x - values|^2 + lam |D2 x|^2`` (D2 the second difference: a Gaussian prior on the
    acceleration). Away from a run's ends its frequency response is 1 / (1 + lam (2 - 2 cos w)^2)
    (w in radians per frame), which ``lam`` sets to 1/2 at ``cutoff_hz``.

    Parameters
    ----------
    values : (F, D) per-frame measurements (any units; each column smoothed alike)
    tracked : (F,) bool; untracked frames break runs and stay as they are
    fps : frames per second
    cutoff_hz : >= 0; 0 or a cut-off at or above the Nyquist frequency returns ``values``

    Returns (F, D) float64.

    >>> x = np.r_[np.zeros(10), np.ones(10)][:, None]
    >>> y = smooth_trajectories(x, np.ones(20, bool), fps=30, cutoff_hz=3)
    >>> bool(abs(y[9, 0] - 0.5) < 0.2 and abs(y[0, 0]) < 0.05)
    True
    """
    values = np.asarray(values, dtype=np.float64)
    out = values.copy()
    if not cutoff_hz or cutoff_hz < 0 or not fps or cutoff_hz >= fps / 2:
        return out
    lam = 1.0 / (2.0 - 2.0 * math.cos(2 * math.pi * cutoff_hz / fps)) ** 2
    tracked = np.asarray(tracked, dtype=bool)
    edges = np.flatnonzero(np.diff(np.r_[0, tracked.astype(np.int8), 0]))
    for a, b in zip(edges[::2], edges[1::2]):
        n = b - a
        if n < 3:
            continue
        out[a:b] = solve_prior(values[a:b], lam)
    return out


def solve_prior(values, lam: float) -> np.ndarray:
    """Solve ``(I + lam D2'D2) x = values`` for (n, D) ``values`` (D2 the (n-2, n) second
    difference): the pentadiagonal system of :func:`smooth_trajectories`, by its LDL'
    factorisation (scalars, the same for every column) and two substitutions vectorised over
    the columns. numpy alone: scipy's banded solver costs its import (about 0.4-0.9 s) once
    per process, more than the solve of a long video. Returns (n, D) float64.

    >>> x = solve_prior(np.eye(5)[:, :1] * 5, 1.0)
    >>> bool(np.allclose((np.eye(5) + np.diff(np.eye(5), 2, 0).T @ np.diff(np.eye(5), 2, 0)) @ x,
    ...                  np.eye(5)[:, :1] * 5))
    True
    """
    y = np.array(values, dtype=np.float64)
    n = len(y)
    # the bands of A = I + lam D2'D2: row i of D2 holds (1, -2, 1) at columns i, i+1, i+2
    c, rows = (1.0, -2.0, 1.0), np.arange(n - 2)
    d0, d1 = np.zeros(n), np.zeros(n - 1)
    for r in range(3):
        np.add.at(d0, rows + r, c[r] * c[r])
        if r < 2:
            np.add.at(d1, rows + r, c[r] * c[r + 1])
    d0, d1, d2 = 1.0 + lam * d0, lam * d1, np.full(n - 2, lam * c[0] * c[2])
    D, l1, l2 = np.zeros(n), np.zeros(n), np.zeros(n)     # A = L diag(D) L', L unit banded
    d0, d1, d2 = d0.tolist(), d1.tolist() + [0.0], d2.tolist() + [0.0, 0.0]
    Dp = Dpp = l1p = l2p = l2pp = 0.0   # D[i-1], D[i-2], l1[i-1], l2[i-1], l2[i-2]
    for i in range(n):
        Di = d0[i] - l1p * l1p * Dp - l2pp * l2pp * Dpp
        D[i] = Di
        l1[i] = (d1[i] - l2p * l1p * Dp) / Di       # L[i+1, i]
        l2[i] = d2[i] / Di                          # L[i+2, i]
        Dpp, Dp, l2pp, l2p, l1p = Dp, Di, l2p, l2[i], l1[i]
    for i in range(1, n):                           # L z = y
        y[i] -= l1[i - 1] * y[i - 1] + (l2[i - 2] * y[i - 2] if i > 1 else 0.0)
    y /= D[:, None]
    for i in range(n - 2, -1, -1):                  # L' x = z / D
        y[i] -= l1[i] * y[i + 1] + (l2[i] * y[i + 2] if i < n - 2 else 0.0)
    return y


def write_track_glb(track: TrackResult, path) -> Path:
    """The track as an animated glTF 2.0 binary (:func:`morphable.io.gltf.write_animated_glb`).

    - base mesh: the model's mean shape with the track's identity; morph targets: the model's
      expression modes (mm per unit coefficient, named after them), so that a keyframe's
      morph weights are the frame's expression coefficients and the mesh is exactly the
      tracked one;
    - the node's pose per keyframe: the frame's head rotation and translation in the camera
      frame (x right, y up, z towards the viewer), and a uniform scale ``s / median(s)`` (s
      the affine camera's px/mm), the translation scaled alike, so that an orthographic view
      of ``median(s)`` px/mm, which the file's camera is (the video's frame, at (0, 0, 1 m)),
      reproduces each frame's projection. An affine camera sees no depth: z is 0;
    - keyframes: the tracked frames at their presentation times (s, the video's frame rate;
      lost frames are interpolated over by viewers and listed in the animation's ``extras``).

    Units in the file: metres. Returns ``path``; InputError when no frame was tracked.
    """
    from ..camera import euler_to_matrix
    from ..io.gltf import write_animated_glb

    if track.fit is None or not track.tracked.any():
        raise InputError(f"{path}: no tracked frame to animate")
    ok = track.tracked
    model = track.fit.model
    s = track.scale[ok]
    ref = float(np.median(s))
    k = s / ref
    moved = track.translation[ok] * k[:, None]
    moved[:, 2] = 0.0
    W, H = track.image_size
    extras = {"frames": [int(i) for i in np.flatnonzero(ok)],
              "frames_lost": [int(i) for i in np.flatnonzero(~ok)], "fps": float(track.fps),
              "image_size": [int(W), int(H)], "px_per_mm": ref, "units": "metres"}
    # glTF's times start at 0 s or later; a container may start a video before 0
    times = track.time_s[ok] - min(0.0, float(np.nanmin(track.time_s)))
    return write_animated_glb(path, model.mean, model.triangles, times,
                              euler_to_matrix(*track.euler_deg[ok].T), moved, k,
                              targets=model.expression_basis, weights=track.expression[ok],
                              target_names=model.expression_names,
                              orthographic_mm=(W / (2 * ref), H / (2 * ref)), extras=extras)


IDENTITY_MODES = ("shared", "average")
"""How :func:`track_video` makes the video's identity from its identity frames."""

DEFAULT_IDENTITY = "average"
"""Chosen on the photo-dressed validation subjects (docs/video.md): with the face mesh's
points, a shared fit of frames spread over a head turn fits the identity to the detector's
pose-dependent errors, worse the more frames it is given; single-frame fits keep each frame's
prior, and their average removes their noise."""

CHUNK_BYTES = 64 * 2 ** 20
"""Decoded frames held at once by :func:`track_video` (a batch of fits), bytes: 32 frames of
640 x 480, 2 of 3840 x 2160; memory does not grow with the video's length."""


def chunk_frames(width: int, height: int, max_frames: int = 32) -> int:
    """Frames of ``width`` x ``height`` px (RGB, 8 bit) per batch: :data:`CHUNK_BYTES` of them,
    at least 1, at most ``max_frames`` (beyond it the batched fit gains little)."""
    return int(max(1, min(max_frames, CHUNK_BYTES // max(1, 3 * width * height))))


def _batches(items, n: int):
    """Lists of ``n`` consecutive items (the last one shorter)."""
    batch = []
    for item in items:
        batch.append(item)
        if len(batch) == n:
            yield batch
            batch = []
    if batch:
        yield batch


def _detect(image, box, landmark_detector: str, face_detector: str):
    """:func:`morphable.detection.detect` in ``box`` (None: the whole image) -> (the
    :class:`~morphable.detection.result.Detection`, the box to carry to the next frame), or
    (None, None) where it finds no face. The box
    carried is the detector's own (:attr:`Detection.box`, in the convention its ``box=``
    reads: the landmark network's framing) where it gives one, else the points' box
    (:func:`carried_box`)."""
    from ..detection import detect

    try:
        det = detect(image, landmark_detector=landmark_detector, face_detector=face_detector,
                     box=box)
    except FitError:
        return None, None
    carry = tuple(float(v) for v in det.box) if det.box is not None else carried_box(det.points)
    return det, carry


def _frame_settings(found: list) -> dict:
    """The fit settings of a group of frames' detections (all Detections, or all bare
    points): ``morphable fit``'s for detections (their σ, the 3D convention of 478-point
    detectors: :func:`morphable.fitting.options.detection_settings`), the detector's model
    error alone for bare points."""
    from ..detection.result import Detection
    from ..fitting.noise import DETECTED_MODEL_STD_MM
    from ..fitting.options import detection_settings

    if isinstance(found[0], Detection):
        return detection_settings(found, len(found[0].points))
    return {"model_std_mm": DETECTED_MODEL_STD_MM}


def fit_frames(fixed, points, image_size) -> list:
    """Pose and expression of frames with the identity held (``fixed``:
    :func:`fixed_identity_model`), all fitted at once (independent frames, one vectorised
    fit: about a third of the time of one fit per frame, the same results).

    Parameters
    ----------
    fixed : MorphableModel with the identity in its mean
    points : list, per frame, of a :class:`~morphable.detection.result.Detection` (fitted as
        ``morphable fit`` fits it: its σ, its convention), (L, 2) px detected points (a
        detector without σ, outline points sliding), or None (no face)
    image_size : (W, H) px, the same for all frames

    Returns a list with, per frame, ``(camera, (E,) expression, landmark RMSE px)``, or None
    where there are no points or the fit misses them by more than :data:`LOST_RMSE_FRACTION`
    of the face's size (the face is lost).
    """
    from ..detection.result import Detection
    from ..fitting import fit_landmarks

    out = [None] * len(points)
    # each frame's (L, 2) px points: a Detection's, or the bare points
    xy = {i: p.points if isinstance(p, Detection) else np.asarray(p, dtype=np.float64)
          for i, p in enumerate(points) if p is not None}
    groups = {}
    for i, y in xy.items():    # one fit per point count and kind (one detector gives one)
        groups.setdefault((len(y), isinstance(points[i], Detection)), []).append(i)
    for ids in groups.values():
        y = np.stack([xy[i] for i in ids])
        try:
            fit = fit_landmarks(fixed, y, np.tile(np.asarray(image_size, dtype=np.float64), (len(ids), 1)),
                                n_identity=0, shared_identity=False,
                                **_frame_settings([points[i] for i in ids]))
            fits = [(fit.cameras[k], fit.expression[k], float(fit.landmark_rmse_px[k])) for k in range(len(ids))]
        except FitError:
            if len(ids) == 1:
                continue
            # one frame the fitter refuses (degenerate points) must not lose its batch
            for i in ids:
                out[i] = fit_frames(fixed, [points[i]], image_size)[0]
            continue
        good = [i for i, f in zip(ids, fits)
                if f[2] <= LOST_RMSE_FRACTION * np.linalg.norm(np.nanmax(xy[i], 0) - np.nanmin(xy[i], 0))]
        if len(good) < len(ids) and good:
            # frames fitted together are not quite independent where one of them fails (the
            # fitter's iterations run on while it does; 1e-3 rad on the others): the good ones
            # again, without it, so that a frame's fit does not depend on its neighbours
            refit = fit_frames(fixed, [points[i] for i in good], image_size)
            if all(f is not None for f in refit):
                fits = dict(zip(good, refit))
            else:
                fits = {i: fit_frames(fixed, [points[i]], image_size)[0] for i in good}
        else:
            fits = dict(zip(ids, fits))
        for i in good:
            out[i] = fits[i]
    return out


def track_video(path, *, model="sfm", identity_frames: int = 9, identity: str = DEFAULT_IDENTITY,
                landmark_detector: str = "auto", face_detector: str = "auto",
                smoothing_hz: float = DEFAULT_SMOOTHING_HZ, progress: bool = False) -> TrackResult:
    """Track the face of a video (see the module docstring for the steps).

    Parameters
    ----------
    path : a video file (:mod:`morphable.video`)
    model : MorphableModel or name/path
    identity_frames : int >= 1, frames spread uniformly for the identity fit
    identity : "average" (each identity frame fitted alone, their identity coefficients
        averaged; :data:`DEFAULT_IDENTITY`) or "shared" (one fit of all of them together)
    landmark_detector, face_detector : see :func:`morphable.detection.detect_landmarks`
    smoothing_hz : cut-off of the temporal prior, Hz (0: off)
    progress : a progress bar on stderr (tqdm)

    Returns a :class:`TrackResult`. InputError for a bad file or a video in which no sampled
    frame shows a face; frames in which the face is lost are reported, never an error.
    """
    from ..camera import Camera, euler_to_matrix
    from ..detection import describe
    from ..fitting.noise import effective_std
    from ..fitting.result import FitResult
    from ..pipeline.fit import fit_images
    from ..video import iter_frames, probe

    if int(identity_frames) < 1:
        raise InputError(f"identity frames must be >= 1, got {identity_frames}")
    if identity not in IDENTITY_MODES:
        raise InputError(f"identity: expected one of {', '.join(IDENTITY_MODES)}, got {identity!r}")
    if not smoothing_hz >= 0:
        raise InputError(f"smoothing must be >= 0 Hz, got {smoothing_hz}")
    describe(landmark_detector, face_detector)     # a bad choice fails before any work
    info = probe(path)
    if isinstance(model, (str, Path)):
        from ..io.registry import load_model

        model = load_model(str(model))
    res = fit_images(path, model=model, landmark_detector=landmark_detector,
                     face_detector=face_detector, video_frames=identity_frames,
                     shared_identity=identity == "shared").fit
    alpha = res.identity
    fixed = fixed_identity_model(model, alpha)
    F, E = info.n_frames, model.n_expression
    rows = {"time_s": [], "tracked": [], "detected": [], "euler": [], "translation": [], "scale": [],
            "expression": [], "detector": [], "sigma": [], "rmse": []}
    frames = iter_frames(path)
    if progress:
        from tqdm import tqdm

        frames = tqdm(frames, total=F, unit="frame", desc=str(path), leave=False)
    detect = functools.partial(_detect, landmark_detector=landmark_detector, face_detector=face_detector)
    box, n_points = None, None
    for batch in _batches(frames, chunk_frames(info.width, info.height)):
        size = batch[0].size
        # landmarks in the box of the previous frame's points (the face detector only where
        # there is no box, or no face in it); the fits of the whole batch at once
        points, detected, carry = [], [], []
        for frame in batch:
            pts, box = detect(frame.image, box) if box is not None else (None, None)
            detected.append(pts is None)
            if pts is None:
                pts, box = detect(frame.image, None)
            points.append(pts)
            carry.append(box)
        fits = fit_frames(fixed, points, size)
        # a box without the face still gives points, which the identity cannot fit: that
        # frame is detected again from scratch, and lost if that fails too
        for i, frame in enumerate(batch):
            if fits[i] is None and points[i] is not None and not detected[i]:
                detected[i] = True
                points[i], carry[i] = detect(frame.image, None)
                fits[i] = fit_frames(fixed, [points[i]], size)[0]
        box = carry[-1] if fits[-1] is not None else None
        for frame, pts, was_detected, fit in zip(batch, points, detected, fits):
            rows["time_s"].append(frame.time_s)
            rows["detected"].append(was_detected)
            rows["tracked"].append(fit is not None)
            if fit is None:
                for k, v in (("euler", np.full(3, np.nan)), ("translation", np.full(3, np.nan)),
                             ("scale", np.nan), ("expression", np.full(E, np.nan)),
                             ("detector", None), ("sigma", np.nan), ("rmse", np.nan)):
                    rows[k].append(v)
                continue
            n_points = n_points or len(pts.points)
            cam, expression, rmse = fit
            rows["euler"].append(cam.euler_deg)
            rows["translation"].append(cam.translation)
            rows["scale"].append(cam.scale)
            rows["expression"].append(expression)
            rows["detector"].append(np.asarray(pts.points, dtype=np.float32))
            rows["sigma"].append(np.nan if pts.sigma_px is None else
                                 float(effective_std(pts.sigma_px[None] ** 2, np.ones((1, len(pts.sigma_px)), bool))[0]))
            rows["rmse"].append(rmse)
    tracked = np.array(rows["tracked"], dtype=bool)
    n = len(tracked)
    raw_euler, raw_expr = np.array(rows["euler"]).reshape(n, 3), np.array(rows["expression"]).reshape(n, E)
    translation, scale = np.array(rows["translation"]).reshape(n, 3), np.array(rows["scale"], dtype=np.float64)
    # the prior on angles, translation, log scale and expression; yaw near +-180 is not a face
    stacked = np.c_[raw_euler, translation, np.log(scale), raw_expr]
    smooth = smooth_trajectories(stacked, tracked, info.fps, smoothing_hz)
    euler, translation, scale, expression = smooth[:, :3], smooth[:, 3:6], np.exp(smooth[:, 6]), smooth[:, 7:]
    cams = [Camera(kind="affine", rotation=euler_to_matrix(*euler[i]), translation=translation[i],
                   scale=scale[i], image_size=(info.width, info.height)) for i in np.flatnonzero(tracked)]
    lm68 = np.full((n, 68, 2), np.nan)
    projected = None
    if cams:
        k = len(cams)
        projected = FitResult(model=fixed, identity=np.zeros(0), frame_identity=np.zeros((k, 0)),
                              expression=expression[tracked], cameras=cams,
                              landmark_rmse_px=np.zeros(k), landmarks=np.zeros((k, 0, 2)),
                              fitted_landmarks=np.zeros((k, 0, 2)),
                              landmark_vertices=np.zeros((k, 0), dtype=np.int64))
        lm68[tracked] = projected.landmarks_68_px()
    L = n_points or 68
    detector = np.full((n, L, 2), np.nan, dtype=np.float32)
    for i, p in enumerate(rows["detector"]):
        if p is not None and len(p) == L:
            detector[i] = p
    return TrackResult(identity=alpha, time_s=np.array(rows["time_s"]), tracked=tracked,
                       detected=np.array(rows["detected"], dtype=bool), euler_deg=euler,
                       translation=translation, scale=scale, expression=expression,
                       landmarks_68_px=lm68, detector_px=detector,
                       detector_std_px=np.array(rows["sigma"], dtype=np.float64), raw_euler_deg=raw_euler,
                       raw_expression=raw_expr, landmark_rmse_px=np.array(rows["rmse"], dtype=np.float64),
                       fps=info.fps, image_size=(info.width, info.height), fit=projected)
