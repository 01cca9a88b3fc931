"""Synthetic Florence-like videos of a scan: pose trajectories, cameras and 2D landmarks.

Three conditions imitate the Florence videos:

============  ======  ======  =============================  ======  ======  ========
condition     yaw     pitch   light                          σ (px)  image   distance
============  ======  ======  =============================  ======  ======  ========
cooperative   ±10°    ±5°     soft, frontal                  1       512 px  1 m
indoor        ±30°    ±15°    lamp (one side), mild blur     2       512 px  3 m
outdoor       ±45°    ±20°    hard sun with shadows, noise   3       256 px  5 m
============  ======  ======  =============================  ======  ======  ========

Each video is a smooth 30-frame head-pose trajectory; 5 frames are sampled uniformly for
reconstruction. Landmarks are the scan's 3D landmarks projected into each frame: inner points
only where the scan does not hide them, jaw points moved onto the face's silhouette (as a
human annotator or a 2D detector places them), then Gaussian pixel noise. Rendered frames (for
running a detector on them) go through ``morphable.raster``.

Poses are relative to the scan's frontal pose, found by a rigid fit of its landmarks to a
model's mean landmarks; yaw/pitch/roll follow :mod:`morphable.camera`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from morphable.camera import Camera
from morphable.errors import InputError
from morphable.ibug68 import JAW
from morphable.logs import import_open3d
from morphable.metrics import Similarity, align_landmarks
from morphable.raster.visibility import scene as raycasting_scene
from morphable.video import sample_indices

__all__ = ["Condition", "CONDITIONS", "Video", "frontal_frame", "trajectory", "sample_frames",
           "project_landmarks", "synthetic_video", "render_frames", "write_rendered_video",
           "detect_face", "detected_points", "detect_frames"]


@dataclass(frozen=True)
class Condition:
    """How one kind of video is filmed.

    Attributes
    ----------
    yaw_deg, pitch_deg : amplitude of the head motion, degrees
    sigma_px : standard deviation of the landmark noise, pixels
    image_px : image width and height, pixels
    light : ``"soft"``, ``"lamp"`` or ``"sun"`` (used when rendering)
    blur_px : Gaussian blur of rendered frames, pixels
    noise : standard deviation of the sensor noise of rendered frames (intensity in [0, 1])
    distance_mm : camera distance (perspective); the face fills about half the image at any
        distance (the focal length follows)
    """

    yaw_deg: float
    pitch_deg: float
    sigma_px: float
    image_px: int
    light: str
    blur_px: float = 0.0
    noise: float = 0.0
    distance_mm: float = 1000.0


# Florence's cooperative videos are close-up; indoor and outdoor ones come from a zoomed
# surveillance camera a few metres away (weaker perspective)
CONDITIONS = {
    "cooperative": Condition(10.0, 5.0, 1.0, 512, "soft", distance_mm=1000.0),
    "indoor": Condition(30.0, 15.0, 2.0, 512, "lamp", blur_px=1.0, distance_mm=3000.0),
    "outdoor": Condition(45.0, 20.0, 3.0, 256, "sun", noise=0.02, distance_mm=5000.0),
}
"""Florence's three kinds of video by name."""


@dataclass
class Video:
    """A synthetic video of a scan.

    Attributes
    ----------
    condition : str
    cameras : list of Camera, one per frame (world = the scan's frame, mm)
    landmarks : (n_frames, 68, 2) float64 pixels, NaN where a point is hidden or off-image
    poses_deg : (n_frames, 3) yaw, pitch, roll of the head relative to frontal, degrees
    sampled : (k,) int, the frames used for reconstruction
    """

    condition: str
    cameras: list
    landmarks: np.ndarray
    poses_deg: np.ndarray
    sampled: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def image_size(self) -> tuple:
        return self.cameras[0].image_size

    def sampled_landmarks(self) -> np.ndarray:
        """(k, 68, 2) px landmarks of the sampled frames."""
        return self.landmarks[self.sampled]

    def sampled_cameras(self) -> list:
        return [self.cameras[i] for i in self.sampled]


def frontal_frame(scan_landmarks, reference_landmarks) -> Similarity:
    """Rigid transform from the scan's frame to a frontal head frame.

    Parameters
    ----------
    scan_landmarks : (68, 3) mm, NaN rows allowed
    reference_landmarks : (68, 3) mm of a frontal face (e.g. ``model.landmark_positions()``)

    Returns
    -------
    Similarity with scale 1: scan -> frontal frame (x to the subject's left, y up, z out).
    """
    return align_landmarks(scan_landmarks, reference_landmarks, scale=False)


def trajectory(condition: Condition, n_frames: int = 30, rng=None) -> np.ndarray:
    """A smooth head-pose trajectory -> (n_frames, 3) yaw, pitch, roll in degrees.

    Yaw sweeps one full period through ± the condition's amplitude; pitch and a small roll
    oscillate with random phases (from ``rng``).

    >>> trajectory(CONDITIONS["indoor"], 30, rng=0).shape
    (30, 3)
    """
    if n_frames < 1:
        raise InputError(f"a video needs at least one frame, got {n_frames}")
    rng = np.random.default_rng(rng)
    # one period without repeating the first pose at the end
    t = np.linspace(0.0, 1.0, n_frames, endpoint=False)
    ph = rng.uniform(0, 2 * np.pi, size=2)
    yaw = condition.yaw_deg * np.sin(2 * np.pi * t + rng.uniform(-0.2, 0.2))
    pitch = condition.pitch_deg * np.sin(4 * np.pi * t + ph[0])
    roll = 0.2 * condition.pitch_deg * np.sin(2 * np.pi * t + ph[1])
    return np.stack([yaw, pitch, roll], 1)


def sample_frames(n_frames: int, k: int) -> np.ndarray:
    """``k`` frame indices spread uniformly over ``n_frames`` (first and last included):
    :func:`morphable.video.sample_indices`.

    >>> sample_frames(30, 5)
    array([ 0,  7, 14, 22, 29])
    """
    return sample_indices(n_frames, k)


def _visible(scene, camera: Camera, points, tol_mm: float = 4.0) -> np.ndarray:
    """(N,) bool: the first surface hit on the ray from the camera is (near) the point."""
    o3d = import_open3d()

    d = -camera.view_directions(points)
    if camera.kind == "affine":
        back = 1e4
        origins = points - back * d
        expected = np.full(len(points), back)
    else:
        origins = np.broadcast_to(camera.centre, points.shape)
        expected = np.linalg.norm(points - camera.centre, axis=1)
    rays = np.concatenate([origins, d], 1).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return t >= expected - tol_mm


class _Silhouette:
    """Candidate scan vertices for each jaw landmark: a horizontal band of the face from the
    landmark towards the midline and the front. Under a pose, the candidate farthest out in
    the image (towards the landmark's side of the face) is where the face outline crosses
    that height (the landmark itself when that side faces the camera)."""

    def __init__(self, vertices, landmarks, frame: Similarity, band_mm: float = 3.0):
        used = np.isfinite(landmarks[JAW]).all(1)
        self.ids, self.side = {}, {}
        v = frame.apply(vertices)
        lm = frame.apply(np.where(np.isfinite(landmarks), landmarks, 0.0))
        mid = lm[30, 0]
        for j, ok in zip(JAW, used):
            if not ok or j == 8:
                continue
            x, y, z = lm[j]
            side = np.sign(x - mid)
            cand = np.flatnonzero((np.abs(v[:, 1] - y) < band_mm) & (v[:, 2] >= z)
                                  & ((v[:, 0] - mid) * side >= 0)
                                  & ((v[:, 0] - mid) * side <= abs(x - mid) + band_mm))
            self.ids[j] = cand
            self.side[j] = side or 1.0
        self.side_axis = frame.inverse().rotation @ np.array([1.0, 0.0, 0.0])

    def points(self, vertices, landmarks, camera: Camera, centre) -> np.ndarray:
        out = camera.project(landmarks)
        c = camera.project(centre[None])[0]
        axis = camera.project((centre + 50.0 * self.side_axis)[None])[0] - c
        axis /= max(np.linalg.norm(axis), 1e-12)
        for j, cand in self.ids.items():
            pts = np.vstack([landmarks[j][None], vertices[cand]])
            uv = camera.project(pts)
            # the side of the face, not of the image centre: at a large yaw a far-side jaw
            # point projects across the centre, and "outwards" must not flip to the midline
            out[j] = uv[np.argmax(((uv - c) @ axis) * self.side[j])]
        return out


def project_landmarks(scan, cameras, frame: Similarity, rng=None, sigma_px: float = 0.0) -> np.ndarray:
    """Landmarks of a scan as seen by each camera -> (n, 68, 2) px, NaN where hidden.

    Parameters
    ----------
    scan : :class:`evaluation.scans.Scan` (or anything with vertices, triangles, landmarks)
    cameras : list of Camera
    frame : scan -> frontal frame (:func:`frontal_frame`), which defines "horizontal"
    rng : seed or Generator for the noise
    sigma_px : Gaussian noise per coordinate, pixels

    Jaw points (iBUG 1-17) sit on the visible outline of the face; the others are dropped
    where the scan hides them. Points outside the image are dropped.
    """
    rng = np.random.default_rng(rng)
    lm = np.asarray(scan.landmarks, dtype=np.float64)
    given = np.isfinite(lm).all(1)
    scene = raycasting_scene(scan.vertices, scan.triangles)
    sil = _Silhouette(scan.vertices, lm, frame)
    centre = np.nanmean(lm, 0)
    lm0 = np.where(given[:, None], lm, 0.0)
    out = []
    for cam in cameras:
        uv = sil.points(scan.vertices, lm0, cam, centre)
        vis = given & _visible(scene, cam, lm0)
        vis[list(sil.ids)] = True  # silhouette points are visible by construction
        uv = uv + rng.normal(0.0, sigma_px, uv.shape)
        W, H = cam.image_size
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
        uv[~(vis & inside & given)] = np.nan
        out.append(uv)
    return np.stack(out)


def synthetic_video(scan, condition: str, reference_landmarks, n_frames: int = 30,
                    n_sampled: int = 5, seed: int = 0, kind: str = "perspective") -> Video:
    """A synthetic video of ``scan`` under one condition.

    Parameters
    ----------
    scan : Scan (mm)
    condition : ``"cooperative"``, ``"indoor"`` or ``"outdoor"``
    reference_landmarks : (68, 3) mm of a frontal face (defines the frontal pose)
    n_frames, n_sampled : video length and frames used for reconstruction
    seed : int — poses and noise are reproducible from it
    kind : camera kind (``"perspective"`` at the condition's distance, or ``"affine"``)

    Examples
    --------
    >>> from morphable import load_model
    >>> from evaluation.scans import model_scan
    >>> scan = model_scan(load_model("ict"), rng=0)
    >>> v = synthetic_video(scan, "indoor", load_model("sfm").landmark_positions())
    >>> v.sampled_landmarks().shape, v.poses_deg.shape
    ((5, 68, 2), (30, 3))
    """
    if condition not in CONDITIONS:
        raise InputError(f"unknown condition {condition!r}; choose from {', '.join(CONDITIONS)}")
    cond = CONDITIONS[condition]
    # one stream per (seed, condition) so that adding a condition changes no other video
    rng = np.random.default_rng([seed, list(CONDITIONS).index(condition)])
    frame = frontal_frame(scan.landmarks, reference_landmarks)
    poses = trajectory(cond, n_frames, rng)
    size = (cond.image_px, cond.image_px)
    centre = frame.apply(np.nanmean(scan.landmarks, 0)[None])[0]
    cams = []
    for yaw, pitch, roll in poses:
        c = Camera.looking_at_face(image_size=size, yaw=yaw, pitch=pitch, roll=roll, kind=kind,
                                   distance_mm=cond.distance_mm, center=centre)
        # the camera sees the frontal frame; compose with scan -> frontal
        cams.append(Camera(kind=kind, rotation=c.rotation @ frame.rotation,
                           translation=c.rotation @ frame.translation + c.translation,
                           scale=c.scale, focal=c.focal, image_size=size))
    lms = project_landmarks(scan, cams, frame, rng=rng, sigma_px=cond.sigma_px)
    return Video(condition=condition, cameras=cams, landmarks=lms, poses_deg=poses,
                 sampled=sample_frames(n_frames, n_sampled))


def render_frames(scan, video: Video, frames=None, seed: int = 0, supersample: int = 2) -> np.ndarray:
    """Render frames of a synthetic video with ``morphable.raster`` -> (k, H, W, 3) in [0, 1].

    The condition's light (soft frontal; a lamp to one side; hard sun from above with cast
    shadows), blur and sensor noise are applied; the scan's texture is used when it has one,
    else its vertex colours, if any.
    """
    try:
        from morphable.raster import DirectionalLight, render
    except ImportError as e:
        raise InputError(f"rendering frames needs morphable.raster ({e})") from None
    from scipy.ndimage import gaussian_filter

    cond = CONDITIONS[video.condition]
    frames = video.sampled if frames is None else np.asarray(frames)
    rng = np.random.default_rng([seed, 99])
    texture = (scan.uv, scan.triangle_uv, scan.texture) if scan.uv is not None and scan.texture is not None else None
    # directions towards the light in the camera frame (+z towards the viewer)
    direction, strength, ambient, shadows = {
        "soft": ((0.0, 0.2, 1.0), 0.5, 0.5, False),
        "lamp": ((0.8, 0.3, 0.6), 0.8, 0.25, False),
        "sun": ((-0.5, 0.8, 0.4), 1.1, 0.1, True),
    }[cond.light]
    light = DirectionalLight(direction=direction, color=strength)
    out = []
    for i in frames:
        img = render(scan.vertices, scan.triangles, video.cameras[i], colors=scan.colors,
                     texture=texture, light=light,
                     ambient=ambient, background=(0.35, 0.4, 0.45), shadows=shadows,
                     supersample=supersample)
        img = np.asarray(img, dtype=np.float64)
        if cond.blur_px > 0:
            img = gaussian_filter(img, sigma=(cond.blur_px, cond.blur_px, 0))
        if cond.noise > 0:
            img = img + rng.normal(0.0, cond.noise, img.shape)
        out.append(np.clip(img, 0.0, 1.0))
    return np.stack(out)


def write_rendered_video(scan, video: Video, path, seed: int = 0, fps: float = 30.0):
    """Render every frame of a synthetic video (:func:`render_frames`, one call: the sensor
    noise is drawn in frame order), made 8-bit as a detector makes a rendered frame
    (:func:`morphable.detection.images.as_image`), and write them as H.264
    (:func:`morphable.video.write_video`, crf 18) -> the path. Memory: all the frames at once,
    (n, H, W, 3) float64."""
    from morphable.detection.images import as_image
    from morphable.video import write_video

    frames = render_frames(scan, video, frames=np.arange(len(video.cameras)), seed=seed)
    return write_video(path, (as_image(f)[0] for f in frames), fps=fps)


def detect_face(image, landmark_detector: str = "auto", face_detector: str = "auto"):
    """The largest face of a frame (:func:`morphable.detection.detect`) ->
    :class:`~morphable.detection.result.Detection` (points, and σ where the detector predicts
    one), or None when no face is found, so that the frame is simply not used.

    Parameters
    ----------
    image : (H, W, 3) uint8 or float in [0, 1]
    landmark_detector, face_detector : see :func:`morphable.detection.detect`
    """
    from morphable.detection import detect
    from morphable.errors import FitError

    try:
        return detect(image, landmark_detector=landmark_detector, face_detector=face_detector)
    except FitError:
        return None


def detected_points(detections, n_points: int):
    """The frames' landmarks and their noise for a fit, from one :func:`detect_face` result
    per frame (None: no face).

    Parameters
    ----------
    detections : list of Detection or None, one per frame
    n_points : 478 or 68, the rows per frame (68: the iBUG points of any detector)

    Returns
    -------
    points : (N, n_points, 2) float64 px, all NaN for a frame without a face
    sigma_px : (N, n_points) float64 px, each point's predicted error, or None when no
        detection gives one (1 px for frames without a face: they have no points)
    """
    from morphable.detection.result import landmark_noise

    points = np.full((len(detections), n_points, 2), np.nan)
    for i, d in enumerate(detections):
        if d is not None:
            points[i] = d.points if len(d.points) == n_points else d.ibug68
    sigma = landmark_noise(detections, 1.0, n_points)
    return points, None if np.ndim(sigma) == 0 else sigma


def detect_frames(images, detector=("auto", "auto"), n_points: int | None = None):
    """Each frame's largest face (:func:`detect_face`) and the fit's points from them
    (:func:`detected_points`).

    Parameters
    ----------
    images : list of (H, W, 3) frames, None for a frame not to detect (an annotated one)
    detector : (landmark detector, face detector) of :func:`morphable.detection.detect`
    n_points : 478 or 68 rows per frame; default the detector's
        (:func:`morphable.detection.landmark_count`)

    Returns
    -------
    detections : list of Detection or None (no face, or not detected), one per frame
    points : (N, n_points, 2) float64 px, NaN for a frame without a face
    sigma_px : (N, n_points) float64 px or None (:func:`detected_points`)
    """
    from morphable.detection import landmark_count

    found = [None if im is None else detect_face(im, *detector) for im in images]
    n = landmark_count(*detector) if n_points is None else n_points
    return (found, *detected_points(found, n))
