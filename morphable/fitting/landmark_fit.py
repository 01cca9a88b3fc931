"""Fit identity, expressions and cameras to 2D landmarks of one or more images.

The landmarks follow a :class:`~morphable.fitting.schemes.LandmarkScheme`: iBUG-68, the face
mesh's 478 points, or any other set of points on the model's surface, some of them outline
points that slide (iBUG-68's jaw, the face mesh's oval).

Steps (each a module of this package, usable alone):

1. linear pose: a scaled orthographic camera from the 2D points and the model's mean
   landmarks (:func:`~morphable.fitting.pose.estimate_affine_pose`);
2. outline correspondences: each 2D outline point takes the nearest point of the face's
   projected outline — the jaw line where it faces the camera, else the cheek's silhouette,
   at any height — and only its distance across the outline counts
   (:mod:`~morphable.fitting.sliding`, :func:`~morphable.fitting.correspondences.slide_contours`);
   re-picked every round and every second nonlinear iteration;
3. closed-form solves for identity, then expression, under the Gaussian prior
   (:mod:`~morphable.fitting.linear`); steps 1 to 3 run ``n_linear`` times
   (:mod:`~morphable.fitting.linear_stage`; only the pose where no outline point is given
   and step 4 follows: with nothing to re-pick, the rounds would only alternate pose and
   shape, which step 4 does jointly);
4. joint Levenberg-Marquardt over rotation (axis-angle increments, no gimbal lock),
   translation, scale (affine) or depth (perspective), expressions and identity, with
   analytic Jacobians, an optional Huber loss and a Schur complement that keeps a shared
   identity cheap for many frames (:mod:`~morphable.fitting.nonlinear`);
5. for ``landmark_std_px="auto"``, the detector's noise estimated from the residuals and a
   refit (:mod:`~morphable.fitting.noise_estimation`);
6. the :class:`~morphable.fitting.result.FitResult` (:func:`~morphable.fitting.result.fit_result`).

The settings are validated in :class:`~morphable.fitting.options.FitOptions`, the data of a
fit are its :class:`~morphable.fitting.problem.Problem` and
:class:`~morphable.fitting.problem.State`, and the model rows it evaluates come from
:mod:`~morphable.fitting.rows`.

Cost (per fit)::

    sum_frames sum_landmarks rho(|uv - y|^2 / s^2) + prior_weight |alpha|^2 + |delta|^2
        + expression_weight sum_frames |beta|^2,     s^2 = landmark_std_px^2 + (k model_std_mm)^2

with ``k`` the image scale in px/mm (``landmark_std_px`` one number, or each point's own),
so that the prior has its Bayesian weight for ``prior_weight = 1`` (times
:func:`~morphable.fitting.problem.detector_looks` for a shared fit of detected frames). For
outline points ``uv - y`` is its component across the outline; for blendshape weights
``expression_weight`` is multiplied by :func:`~morphable.fitting.noise.expression_precision`,
E / 6 for E blendshapes. Only the
landmark rows of the model are evaluated, never the full mesh. ``landmark_std_px="auto"``
estimates the detector's noise from the residuals (MacKay's evidence approximation: the
normalised residuals of a fit add up to their degrees of freedom, the observations minus the
trace of the hat matrix) and refits. ``delta`` are the landmarks' definition offsets, and the
noise model is that of :mod:`~morphable.fitting.noise`.
"""
from __future__ import annotations

import time

import numpy as np

from ..threads import single_blas_thread
from .correspondences import landmark_bank
from .linear_stage import linear_stage
from .noise import MODEL_STD_MM
from .noise_estimation import AUTO_ROUNDS, estimate_landmark_std
from .nonlinear import lm_stage
from .options import FitOptions
from .problem import Problem, as_frames
from .result import FitResult, fit_result
from .rows import residuals
from .schemes import fit_scheme, ibug68_3d_scheme
from .sliding import slide

__all__ = ["fit_landmarks"]


@single_blas_thread()
def fit_landmarks(model, landmarks, image_size, *, scheme=None, camera: str = "affine", mask=None,
                  n_iterations: int = 4, n_linear: int = 3, n_identity=None, n_expression=None,
                  prior_weight: float = 1.0, expression_weight: float = 1.0, robust=None,
                  huber_k: float = 1.345, shared_identity: bool = True,
                  landmark_std_px=1.0, model_std_mm=MODEL_STD_MM,
                  definition_std_mm=None, focal_px=None,
                  contour=None, convention=None, detected=None, identity_prior_mean=None,
                  identity_prior_std=None, dtype=np.float64) -> FitResult:
    """Fit a morphable model to 2D landmarks of one or more images.

    Parameters
    ----------
    model : MorphableModel or str
        A name is loaded with ``load_model``.
    landmarks : (L, 2) or (N, L, 2) array-like, pixels
        0-based image coordinates (x right, y down); NaN rows are missing points.
    image_size : (W, H) or (N, 2), pixels
    scheme : LandmarkScheme, optional
        What the L landmarks are (:mod:`~morphable.fitting.schemes`); None: by their count,
        68 iBUG-68 (the model's ``landmark_ids``), 478 the face mesh's points (the model's
        ``facemesh478`` sidecar).
    camera : {"affine", "perspective"}
        Scaled orthographic or pinhole camera (fixed focal ``focal_px``, default ``max(W, H)``).
    mask : (L,) or (N, L) bool, optional
        False excludes a landmark (in addition to NaN rows).
    n_iterations : int
        Levenberg-Marquardt iterations after the linear stage (0 = linear fit only).
    n_linear : int
        Rounds of pose / outline / identity / expression linear solves (none, only the pose,
        where no frame gives an outline point and ``n_iterations > 0``).
    n_identity, n_expression : int or None
        Fit only the first modes (None = all).
    prior_weight, expression_weight : float >= 0
        Weights of ``|alpha|^2`` and ``|beta|^2`` (1 = the Gaussian prior at its Bayesian
        weight; for blendshapes, ``|beta|^2`` is weighted by
        :func:`~morphable.fitting.noise.expression_precision` too); 0 is allowed and stays
        finite (a tiny ridge remains).
    robust : None or "huber"
        Huber loss on the normalised landmark residuals (threshold ``huber_k``).
    shared_identity : bool
        True: one identity for all frames. False: every frame is fitted on its own (batch mode,
        vectorised); ``identity`` is then the average of the per-frame identities.
    landmark_std_px : float, "auto", or (L,) or (N, L) array-like, px
        Noise (standard deviation) of the 2D points. One number for all points; "auto"
        estimates it from the fit's own residuals (fit at 1 px, set the noise so that the
        normalised residuals add up to their degrees of freedom, refit), one value per shared
        identity, which costs about 60 % more time; or an array, each point's own noise (the
        same in every frame, or per frame), as a detector that predicts an uncertainty per
        point gives it: each residual then has its own ``s^2 = sigma^2 + (k model_std_mm)^2
        (+ (k definition_std_mm)^2)``, in the linear stage and in Levenberg-Marquardt alike,
        and the first pose weighs the points by it. Array values must be > 0 (NaN: InputError);
        a point with a noise of :data:`~morphable.fitting.noise.MISSING_STD_PX` (1e6 px) or
        more, ``inf`` included, is a missing point. The noise used is
        ``FitResult.landmark_std_px`` (per frame) and ``FitResult.point_std_px`` (per point).
    model_std_mm : float or (N,) array
        The model's per-frame landmark error (mm), or per frame; for landmarks a detector
        found, :data:`~morphable.fitting.noise.DETECTED_MODEL_STD_MM` (``morphable fit`` uses it
        for detected frames).
    definition_std_mm : None, float or (L,) array
        Standard deviation (mm, per coordinate) of each landmark's definition error, one 3D
        offset shared by all frames of a subject (see :mod:`~morphable.fitting.noise`); 0 = none.
        None: the scheme's (iBUG-68: :data:`~morphable.fitting.noise.DEFINITION_STD_MM`,
        largest for the eyebrows).
    convention : {None, "2d", "3d"}
        Where the detector puts outline points (the jaw, the face mesh's oval) and hidden
        points: "2d" (None: the default) on the face's visible outline, as 2D annotations
        (300-W, dlib, the face mesh) do: they slide along the model's outline; "3d" every
        point on its own surface point, a hidden one where it projects, as AFLW2000-3D, 3DDFA
        and the landmark network do: all points are fixed surface points (the scheme's, e.g.
        the face mesh's oval; iBUG-68's jaw on a model without jaw vertices: the points of
        :func:`morphable.labels.label_schemes`, which the network's labels use). A hidden
        point then counts with its noise like any other.
    contour : {None, "slide", "fixed"}
        The older name of the same choice: "slide" = ``convention="2d"``, "fixed" =
        ``convention="3d"`` but with the scheme as given (iBUG-68's jaw points without a
        model vertex are then left out). Giving both, they must agree.
    detected : None, bool or (N,) bool
        The frames whose landmarks a detector found (None: none, annotations). In a shared fit
        the detected frames count as one look at the face's shape: the identity's prior
        weight is multiplied by ``N / (annotated frames + 1)``
        (:func:`~morphable.fitting.problem.detector_looks`), as a detector's face-shaped errors
        do not average away over the frames of one face. It does not set ``model_std_mm``
        (:func:`~morphable.fitting.noise.frame_model_std` gives the detector's).
    identity_prior_mean : None or (K,) array-like, std units
        The centre of the identity's Gaussian prior: the prior term becomes
        ``prior_weight |alpha - identity_prior_mean|^2`` (None: 0, the model's mean face). For
        an identity guessed from elsewhere, e.g. a face descriptor
        (``evaluation.bench_descriptor_prior``); its first ``n_identity`` values are used.
    identity_prior_std : None or (K,) array-like > 0, std units
        The identity prior's standard deviation per mode (None: 1, the model's own): the
        prior weight of mode k becomes ``prior_weight / identity_prior_std[k]^2``, e.g. the
        residual spread of a guessed ``identity_prior_mean``.
    dtype : numpy dtype of the returned meshes (the fit itself runs in float64)

    Returns
    -------
    FitResult

    Raises
    ------
    FitError when the landmarks cannot determine a fit (fewer than 4 usable points,
    collinear or coincident points, a non-finite result). InputError for malformed input.

    Examples
    --------
    >>> from morphable import load_model
    >>> from morphable.camera import Camera
    >>> model = load_model("sfm")
    >>> cam = Camera.looking_at_face(image_size=(512, 512), yaw=20)
    >>> lms = cam.project(model.landmark_positions())      # NaN rows for the jaw contour
    >>> res = fit_landmarks(model, lms, (512, 512))
    >>> bool(res.landmark_rmse_px[0] < 1.0), round(float(res.euler_deg[0, 0]))
    (True, 20)
    """
    t0 = time.perf_counter()
    if isinstance(model, str):
        from ..io.registry import load_model

        model = load_model(model)
    options = FitOptions(camera=camera, n_iterations=n_iterations, n_linear=n_linear,
                         n_identity=n_identity, n_expression=n_expression,
                         prior_weight=prior_weight, expression_weight=expression_weight,
                         robust=robust, huber_k=huber_k, shared_identity=shared_identity,
                         landmark_std_px=landmark_std_px, model_std_mm=model_std_mm,
                         definition_std_mm=definition_std_mm, focal_px=focal_px,
                         contour=contour, convention=convention, detected=detected,
                         identity_prior_mean=identity_prior_mean,
                         identity_prior_std=identity_prior_std, dtype=dtype)
    y, given, size = as_frames(landmarks, mask, image_size)
    # the scheme and the model's landmark rows are prepared once per model, scheme and
    # process: not part of a fit's time
    t_bank = time.perf_counter()
    if scheme is None and options.convention == "3d" and y.shape[1] == 68:
        scheme = ibug68_3d_scheme(model)
    bank = landmark_bank(model, fit_scheme(model, y.shape[1], scheme), slide=options.slide)
    t0 += time.perf_counter() - t_bank
    pb = Problem(model, bank, options, y, given, size)
    with np.errstate(all="ignore"):
        # with no outline point to re-pick, the linear rounds would only alternate pose and
        # shape, which the nonlinear stage does jointly: it starts from the mean face in the
        # affine pose (as accurate, less time: docs/fitting.md)
        rounds = options.n_linear
        if pb.sliding is None and options.n_iterations:
            rounds = 0
        st = linear_stage(pb, rounds)
        st, iters = lm_stage(pb, st, options.n_iterations)
        for _ in range(AUTO_ROUNDS if options.auto_std else 0):
            slide(pb, st)
            pb.set_landmark_std(estimate_landmark_std(pb, st))
            st, more = lm_stage(pb, st, options.n_iterations)
            iters += more
        slide(pb, st)
        _, _, _, _, depth, r = residuals(pb, st, False)
    res = fit_result(pb, st, iters, r, depth)
    res.runtime_ms = (time.perf_counter() - t0) * 1e3
    return res
