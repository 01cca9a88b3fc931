"""What a landmark detector found in a photo: :class:`Detection`."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["Detection", "SCHEMES", "CONVENTIONS", "FACE_PROBABILITY", "landmark_noise"]

SCHEMES = {"facemesh478": 478, "ibug68": 68}
"""The point sets a detection's ``points`` come in, and their row counts."""
FACE_PROBABILITY = 0.5
"""The face probability (:attr:`Detection.score`) from which a detector's crop holds a face."""
CONVENTIONS = ("2d", "3d")
"""Where a detector puts outline and hidden points: "2d" on the face's visible outline (300-W,
dlib), "3d" each on its own surface point, a hidden one where it projects (the face mesh, the
landmark network, AFLW2000-3D)."""


@dataclass(frozen=True)
class Detection:
    """One face's landmarks in a photo.

    Attributes
    ----------
    points : (P, 2) float64 px, 0-based, x right, y down; P = ``SCHEMES[scheme]``
    sigma_px : (P,) float64 px or None: each point's predicted error (standard deviation of
        an isotropic Gaussian), where the detector predicts one
    ibug68 : (68, 2) float64 px: the 68 iBUG points (the detector's own, or mapped)
    ibug68_sigma_px : (68,) float64 px or None
    scheme : "facemesh478" (mediapipe's order) or "ibug68"
    convention : "2d" or "3d" (:data:`CONVENTIONS`)
    detector : the landmark and face detectors that ran, e.g. ``"network full-range"``
    score : float or None: the detector's face probability in [0, 1]
    box : (4,) float64 ``(left, top, right, bottom)`` px or None: the face box the landmarks
        were read in (the last crop's, for a detector that re-centres)
    """
    points: np.ndarray
    sigma_px: np.ndarray | None
    ibug68: np.ndarray
    ibug68_sigma_px: np.ndarray | None
    scheme: str
    convention: str
    detector: str
    score: float | None = None
    box: np.ndarray | None = None

    def __post_init__(self):
        if self.scheme not in SCHEMES or self.convention not in CONVENTIONS:
            raise InputError(f"{self.detector}: scheme {self.scheme!r} / convention "
                             f"{self.convention!r} unknown")
        n = SCHEMES[self.scheme]
        for name, value, shape in (("points", self.points, (n, 2)), ("ibug68", self.ibug68, (68, 2)),
                                   ("sigma_px", self.sigma_px, (n,)),
                                   ("ibug68_sigma_px", self.ibug68_sigma_px, (68,))):
            if value is None and name.endswith("sigma_px"):
                continue
            a = np.asarray(value, dtype=np.float64)
            # a plugin's NaN would reach the fitter as a silent hole: refused here, once
            if a.shape != shape or not np.isfinite(a).all():
                raise InputError(f"{self.detector}: {name} must be finite, shape {shape}; got "
                                 f"shape {a.shape}{'' if np.isfinite(a).all() else ' with NaN or inf'}")
            if name.endswith("sigma_px") and not (a > 0).all():
                raise InputError(f"{self.detector}: {name} must be > 0")
            object.__setattr__(self, name, a)


def landmark_noise(detections, default_px=1.0, n_points: int = 478):
    """The ``landmark_std_px`` of :func:`morphable.fitting.fit_landmarks` for frames some of
    which a detector with σ found.

    Parameters
    ----------
    detections : list of :class:`Detection` or None, one per frame (None: an annotated frame)
    default_px : float or "auto": the noise of frames without σ (the ``--landmark-std``)
    n_points : 478 or 68: the rows the fit is given (68 when frames of the face mesh's 478
        and of dlib's 68 are mixed and the fit takes the iBUG points)

    Returns
    -------
    ``default_px`` itself when no frame has σ or ``default_px`` is "auto" (its estimate is one
    noise per fit: an explicit choice wins); else (N, n_points) float64 px: each frame's σ
    (its face-mesh rows or its iBUG rows), ``default_px`` for the frames without.
    """
    if default_px == "auto" or all(d is None or d.sigma_px is None for d in detections):
        return default_px
    if n_points not in (68, 478):
        raise InputError(f"landmark noise: n_points must be 68 or 478, got {n_points}")
    out = np.full((len(detections), n_points), float(default_px))
    for i, d in enumerate(detections):
        if d is None or d.sigma_px is None:
            continue
        sigma = d.sigma_px if n_points == len(d.sigma_px) else d.ibug68_sigma_px
        if sigma is None or len(sigma) != n_points:
            raise InputError(f"{d.detector}: σ for {len(d.sigma_px)} points, the fit takes {n_points}")
        out[i] = sigma
    return out
