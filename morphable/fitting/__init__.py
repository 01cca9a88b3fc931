"""Landmark fitting: identity, expressions and cameras from 2D iBUG-68 landmarks.

>>> from morphable.fitting import fit_landmarks, FitResult   # doctest: +SKIP

numpy only at import time; scipy and dlib load inside the functions that need them.
"""
from .correspondences import Correspondences, LandmarkBank, landmark_bank, slide_contours
from .landmark_fit import fit_landmarks
from .linear import solve_expression, solve_identity
from .pose import estimate_affine_pose, project
from .result import FitResult
from .synthetic import simulate_landmarks

__all__ = ["fit_landmarks", "FitResult", "estimate_affine_pose", "project", "solve_identity",
           "solve_expression", "landmark_bank", "LandmarkBank", "Correspondences", "slide_contours",
           "simulate_landmarks", "detect_landmarks", "detect_faces"]


def __getattr__(name):
    # detection pulls dlib: load it only when asked for
    if name in ("detect_landmarks", "detect_faces"):
        from . import detect

        return getattr(detect, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
