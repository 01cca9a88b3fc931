"""The settings of a landmark fit, validated in one place.

:func:`~morphable.fitting.landmark_fit.fit_landmarks` builds a :class:`FitOptions` from its
keyword arguments (their meaning is documented there). Settings alone are checked when the
options are made; the checks that need the frames or the model are the methods that resolve
a setting for them (:meth:`FitOptions.frame_model_std`, :meth:`FitOptions.modes`,
:meth:`FitOptions.focal`, :meth:`FitOptions.landmark_definition_std`).
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .noise import MODEL_STD_MM

__all__ = ["FitOptions", "CONVENTIONS", "FACEMESH_CONVENTION", "detected_settings",
           "detection_settings"]

CONVENTIONS = {"2d": "slide", "3d": "fixed"}
"""The landmark conventions and the outline handling each takes (``contour``): "2d", outline
points where a 2D annotator puts them, on the face's visible outline (they slide along it);
"3d", every point a fixed surface point, a hidden one where it projects (AFLW2000-3D, 3DDFA,
the landmark network)."""


def _finite_nonnegative(v) -> bool:
    # a plain number is checked without numpy: the defaults are numbers, and a fit's options
    # are made for every fit
    if isinstance(v, (int, float)):
        return math.isfinite(v) and v >= 0
    a = np.asarray(v)
    return bool(np.isfinite(a).all() and (a >= 0).all())


@dataclass(frozen=True, eq=False)
class FitOptions:
    """The settings of :func:`~morphable.fitting.landmark_fit.fit_landmarks`, with its defaults.

    Raises InputError for a malformed setting. After validation ``model_std_mm`` and
    ``definition_std_mm`` are float64 arrays ((), (N,) or (L,)), or ``definition_std_mm``
    None (the landmark scheme's), ``landmark_std_px`` a number, "auto" or a read-only
    float64 array ((L,) or (N, L) px: :attr:`point_std`), and ``dtype`` a numpy dtype.
    """

    camera: str = "affine"
    n_iterations: int = 4
    n_linear: int = 3
    n_identity: int | None = None
    n_expression: int | None = None
    prior_weight: float = 1.0
    expression_weight: float = 1.0
    robust: str | None = None
    huber_k: float = 1.345
    shared_identity: bool = True
    landmark_std_px: object = 1.0
    model_std_mm: object = MODEL_STD_MM
    definition_std_mm: object = None
    focal_px: object = None
    contour: str | None = None
    convention: str | None = None
    detected: object = None
    identity_prior_mean: object = None
    identity_prior_std: object = None
    dtype: object = np.float64

    def __post_init__(self):
        if self.camera not in ("affine", "perspective"):
            raise InputError(f"camera: expected 'affine' or 'perspective', got {self.camera!r}")
        if self.convention not in (None, *CONVENTIONS):
            raise InputError(f"convention: expected '2d' or '3d', got {self.convention!r}")
        if self.contour not in (None, "slide", "fixed"):
            raise InputError(f"contour: expected 'slide' or 'fixed', got {self.contour!r}")
        if (self.contour is not None and self.convention is not None
                and self.contour != CONVENTIONS[self.convention]):
            raise InputError(f"contour={self.contour!r} contradicts convention="
                             f"{self.convention!r} (which means contour="
                             f"{CONVENTIONS[self.convention]!r})")
        if self.robust not in (None, "huber"):
            raise InputError(f"robust: expected None or 'huber', got {self.robust!r}")
        auto = self.auto_std
        if auto and self.landmark_std_px != "auto":
            raise InputError(f"landmark_std_px: expected a number, an array or 'auto', got "
                             f"{self.landmark_std_px!r}")
        v = self.landmark_std_px
        point_std = not (auto or isinstance(v, numbers.Real) or
                         (isinstance(v, np.ndarray) and v.ndim == 0))
        if point_std:
            object.__setattr__(self, "landmark_std_px", _point_std(v))
        definition_std_mm = (None if self.definition_std_mm is None
                             else np.asarray(self.definition_std_mm, dtype=np.float64))
        for name, v in (("prior_weight", self.prior_weight),
                        ("expression_weight", self.expression_weight),
                        ("landmark_std_px", 1.0 if auto or point_std else self.landmark_std_px),
                        ("model_std_mm", self.model_std_mm),
                        ("definition_std_mm",
                         0.0 if definition_std_mm is None else definition_std_mm),
                        ("huber_k", self.huber_k)):
            if not _finite_nonnegative(v):
                raise InputError(f"{name}: must be finite and >= 0, got {v}")
        model_std_mm = np.asarray(self.model_std_mm, dtype=np.float64)
        if not (auto or point_std) and self.landmark_std_px == 0 and (model_std_mm == 0).any():
            raise InputError("landmark_std_px and model_std_mm cannot both be 0")
        if self.focal_px is not None:
            focal = np.asarray(self.focal_px, dtype=np.float64)
            if not (np.all(np.isfinite(focal)) and np.all(focal > 0)):
                raise InputError(f"focal_px: must be positive, got {self.focal_px}")
        if self.identity_prior_mean is not None:
            mean = np.array(self.identity_prior_mean, dtype=np.float64)
            if mean.ndim != 1 or not np.all(np.isfinite(mean)):
                raise InputError(f"identity_prior_mean: expected finite (K,) identity coefficients, "
                                 f"got shape {mean.shape}")
            mean.setflags(write=False)
            object.__setattr__(self, "identity_prior_mean", mean)
        if self.identity_prior_std is not None:
            std = np.array(self.identity_prior_std, dtype=np.float64)
            if std.ndim != 1 or not np.all(np.isfinite(std) & (std > 0)):
                raise InputError(f"identity_prior_std: expected positive finite (K,) values, got "
                                 f"{np.shape(self.identity_prior_std)} {std if std.size < 8 else ''}")
            std.setflags(write=False)
            object.__setattr__(self, "identity_prior_std", std)
        # frozen: the normalised values replace the given ones once, here
        object.__setattr__(self, "definition_std_mm", definition_std_mm)
        object.__setattr__(self, "model_std_mm", model_std_mm)
        object.__setattr__(self, "dtype", np.dtype(self.dtype))

    @property
    def auto_std(self) -> bool:
        """True for ``landmark_std_px="auto"``: the noise is estimated from the residuals."""
        return isinstance(self.landmark_std_px, str)

    @property
    def start_std_px(self) -> float:
        """The one landmark noise the fit starts with, px (1 for ``"auto"``; for a noise per
        point, 1: the per-point values are :meth:`landmark_std`)."""
        return 1.0 if self.auto_std or self.point_std is not None else float(self.landmark_std_px)

    @property
    def point_std(self):
        """The per-point landmark noise (an array: (L,) or (N, L) px), None for one number or
        ``"auto"``."""
        v = self.landmark_std_px
        return v if isinstance(v, np.ndarray) and v.ndim else None

    @property
    def slide(self) -> bool:
        """Whether outline points slide along the face's outline (``contour="slide"``, the
        default, or ``convention="2d"``) or are fixed surface points."""
        if self.contour is not None:
            return self.contour == "slide"
        return CONVENTIONS[self.convention or "2d"] == "slide"

    def landmark_std(self, n_frames: int, n_landmarks: int) -> np.ndarray:
        """(N, L) the landmark noise of each point of each frame, px (a read-only view): the
        one number, 1 for ``"auto"`` (where the fit starts), or the per-point array. InputError
        for an array of another shape."""
        std = self.point_std
        if std is None:
            std = np.float64(1.0 if self.auto_std else self.landmark_std_px)
        elif std.shape not in ((n_landmarks,), (n_frames, n_landmarks)):
            raise InputError(f"landmark_std_px: expected one number, ({n_landmarks},) or "
                             f"({n_frames}, {n_landmarks}) px, got shape {std.shape}")
        return np.broadcast_to(std, (n_frames, n_landmarks))

    @property
    def perspective(self) -> bool:
        return self.camera == "perspective"

    def frame_model_std(self, n_frames: int) -> np.ndarray:
        """(N,) ``model_std_mm`` of each of ``n_frames`` frames, mm (a read-only view)."""
        if self.model_std_mm.shape not in ((), (n_frames,)):
            raise InputError(f"model_std_mm: expected a number or one per frame ({n_frames}), "
                             f"got shape {self.model_std_mm.shape}")
        return np.broadcast_to(self.model_std_mm, (n_frames,))

    def frame_detected(self, n_frames: int) -> np.ndarray:
        """(N,) bool: the frames whose landmarks a detector found (``detected``; None: none)."""
        if self.detected is None:
            return np.zeros(n_frames, bool)
        d = np.asarray(self.detected)
        if d.dtype != bool or d.shape not in ((), (n_frames,)):
            raise InputError(f"detected: expected a bool or {n_frames} bools (one per frame), "
                             f"got {d.dtype} of shape {d.shape}")
        return np.broadcast_to(d, (n_frames,))

    def landmark_definition_std(self, scheme) -> np.ndarray:
        """(L,) ``definition_std_mm`` of each landmark of ``scheme``, mm (a read-only view):
        the scheme's own where None."""
        if self.definition_std_mm is None:
            view = scheme.definition_std_mm.view()
            view.flags.writeable = False
            return view
        if self.definition_std_mm.shape not in ((), (scheme.n,)):
            raise InputError(f"definition_std_mm: expected a number or {scheme.n} numbers, got "
                             f"shape {self.definition_std_mm.shape}")
        return np.broadcast_to(self.definition_std_mm, (scheme.n,))

    def modes(self, model) -> tuple[int, int]:
        """(K, E): the identity and expression modes of ``model`` the fit solves for."""
        K = model.n_identity if self.n_identity is None else int(self.n_identity)
        E = model.n_expression if self.n_expression is None else int(self.n_expression)
        if not (0 <= K <= model.n_identity) or not (0 <= E <= model.n_expression):
            raise InputError(f"n_identity/n_expression must be in [0, {model.n_identity}] / "
                             f"[0, {model.n_expression}], got {K} / {E}")
        return K, E

    def focal(self, size) -> np.ndarray:
        """(N,) pinhole focal length of each frame, px: ``focal_px``, else ``max(W, H)`` of
        ``size`` (N, 2)."""
        if self.focal_px is None:
            return size.max(1)
        return np.broadcast_to(np.asarray(self.focal_px, dtype=np.float64), (len(size),)).copy()


FACEMESH_CONVENTION = "3d"
"""The convention of the face mesh's detected points: mediapipe's face mesh regresses a 3D
mesh, so its oval points are mesh points where they project, not the visible outline. Fitted
so, the Florence protocol's shared fits came out better in every condition and the per-frame
ones the same or better, in less time (docs/fitting.md, "Fitting with per-point sigma")."""


def detected_settings(detected, n_landmarks: int) -> dict:
    """The fit settings for frames whose landmarks a detector found or not ((N,) bool
    ``detected``) with ``n_landmarks`` points each: ``model_std_mm``, the detector's model
    error for detected frames (:func:`~morphable.fitting.noise.frame_model_std`); and where
    every frame holds the face mesh's detected 478 points, its ``convention``
    (:data:`FACEMESH_CONVENTION`) and ``detected``: a shared fit counts its frames as one
    look at the face (:func:`~morphable.fitting.problem.detector_looks`). The face mesh's
    errors are correlated over its 478 dense points and over the views of a video; with
    dlib's 68 points the same rule cost 1-8 % on the Florence protocol, where the face mesh
    gained up to 13 % (docs/fitting.md, "Fitting with per-point sigma")."""
    from .noise import frame_model_std

    detected = np.asarray(detected, dtype=bool)
    out = {"model_std_mm": frame_model_std(detected)}
    if n_landmarks == 478 and detected.size and detected.all():
        out.update(convention=FACEMESH_CONVENTION, detected=detected)
    return out


def detection_settings(detections, n_landmarks: int, landmark_std_px=1.0) -> dict:
    """The keywords of :func:`~morphable.fitting.fit_landmarks` for frames found by detectors
    or annotated, as ``morphable fit`` fits them: :func:`detected_settings` plus
    ``landmark_std_px``, each frame's σ where its detector gives one
    (:func:`morphable.detection.result.landmark_noise`).

    Parameters
    ----------
    detections : list of :class:`~morphable.detection.result.Detection`, or None for an
        annotated frame, one per frame
    n_landmarks : 478 or 68, the points per frame the fit is given
    landmark_std_px : float or "auto", px: the noise of frames without σ

    Examples
    --------
    >>> detection_settings([None], 68)["landmark_std_px"]
    1.0
    """
    from ..detection.result import landmark_noise

    return {**detected_settings([d is not None for d in detections], n_landmarks),
            "landmark_std_px": landmark_noise(detections, landmark_std_px, n_landmarks)}


def _point_std(value) -> np.ndarray:
    """A per-point landmark noise array (px) as float64; InputError for NaN, values <= 0 or
    not numbers. +inf (and anything from :data:`~morphable.fitting.noise.MISSING_STD_PX` up)
    is a missing point."""
    try:
        std = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("landmark_std_px: expected numbers (px), got "
                         f"{type(value).__name__} of non-numbers") from None
    if std.ndim not in (1, 2):
        raise InputError(f"landmark_std_px: expected one number, (L,) or (N, L) px, got shape "
                         f"{std.shape}")
    if np.isnan(std).any():
        i = np.argwhere(np.isnan(std))[0].tolist()
        raise InputError(f"landmark_std_px: NaN at {tuple(i) if len(i) > 1 else i[0]} "
                         "(a point without a noise: give +inf or a NaN landmark for a missing point)")
    if (std <= 0).any():
        i = np.argwhere(std <= 0)[0].tolist()
        raise InputError(f"landmark_std_px: must be > 0, got {std[tuple(i)]:g} at "
                         f"{tuple(i) if len(i) > 1 else i[0]}")
    std.flags.writeable = False
    return std
