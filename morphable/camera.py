"""Cameras: scaled orthographic ("affine") and pinhole perspective, with rotations.

Frames
------
- Model/world: millimetres; x to the subject's left, y up, z out of the face.
- Camera (OpenGL): x right, y up, z towards the viewer; the camera looks along -z.
  ``X_cam = R @ X + t``.
- Image: pixels, x right, y down, 0-based, pixel centres at integers; the principal point
  defaults to the image centre ``((W - 1) / 2, (H - 1) / 2)``.

Projection
----------
- affine (scaled orthographic): ``u = cx + s * Xc``, ``v = cy - s * Yc`` (s in px/mm).
- perspective: ``u = cx + f * Xc / (-Zc)``, ``v = cy - f * Yc / (-Zc)`` (f in px); points
  must have ``Zc < 0`` (in front of the camera).

Depth is ``-Zc`` in mm (larger is farther) for both kinds.

Rotations are stored as 3x3 matrices; the public angles are degrees:
``R = Rz(roll) @ Rx(pitch) @ Ry(yaw)`` — yaw about the vertical axis (positive turns the
nose towards the image's right, i.e. the subject looks to their left and shows more of
their right cheek), pitch about x (positive turns the nose down), roll about the view axis
(positive is counter-clockwise in the image).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import InputError

__all__ = ["Camera", "euler_to_matrix", "matrix_to_euler", "axis_angle_to_matrix",
           "matrix_to_axis_angle", "cross"]


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def euler_to_matrix(yaw, pitch, roll) -> np.ndarray:
    """Degrees -> rotation ``Rz(roll) @ Rx(pitch) @ Ry(yaw)``, shape (..., 3, 3)."""
    y, p, r = (np.radians(np.asarray(a, dtype=np.float64)) for a in (yaw, pitch, roll))
    y, p, r = np.broadcast_arrays(y, p, r)
    return _rz(r) @ _rx(p) @ _ry(y)


def matrix_to_euler(R) -> np.ndarray:
    """Rotation (..., 3, 3) -> (..., 3) degrees (yaw, pitch, roll), inverse of
    :func:`euler_to_matrix`; pitch in [-90, 90], yaw and roll in (-180, 180]."""
    R = np.asarray(R, dtype=np.float64)
    # R = Rz(r) Rx(p) Ry(y): R[2,1] = sin p, R[2,0] = -cos p sin y, R[2,2] = cos p cos y,
    # R[0,1] = -sin r cos p, R[1,1] = cos r cos p
    pitch = np.arcsin(np.clip(R[..., 2, 1], -1.0, 1.0))
    yaw = np.arctan2(-R[..., 2, 0], R[..., 2, 2])
    roll = np.arctan2(-R[..., 0, 1], R[..., 1, 1])
    # gimbal lock (pitch = +-90): put everything into roll
    lock = np.abs(R[..., 2, 1]) > 1 - 1e-12
    if np.any(lock):
        yaw = np.where(lock, 0.0, yaw)
        roll = np.where(lock, np.arctan2(R[..., 1, 0], R[..., 0, 0]), roll)
    return np.degrees(np.stack([yaw, pitch, roll], -1))


_NEXT, _PREV = np.array([1, 2, 0]), np.array([2, 0, 1])
# the cross-product matrix [w]x of w as w[..., _SKEW] * _SKEW_SIGN
_SKEW = np.array([[0, 2, 1], [2, 0, 0], [1, 0, 0]])
_SKEW_SIGN = np.array([[0.0, -1.0, 1.0], [1.0, 0.0, -1.0], [-1.0, 1.0, 0.0]])


def cross(a, b) -> np.ndarray:
    """Cross product of 3-vectors over the last axis, (..., 3) x (..., 3) -> (..., 3),
    broadcasting like ``np.cross``: the same values, a few times faster on the small arrays of
    a fit (``np.cross`` spends most of its time moving axes; here ``a1 b2 - a2 b1`` and its
    cyclic shifts are two products of shifted copies)."""
    return a[..., _NEXT] * b[..., _PREV] - a[..., _PREV] * b[..., _NEXT]


def axis_angle_to_matrix(w) -> np.ndarray:
    """Rodrigues: axis-angle (..., 3) in radians -> (..., 3, 3); exact near zero."""
    w = np.asarray(w, dtype=np.float64)
    theta = np.sqrt((w * w).sum(-1))[..., None, None]      # np.linalg.norm's sum, less overhead
    K = w[..., _SKEW] * _SKEW_SIGN
    t2 = theta * theta
    small = t2 < 1e-12
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1 - t2 / 6, np.sin(safe) / safe)
    b = np.where(small, 0.5 - t2 / 24, (1 - np.cos(safe)) / np.where(small, 1.0, t2))
    return np.eye(3) + a * K + b * (K @ K)


def matrix_to_axis_angle(R) -> np.ndarray:
    """Rotation (..., 3, 3) -> axis-angle (..., 3) radians (scipy, robust near pi)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=np.float64)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


@dataclass
class Camera:
    """A camera for one image (see the module docstring for frames and formulas).

    Attributes
    ----------
    kind : {"affine", "perspective"}
    rotation : (3, 3) float, world -> camera
    translation : (3,) float, mm, camera frame
    scale : float, px/mm (affine) — ignored for perspective
    focal : float, px (perspective) — ignored for affine
    image_size : (W, H) ints, pixels
    principal : (2,) float or None (None = image centre)

    Examples
    --------
    >>> cam = Camera.looking_at_face(image_size=(512, 512), yaw=30)
    >>> cam.project(np.zeros((1, 3))).round(1)
    array([[255.5, 255.5]])
    """

    kind: str = "affine"
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0
    focal: float = 1.0
    image_size: tuple = (512, 512)
    principal: np.ndarray | None = None

    def __post_init__(self):
        if self.kind not in ("affine", "perspective"):
            raise InputError(f"camera kind must be 'affine' or 'perspective', got {self.kind!r}")
        W, H = (int(x) for x in self.image_size)
        if W <= 0 or H <= 0:
            raise InputError(f"image size must be positive, got {self.image_size}")
        self.image_size = (W, H)
        self.rotation = np.asarray(self.rotation, dtype=np.float64).reshape(3, 3)
        self.translation = np.asarray(self.translation, dtype=np.float64).reshape(3)
        if self.principal is None:
            self.principal = np.array([(W - 1) / 2.0, (H - 1) / 2.0])
        self.principal = np.asarray(self.principal, dtype=np.float64).reshape(2)
        if not (np.isfinite(self.rotation).all() and np.isfinite(self.translation).all()
                and np.isfinite(self.principal).all() and math.isfinite(self.scale)
                and math.isfinite(self.focal)):
            raise InputError("camera parameters contain NaN or inf")

    # --- construction -------------------------------------------------------------------
    @classmethod
    def looking_at_face(cls, image_size=(512, 512), yaw=0.0, pitch=0.0, roll=0.0,
                        kind="affine", face_width_px=None, distance_mm=600.0, center=(0, 0, 0)):
        """A camera that sees a head-sized object at ``center`` (mm) filling about half the image.

        Parameters
        ----------
        yaw, pitch, roll : degrees
        face_width_px : float or None
            Pixels per 150 mm (a face's width); default half the smaller image side.
        distance_mm : float
            Camera distance for perspective (focal chosen to keep ``face_width_px``).
        """
        W, H = image_size
        px = face_width_px or 0.5 * min(W, H)
        R = euler_to_matrix(yaw, pitch, roll)
        t = -R @ np.asarray(center, dtype=np.float64) + np.array([0.0, 0.0, -distance_mm])
        s = px / 150.0
        return cls(kind=kind, rotation=R, translation=t, scale=s, focal=s * distance_mm,
                   image_size=(W, H))

    def with_pose(self, yaw=None, pitch=None, roll=None):
        """A copy with some Euler angles replaced (degrees)."""
        y, p, r = self.euler_deg
        return replace(self, rotation=euler_to_matrix(yaw if yaw is not None else y,
                                                      pitch if pitch is not None else p,
                                                      roll if roll is not None else r))

    # --- geometry -----------------------------------------------------------------------
    @property
    def euler_deg(self) -> np.ndarray:
        """(yaw, pitch, roll) in degrees."""
        return matrix_to_euler(self.rotation)

    def to_camera(self, points) -> np.ndarray:
        """(..., N, 3) world mm -> camera frame mm."""
        return np.asarray(points) @ self.rotation.T + self.translation

    def depth(self, points) -> np.ndarray:
        """(..., N) distance along the viewing direction, mm."""
        return -self.to_camera(points)[..., 2]

    @property
    def centre(self) -> np.ndarray:
        """(3,) world mm: the pinhole (perspective); for the affine camera, the point of its
        axis at the camera plane."""
        return -self.rotation.T @ self.translation

    def view_directions(self, points) -> np.ndarray:
        """(..., 3) unit vectors from world points (..., 3) towards the camera: the pinhole's
        direction (perspective) or the camera's +z axis, the same for all (affine)."""
        if self.kind == "affine":
            return np.broadcast_to(self.rotation.T @ np.array([0.0, 0.0, 1.0]), np.shape(points))
        d = self.centre - np.asarray(points, dtype=np.float64)
        return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)

    def px_per_mm(self, points) -> np.ndarray:
        """(...,) image scale at world points (..., 3) mm, px/mm: ``scale`` (affine) or
        ``focal / depth`` (perspective; NaN at depth <= 0)."""
        return self._px_per_mm_at(self.to_camera(points))

    def _px_per_mm_at(self, camera_points) -> np.ndarray:
        """:meth:`px_per_mm` of points already in the camera frame."""
        if self.kind == "affine":
            return np.full(np.shape(camera_points)[:-1], float(self.scale))
        d = -camera_points[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(d > 0, self.focal / np.where(d > 0, d, 1.0), np.nan)

    def project(self, points) -> np.ndarray:
        """(..., N, 3) world mm -> (..., N, 2) pixels.

        Perspective points behind the camera (depth <= 0) give NaN pixels.
        """
        return self.project_camera_frame(self.to_camera(points))

    def project_camera_frame(self, camera_points) -> np.ndarray:
        """(..., N, 3) camera-frame mm (:meth:`to_camera`) -> (..., N, 2) pixels, as
        :meth:`project`, for points already moved into the camera frame."""
        Xc = np.asarray(camera_points)
        k = self._px_per_mm_at(Xc)
        x, y = k * Xc[..., 0], k * Xc[..., 1]
        return np.stack([self.principal[0] + x, self.principal[1] - y], -1)

    def rays(self, width=None, height=None, supersample: int = 1):
        """Ray origins and unit directions (world frame) through pixel centres.

        Returns
        -------
        origins, directions : (H*ss, W*ss, 3) float64 (mm); for the affine camera the
        origins lie on a plane ``far`` behind the scene and the directions are parallel.
        ``pixel (i, j)`` at supersample 1 is the ray through image point (x=j, y=i).
        """
        W = width or self.image_size[0]
        H = height or self.image_size[1]
        ss = int(supersample)
        xs = (np.arange(W * ss) + 0.5) / ss - 0.5
        ys = (np.arange(H * ss) + 0.5) / ss - 0.5
        u, v = np.meshgrid(xs, ys)
        Rt = self.rotation.T
        if self.kind == "affine":
            xc = (u - self.principal[0]) / self.scale
            yc = (self.principal[1] - v) / self.scale
            # start far in front of the camera plane so that nothing is clipped
            far = 1e4
            pc = np.stack([xc, yc, np.full_like(xc, far)], -1) - self.translation
            origins = pc @ Rt.T
            d = Rt @ np.array([0.0, 0.0, -1.0])
            return origins, np.broadcast_to(d, origins.shape).copy()
        xc = (u - self.principal[0]) / self.focal
        yc = (self.principal[1] - v) / self.focal
        dc = np.stack([xc, yc, -np.ones_like(xc)], -1)
        dc /= np.linalg.norm(dc, axis=-1, keepdims=True)
        return np.broadcast_to(self.centre, dc.shape).copy(), dc @ Rt.T

    def to_dict(self) -> dict:
        """JSON-ready description (angles in degrees, mm, px)."""
        yaw, pitch, roll = (float(a) for a in self.euler_deg)
        d = {"kind": self.kind, "yaw_deg": yaw, "pitch_deg": pitch, "roll_deg": roll,
             "rotation": self.rotation.tolist(), "translation_mm": self.translation.tolist(),
             "image_size": list(self.image_size), "principal_px": self.principal.tolist()}
        d["scale_px_per_mm" if self.kind == "affine" else "focal_px"] = float(
            self.scale if self.kind == "affine" else self.focal)
        return d

    @classmethod
    def from_dict(cls, d: dict):
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(kind=d["kind"], rotation=np.asarray(d["rotation"]),
                       translation=np.asarray(d["translation_mm"]),
                       scale=float(d.get("scale_px_per_mm", 1.0)), focal=float(d.get("focal_px", 1.0)),
                       image_size=tuple(d["image_size"]), principal=np.asarray(d["principal_px"]))
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"camera description is incomplete ({e})") from None
