"""The outcome of a landmark fit: coefficients, one camera per frame, residuals, a report."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FitResult"]


@dataclass(eq=False)
class FitResult:
    """Identity, per-frame expressions and cameras recovered from 2D landmarks.

    Attributes
    ----------
    model : MorphableModel
    identity : (k,) float64, std units; with ``shared_identity=False`` the average of the
        per-frame identities (the model is linear, so this is the average neutral mesh)
    frame_identity : (N, k) float64, the identity used for each frame (all rows equal when shared)
    expression : (N, E) float64, per-frame expression coefficients
    cameras : list of N :class:`morphable.camera.Camera`
    landmark_rmse_px : (N,) float64, RMS distance (px) between the given landmarks and the
        projections of their model points (jaw points: the distance across the fitted
        outline), over the landmarks used by the fit
    landmarks : (N, 68, 2) the input pixels (NaN where missing)
    fitted_landmarks : (N, 68, 2) projected model points (jaw points: the foot of the given
        point on the projected outline; NaN where unused)
    landmark_vertices : (N, 68) int, nearest model vertex of each used landmark, -1 if unused
    shared_identity : bool
    iterations : int, nonlinear iterations run
    runtime_ms : float, wall time of the fit (without the once-per-model preparation of its
        landmark rows)
    cost : (N,) px^2, final sum of squared landmark residuals per frame
    landmark_std_px : (N,) float64, the landmark noise (px) the fit assumed for each frame
        (estimated for ``"auto"``: one value per shared identity, else per frame)
    model_std_mm : (N,) float64, the model's landmark error (mm) the fit assumed for each frame
        (a detector's is larger than an annotation's)
    """

    model: object
    identity: np.ndarray
    frame_identity: np.ndarray
    expression: np.ndarray
    cameras: list
    landmark_rmse_px: np.ndarray
    landmarks: np.ndarray
    fitted_landmarks: np.ndarray
    landmark_vertices: np.ndarray
    shared_identity: bool = True
    iterations: int = 0
    runtime_ms: float = 0.0
    cost: np.ndarray = field(default_factory=lambda: np.zeros(0))
    dtype: object = np.float64
    landmark_std_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    model_std_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n_frames(self) -> int:
        return len(self.cameras)

    @property
    def euler_deg(self) -> np.ndarray:
        """(N, 3) yaw, pitch, roll of each frame in degrees."""
        return np.stack([c.euler_deg for c in self.cameras]) if self.cameras else np.zeros((0, 3))

    def vertices(self, frame=None, dtype=None) -> np.ndarray:
        """Model-frame meshes (identity + the frame's expression), mm.

        Returns (N, V, 3) for ``frame=None``, (V, 3) for an integer frame.
        """
        dtype = dtype or self.dtype
        if frame is None:
            return self.model.vertices(self.frame_identity, self.expression, dtype=dtype)
        return self.model.vertices(self.frame_identity[frame], self.expression[frame], dtype=dtype)

    def neutral_vertices(self, dtype=None) -> np.ndarray:
        """(V, 3) mm: the identity without expression (the per-frame average when not shared)."""
        return self.model.vertices(self.identity, None, dtype=dtype or self.dtype)

    def to_dict(self, images=None) -> dict:
        """JSON-ready report: model, per-frame pose and residual, identity, iterations, runtime."""
        images = list(images) if images is not None else [None] * self.n_frames
        frames = []
        for i, cam in enumerate(self.cameras):
            yaw, pitch, roll = (float(a) for a in cam.euler_deg)
            f = {"image": None if images[i] is None else str(images[i]),
                 "landmark_rmse_px": float(self.landmark_rmse_px[i]),
                 "landmark_std_px": float(self.landmark_std_px[i]) if len(self.landmark_std_px) else None,
                 "model_std_mm": float(self.model_std_mm[i]) if len(self.model_std_mm) else None,
                 "yaw_deg": yaw, "pitch_deg": pitch, "roll_deg": roll,
                 "translation": [float(x) for x in cam.translation], "camera": cam.kind,
                 "image_size": list(cam.image_size),
                 "expression": {n: float(v) for n, v in zip(self.model.expression_names, self.expression[i])}}
            if cam.kind == "affine":
                f["scale"] = float(cam.scale)
            else:
                f["focal_px"] = float(cam.focal)
            if not self.shared_identity:
                f["identity"] = [float(x) for x in self.frame_identity[i]]
            frames.append(f)
        return {"model": self.model.name, "n_frames": self.n_frames,
                "shared_identity": bool(self.shared_identity), "frames": frames,
                "identity": [float(x) for x in self.identity],
                "iterations": int(self.iterations), "runtime_ms": float(self.runtime_ms)}
