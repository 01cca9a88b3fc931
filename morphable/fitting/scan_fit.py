"""A model fitted to a 3D face scan: to its surface, or to its own 3D landmarks.

- :func:`fit_surface` — identity (and expressions, and a rigid pose) fitted point-to-plane to
  the scan's surface, started from its landmarks;
- :func:`fit_landmarks_3d` — identity and expressions fitted to the scan's 3D landmarks alone,
  with the landmark fit's definition-error profile and priors;
- :func:`outer_skin` — the model vertices a scan can have (no cavities, no inside).

A scan is plain arrays: vertices (n, 3) mm, triangles (m, 3) int, landmarks (68, 3) mm in
iBUG order (NaN rows where missing), all in the scan's own frame; any mesh loader gives them
(:func:`evaluation.scans.load_scan` is one). scipy and open3d are imported inside the functions.
Each function's example fits a face of the model itself, given as such a scan.
"""
from __future__ import annotations

import weakref

import numpy as np

from ..errors import InputError
from ..ibug68 import N_LANDMARKS
from ..logs import import_open3d
from ..metrics import NOSE_TIP, Similarity, align_landmarks, submesh

__all__ = ["fit_surface", "fit_landmarks_3d", "outer_skin", "MIN_OPEN"]

MIN_OPEN = 0.1
"""Share of directions from a skin vertex that must reach open space for :func:`outer_skin`."""
_OUTER: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def outer_skin(model) -> np.ndarray:
    """(V,) bool: the vertices a scan of the face can have — the model's skin
    (:meth:`~morphable.model.MorphableModel.skin_vertices`) and, for a model with an inside
    (eyeballs, teeth: ICT), only the skin of its mean face that is not in a cavity: from a
    vertex at least :data:`MIN_OPEN` of 64 directions spread over the sphere reach open space
    (a flat patch: half of them). This leaves out the inside of the nostrils, between the lips
    and the ear's folds (10 % of ICT's skin; on james the nostrils' insides made a third of the
    ICT mean face's error in the crop). Read-only, cached per model."""
    if model in _OUTER:
        return _OUTER[model]
    keep = np.zeros(model.n_vertices, dtype=bool)
    keep[model.skin_vertices()] = True
    if not keep.all():
        o3d = import_open3d()

        from ..normals import vertex_normals
        from ..raster.visibility import scene as raycasting_scene

        ids, tri = submesh(model.triangles, keep)
        v = np.asarray(model.mean, dtype=np.float64)[ids]
        scene = raycasting_scene(v, tri)
        start = v + 0.5 * vertex_normals(v, tri)     # just off the surface, not on it
        i = np.arange(64) + 0.5                       # a Fibonacci sphere of directions
        z, phi = 1.0 - 2.0 * i / len(i), np.pi * (1.0 + 5.0 ** 0.5) * i
        r = np.sqrt(1.0 - z * z)
        directions = np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)
        free = np.zeros(len(v))
        for d in directions:
            rays = np.concatenate([start, np.broadcast_to(d, v.shape)], 1).astype(np.float32)
            free += np.isinf(scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy())
        keep[ids[free / len(directions) < MIN_OPEN]] = False
    keep.flags.writeable = False
    _OUTER[model] = keep
    return keep


def _scan_landmarks(landmarks, name: str) -> np.ndarray:
    lm = np.asarray(landmarks, dtype=np.float64)
    if lm.shape != (N_LANDMARKS, 3):
        raise InputError(f"{name}: expected (68, 3) landmarks in iBUG order, mm, got {lm.shape}")
    return lm


def fit_surface(model, vertices, triangles, landmarks, *, n_iterations: int = 8,
                prior_weight: float = 1.0, max_distance_mm: float = 10.0,
                radius_mm: float = 95.0, expression: bool = False, pose: str = "landmarks",
                skin=None, name: str = "scan"):
    """Coefficients fitting ``model`` to a scan surface -> identity (K,), expression (E,).

    Each of ``n_iterations`` rounds pairs every ``skin`` vertex of the model within
    ``radius_mm`` of the nose tip with its nearest scan vertex (closer than
    ``max_distance_mm``) and solves the point-to-plane equations
    ``n . (mean + A alpha + B beta - p) = 0`` (the scan moved into the model's frame) by
    least squares with ``prior_weight (|alpha|^2 + |beta|^2)`` (mm^2 units).

    Parameters
    ----------
    vertices : (n, 3) mm, the scan's vertices
    triangles : (m, 3) int, its triangles (for the normals)
    landmarks : (68, 3) mm, its iBUG landmarks, NaN where missing
    expression : also fit the expression coefficients (blendshape weights kept in [0, 1]);
        False leaves them 0
    pose : how the scan is placed in the model's frame. ``"landmarks"``: the similarity from
        its landmarks to the current face's landmark vertices, every round (the face's size is
        then the similarity's; the definition profile was measured this way). ``"joint"``: a
        rigid transform, started from the landmarks and then solved with the coefficients (a
        small rotation and translation in the same least squares), so that the landmarks'
        definitions do not bias the fit and a face of the model is recovered.
    skin : (V,) bool, the model vertices that may meet the scan; default :func:`outer_skin`
        (teeth behind the lips would pull them inwards)
    name : the scan, as error messages name it (e.g. its path)

    Examples
    --------
    >>> from morphable import load_model
    >>> sfm = load_model("sfm")
    >>> face = sfm.vertices(np.r_[1.5, -1.0, np.zeros(61)])     # the "scan": a face of the model
    >>> landmarks = np.where(sfm.landmark_ids[:, None] >= 0, face[sfm.landmark_ids], np.nan)
    >>> alpha, beta = fit_surface(sfm, face, sfm.triangles, landmarks, pose="joint")
    >>> [round(float(a), 1) for a in alpha[:3]]
    [1.4, -1.0, 0.0]
    """
    from scipy.optimize import lsq_linear
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    from ..normals import vertex_normals

    if pose not in ("landmarks", "joint"):
        raise InputError(f"pose: expected 'landmarks' or 'joint', got {pose!r}")
    landmarks = _scan_landmarks(landmarks, name)
    ids = np.asarray(model.landmark_ids)
    ok = (ids >= 0) & np.isfinite(landmarks).all(1)
    if ok.sum() < 4:
        raise InputError(f"{name}: fewer than 4 landmarks shared with model {model.name}")
    joint = pose == "joint"
    K, E = model.n_identity, model.n_expression if expression else 0
    basis = np.concatenate([model.identity_basis, model.expression_basis[:E]]).astype(np.float64)
    mean = np.asarray(model.mean, dtype=np.float64)
    normals = vertex_normals(vertices, triangles, weighting="angle")
    # the rotation and translation (joint pose) go unregularised, before the coefficients
    P = 6 if joint else 0
    bounded = bool(E) and model.expression_kind == "blendshapes"
    lower, upper = np.full(P + K + E, -np.inf), np.full(P + K + E, np.inf)
    if bounded:
        lower[P + K:], upper[P + K:] = 0.0, 1.0
    ridge = np.sqrt(prior_weight) * np.eye(P + K + E)[P:]
    coeffs = np.zeros(K + E)
    skin = np.flatnonzero(outer_skin(model) if skin is None else skin)
    to_model = align_landmarks(landmarks[ok], mean[ids[ok]], scale=False)
    for _ in range(n_iterations):
        v = model.vertices(identity=coeffs[:K], expression=coeffs[K:] if E else None)
        if not joint:
            to_model = align_landmarks(landmarks[ok], v[ids[ok]])
        S, Sn = to_model.apply(vertices), normals @ to_model.rotation.T
        sel = skin[np.linalg.norm(v[skin] - v[ids[NOSE_TIP]], axis=1) < radius_mm]
        d, j = cKDTree(S).query(v[sel])
        sel, j = sel[d < max_distance_mm], j[d < max_distance_mm]
        rows = np.einsum("vi,kvi->vk", Sn[j], basis[:, sel])
        rhs = np.einsum("vi,vi->v", Sn[j], S[j] - mean[sel])
        if joint:   # the face turned by w and moved by t: n . (w x v + t) = w . (v x n) + n . t
            rows = np.concatenate([np.cross(v[sel], Sn[j]), Sn[j], rows], 1)
        if bounded:
            sol = lsq_linear(np.vstack([rows, ridge]), np.r_[rhs, np.zeros(len(ridge))],
                             bounds=(lower, upper)).x
        else:
            sol = np.linalg.solve(rows.T @ rows + ridge.T @ ridge, rows.T @ rhs)
        coeffs = sol[P:]
        if joint:   # moving the face by (w, t) is moving the scan by its inverse
            step = Similarity(1.0, Rotation.from_rotvec(sol[:3]).as_matrix(), sol[3:6])
            to_model = step.inverse() @ to_model
    return coeffs[:K], np.r_[coeffs[K:], np.zeros(model.n_expression - E)]


def fit_landmarks_3d(model, landmarks, *, n_iterations: int = 10, prior_weight: float = 1.0,
                     expression_weight: float = 1.0, definition_std_mm=None,
                     name: str = "scan"):
    """Coefficients fitting ``model`` to a scan's own 3D landmarks -> identity (K,),
    expression (E,).

    What the landmarks say about the face's shape under this model, without images: where a
    landmark fit goes with ever more noise-free views (when its definition offsets are
    right). Only the landmarks a landmark fit has fixed vertices for are used (not the sliding
    jaw points); each of ``n_iterations`` rounds moves the scan's landmarks onto the current
    face's landmark vertices by a similarity (a landmark fit cannot tell a face's size from its
    distance either) and solves, by least squares, the landmark positions weighted by ``1 /
    definition_std_mm^2`` with the landmark fit's priors: ``prior_weight |alpha|^2`` and
    ``expression_weight * expression_precision(model) |beta|^2``, blendshape weights in
    [0, 1].

    Parameters
    ----------
    landmarks : (68, 3) mm, the scan's iBUG landmarks in any frame, NaN where missing
    definition_std_mm : (68,) mm per coordinate, default the landmark fit's
        :data:`~morphable.fitting.noise.DEFINITION_STD_MM`
    name : the scan, as error messages name it (e.g. its path)

    Examples
    --------
    >>> from morphable import load_model
    >>> sfm = load_model("sfm")
    >>> face = sfm.vertices(np.r_[1.5, -1.0, np.zeros(61)])
    >>> landmarks = np.where(sfm.landmark_ids[:, None] >= 0, face[sfm.landmark_ids], np.nan)
    >>> alpha, beta = fit_landmarks_3d(sfm, landmarks)
    >>> [round(float(a), 1) for a in alpha[:3]]
    [1.4, -0.8, 0.1]
    """
    from scipy.optimize import lsq_linear

    from .correspondences import landmark_bank
    from .noise import DEFINITION_STD_MM, expression_precision

    landmarks = _scan_landmarks(landmarks, name)
    sd = DEFINITION_STD_MM if definition_std_mm is None else np.asarray(definition_std_mm, float)
    ok = (landmark_bank(model).fixed_row >= 0) & np.isfinite(landmarks).all(1) & (sd > 0)
    if ok.sum() < 4:
        raise InputError(f"{name}: fewer than 4 landmarks shared with model {model.name}")
    ids = np.asarray(model.landmark_ids)[ok]
    K, E = model.n_identity, model.n_expression
    mean = np.asarray(model.mean, dtype=np.float64)[ids]
    # (3L, K + E): the landmark coordinates per unit coefficient
    basis = np.concatenate([model.identity_basis, model.expression_basis])[:, ids]
    basis = basis.astype(np.float64).reshape(K + E, -1).T
    w = np.repeat(1.0 / sd[ok], 3)
    prior = np.r_[np.full(K, prior_weight),
                  np.full(E, expression_weight * expression_precision(model))]
    A = np.vstack([w[:, None] * basis, np.diag(np.sqrt(prior))])
    bounded = bool(E) and model.expression_kind == "blendshapes"
    bounds = (np.r_[np.full(K, -np.inf), np.zeros(E)], np.r_[np.full(K, np.inf), np.ones(E)])
    coeffs = np.zeros(K + E)
    for _ in range(n_iterations):
        face = mean + (basis @ coeffs).reshape(-1, 3)
        target = align_landmarks(landmarks[ok], face).apply(landmarks[ok])
        b = np.r_[w * (target - mean).ravel(), np.zeros(K + E)]
        coeffs = (lsq_linear(A, b, bounds=bounds).x if bounded
                  else np.linalg.lstsq(A, b, rcond=None)[0])
    return coeffs[:K], coeffs[K:]
