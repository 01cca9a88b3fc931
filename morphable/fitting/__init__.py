"""Landmark fitting: identity, expressions and cameras from 2D iBUG-68 landmarks.

Modules, each usable alone:

- :mod:`.landmark_fit` — :func:`fit_landmarks`, the whole fit (one or many frames, shared or
  per-frame identity, affine or pinhole camera) returning a :class:`FitResult`, as named steps:
  - :mod:`.options` — its settings, validated (:class:`~.options.FitOptions`);
  - :mod:`.noise` — the noise and definition-error model, its defaults and the data weights;
  - :mod:`.problem` — a fit's fixed data and its state; :mod:`.rows` — the model rows of the
    correspondences, the points and residuals they give; :mod:`.sliding` — the jaw
    correspondences re-picked on the current outline;
  - :mod:`.linear_stage`, :mod:`.nonlinear` — the closed-form start and the joint
    Levenberg-Marquardt; :mod:`.noise_estimation` — ``landmark_std_px="auto"``;
  - :mod:`.result` — :class:`FitResult` and its assembly;
- :mod:`.pose` — the linear affine pose and the projection with its Jacobian;
- :mod:`.linear` — closed-form identity and expression solves under the Gaussian prior;
- :mod:`.correspondences` — landmark rows of a model, jaw sliding and the outline's silhouette;
- :mod:`.synthetic` — detector-like landmarks of a model face (tests, benchmarks).

Detection in photos is :mod:`morphable.detection`.

>>> from morphable.fitting import fit_landmarks, FitResult   # doctest: +SKIP

numpy only, at import time and in the fit.
"""
from .correspondences import Correspondences, LandmarkBank, landmark_bank, slide_contours
from .landmark_fit import fit_landmarks
from .linear import solve_expression, solve_identity
from .pose import estimate_affine_pose, project
from .result import FitResult
from .synthetic import simulate_landmarks

__all__ = ["fit_landmarks", "FitResult", "estimate_affine_pose", "project", "solve_identity",
           "solve_expression", "landmark_bank", "LandmarkBank", "Correspondences", "slide_contours",
           "simulate_landmarks"]
