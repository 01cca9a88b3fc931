"""Model fitting: identity, expressions and cameras from 2D landmarks (iBUG-68, the face
mesh's 478 points, any :mod:`.schemes` landmark scheme), or from a 3D scan.

Modules, each usable alone:

- :mod:`.landmark_fit` — :func:`fit_landmarks`, the whole fit (one or many frames, shared or
  per-frame identity, affine or pinhole camera) returning a :class:`FitResult`, as named steps:

  - :mod:`.options` — its settings, validated (:class:`~.options.FitOptions`);
  - :mod:`.noise` — the noise and definition-error model, its defaults and the data weights;
  - :mod:`.problem` — a fit's fixed data and its state; :mod:`.rows` — the model rows of the
    correspondences, the points and residuals they give; :mod:`.sliding` — the outline
    correspondences re-picked on the current outline;
  - :mod:`.linear_stage`, :mod:`.nonlinear` — the closed-form start and the joint
    Levenberg-Marquardt; :mod:`.offsets` — the landmark offsets of a shared fit, solved by
    their block-diagonal structure; :mod:`.noise_estimation` — ``landmark_std_px="auto"``;
  - :mod:`.result` — :class:`FitResult` and its assembly;

- :mod:`.pose` — the linear affine pose and the projection with its Jacobian;
- :mod:`.linear` — closed-form identity and expression solves under the Gaussian prior;
- :mod:`.schemes` — landmark schemes: L points on a model's surface, the outline ones sliding;
- :mod:`.correspondences` — landmark rows of a model and scheme, outline sliding and the
  outline's silhouette;
- :mod:`.synthetic` — detector-like landmarks of a model face (tests, benchmarks);
- :mod:`.scan_fit` — a model fitted to a 3D scan: :func:`fit_surface` (point-to-plane) and
  :func:`fit_landmarks_3d` (its 3D landmarks), on the :func:`outer_skin` vertices.

Detection in photos is :mod:`morphable.detection`.

>>> from morphable import load_model
>>> from morphable.camera import Camera
>>> from morphable.fitting import fit_landmarks, simulate_landmarks
>>> sfm = load_model("sfm")
>>> seen = simulate_landmarks(sfm, Camera.looking_at_face((512, 512), yaw=20))   # (68, 2) px
>>> fit = fit_landmarks(sfm, seen, (512, 512))
>>> round(float(fit.euler_deg[0, 0]), 1), bool(fit.landmark_rmse_px[0] < 0.1)      # yaw, degrees
(20.0, True)

numpy only, at import time and in the landmark fit; scipy and open3d load inside the scan fits.
"""
from .correspondences import Correspondences, LandmarkBank, landmark_bank, slide_contours
from .landmark_fit import fit_landmarks
from .linear import solve_expression, solve_identity
from .pose import estimate_affine_pose, project
from .result import FitResult
from .scan_fit import fit_landmarks_3d, fit_surface, outer_skin
from .synthetic import simulate_landmarks

__all__ = ["fit_landmarks", "FitResult", "estimate_affine_pose", "project", "solve_identity",
           "solve_expression", "landmark_bank", "LandmarkBank", "Correspondences", "slide_contours",
           "simulate_landmarks", "fit_surface", "fit_landmarks_3d", "outer_skin"]
