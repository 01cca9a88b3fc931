"""What a landmark detector found in a photo: :class:`Detection`."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["Detection", "SCHEMES", "CONVENTIONS"]

SCHEMES = {"facemesh478": 478, "ibug68": 68}
"""The point sets a detection's ``points`` come in, and their row counts."""
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
