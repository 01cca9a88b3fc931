"""The outcome of a landmark fit: coefficients, one camera per frame, residuals, a report."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
from ..errors import FitError, InputError
from .noise import effective_std

__all__ = ["FitResult", "fit_result", "AFFINE_DISTANCE_MM"]

AFFINE_DISTANCE_MM = 600.0
"""Camera distance reported for affine fits (the projection does not depend on it)."""


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
        projections of their model points (outline points: the distance across the fitted
        outline), over the landmarks used by the fit
    landmarks : (N, L, 2) the input pixels (NaN where missing), L the landmarks of the
        scheme fitted
    fitted_landmarks : (N, L, 2) projected model points (outline points: the foot of the
        given point on the projected outline; NaN where unused)
    landmark_vertices : (N, L) int, nearest model vertex of each used landmark, -1 if unused
    shared_identity : bool
    iterations : int, nonlinear iterations run
    runtime_ms : float, wall time of the fit (without the once-per-model preparation of its
        landmark rows)
    cost : (N,) px^2, final sum of squared landmark residuals per frame
    landmark_std_px : (N,) float64, the landmark noise (px) the fit assumed for each frame
        (estimated for ``"auto"``: one value per shared identity, else per frame; with a
        noise per point, the one noise of the same total weight over the used points,
        :func:`~morphable.fitting.noise.effective_std`)
    point_std_px : (N, L) float64, the landmark noise (px) the fit assumed for each point,
        NaN where a point was not used (missing, or its noise at or above
        :data:`~morphable.fitting.noise.MISSING_STD_PX`)
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
    point_std_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

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

    def landmarks_68_px(self, convention: str = "2d") -> np.ndarray:
        """(N, 68, 2) 0-based px: the fitted face's iBUG-68 landmarks in each frame, whatever
        landmark set was fitted, so that any benchmark can compare a fit with 68-point ground
        truth; NaN where the model has no such point (SFM's inner mouth corners).

        The rule is :func:`~morphable.fitting.synthetic.simulate_landmarks`' on the fitted face
        and camera: fixed points (the chin among them) are projected, jaw points lie on the
        face's outline at the heights where a detector puts them (evenly spaced along the jaw
        line from the outer eye corners' height down to the chin; on the cheek's silhouette
        where the jaw line turns away). ``convention="3d"`` leaves the jaw points on the jaw line
        where it is hidden too: projected 3D landmarks, the convention of AFLW2000-3D's ground
        truth and of 3DDFA."""
        from .synthetic import simulate_landmarks

        if convention not in ("2d", "3d"):
            raise InputError(f"convention: expected '2d' or '3d', got {convention!r}")
        return np.stack([simulate_landmarks(self.model, cam, vertices=self.vertices(i, np.float64),
                                            march=convention == "2d")
                         for i, cam in enumerate(self.cameras)])

    def to_dict(self, images=None) -> dict:
        """JSON-ready report: model, per-frame pose and residual, the fitted face's projected
        iBUG-68 landmarks (``landmarks_68_px``, 68 x [x, y] px or null where the model has no
        such point), identity, iterations, runtime."""
        images = list(images) if images is not None else [None] * self.n_frames
        lm68 = self.landmarks_68_px()
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
                 "expression": {n: float(v) for n, v in zip(self.model.expression_names, self.expression[i])},
                 "landmarks_68_px": [[float(x), float(y)] if np.isfinite(x + y) else None
                                     for x, y in lm68[i]]}
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


def fit_result(pb, st, iterations: int, r, depth) -> FitResult:
    """The :class:`FitResult` of a finished fit: its :class:`~morphable.fitting.problem.Problem`
    ``pb`` and final :class:`~morphable.fitting.problem.State` ``st``, the nonlinear
    iterations run, and the final residuals ``r`` (N, L, 2) px and depths (N, L) mm
    (:func:`~morphable.fitting.rows.residuals`). FitError for a non-finite fit, or a pinhole
    fit with landmarks behind the camera."""
    used = pb.mask & st.corr.defined
    cost = np.where(used, (r ** 2).sum(-1), 0.0).sum(1)
    rmse = np.sqrt(cost / np.maximum(used.sum(1), 1))
    parts = (st.R, st.t, st.k, st.alpha, st.beta, rmse)
    if not np.isfinite(np.concatenate([a.ravel() for a in parts])).all():
        raise FitError("the fit did not converge to finite values (degenerate landmarks?)")
    if pb.perspective and np.any(used & ~(depth > 0)):
        raise FitError("the perspective fit put landmarks behind the camera")
    cams = []
    sizes = np.rint(pb.size).astype(int).tolist()
    for i in range(pb.N):
        W_, H_ = sizes[i]
        t = st.t[i].copy()
        if not pb.perspective:
            t[2] = -AFFINE_DISTANCE_MM
        cams.append(Camera(kind=pb.options.camera, rotation=st.R[i], translation=t,
                           scale=float(st.k[i]) if not pb.perspective else 1.0,
                           focal=float(st.k[i]) if pb.perspective else 1.0,
                           image_size=(W_, H_), principal=pb.principal[i]))
    std = (effective_std(pb.landmark_var, used) if pb.point_std
           else np.zeros(pb.N) + pb.landmark_std_px)
    K, y = pb.n_identity, pb.y_obs
    frame_alpha = st.alpha[:, :K].repeat(pb.N // len(st.alpha), 0)          # (N, K)
    # outline points: the foot of the landmark on the fitted outline (the target moved along it)
    fitted = np.where(used[..., None], y + r, np.nan)
    return FitResult(model=pb.model, identity=frame_alpha.mean(0), frame_identity=frame_alpha,
                     expression=st.beta.copy(), cameras=cams, landmark_rmse_px=rmse,
                     landmarks=np.where(pb.given[..., None], y, np.nan), fitted_landmarks=fitted,
                     landmark_vertices=np.where(used, st.corr.vertex_ids(pb.bank), -1),
                     shared_identity=bool(pb.shared), iterations=iterations,
                     cost=cost, dtype=pb.options.dtype,
                     landmark_std_px=std, model_std_mm=pb.model_std_mm.astype(np.float64),
                     point_std_px=np.where(used, np.sqrt(pb.landmark_var), np.nan))
