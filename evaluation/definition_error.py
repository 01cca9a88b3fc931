"""How far a scan's landmark annotations lie from a model's landmark vertices, per group.

A model's landmark vertex (e.g. the SFM's eyebrow points) and an annotation of the same
iBUG landmark on a face are two definitions of one point: they differ by a few millimetres,
the same way in every photo of that face. The landmark fit models this as a per-landmark 3D
offset (``definition_std_mm`` of :func:`morphable.fitting.fit_landmarks`); this script
measures its size. For each scan, the model's identity is fitted to the scan *surface*
(point-to-plane, so the landmarks play no part beyond the first alignment), the scan's
landmarks are moved rigidly onto the fitted face's landmark vertices, and what remains is
the definition difference. The table gives, per landmark group, its RMS per coordinate (x
right, y up, z out of the face) and over the coordinates (the 3D RMS / sqrt 3): the latter,
rounded, is the fitter's default profile ``DEFINITION_STD_MM``.

Commands::

    python -m evaluation.definition_error --synthetic-scan ict --n-scans 6
    python -m evaluation.definition_error --scan SCAN.obj --scan-landmarks SCAN.ljson

The default profile was measured on ICT FaceKit subjects (seeds 100-105), which are not the
held-out scan. :func:`fit_landmarks_3d` fits the model to a scan's own 3D landmarks with that
profile as their error: what the landmarks say about the face's shape without images
(``python -m evaluation.florence ... --methods landmarks-3d``).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors
from morphable.ibug68 import DEFINITION_GROUPS

__all__ = ["fit_surface", "fit_landmarks_3d", "definition_offsets", "group_rms", "main"]


def fit_surface(model, scan, iterations: int = 8, prior_weight: float = 1.0,
                max_distance_mm: float = 10.0, radius_mm: float = 95.0, expression: bool = False,
                pose: str = "landmarks"):
    """Coefficients fitting ``model`` to the scan surface -> identity (K,), expression (E,).

    Each round pairs every outer-skin vertex of the model (:func:`evaluation.scans.outer_skin`)
    within ``radius_mm`` of the nose tip with its nearest scan vertex (closer than
    ``max_distance_mm``) and solves the point-to-plane equations
    ``n . (mean + A alpha + B beta - p) = 0`` (the scan moved into the model's frame) by
    least squares with ``prior_weight (|alpha|^2 + |beta|^2)`` (mm^2 units).

    Parameters
    ----------
    expression : also fit the expression coefficients (blendshape weights kept in [0, 1]);
        False leaves them 0
    pose : how the scan is placed in the model's frame. ``"landmarks"``: the similarity from
        its landmarks to the current face's landmark vertices, every round (the face's size is
        then the similarity's; the definition profile was measured this way). ``"joint"``: a
        rigid transform, started from the landmarks and then solved with the coefficients (a
        small rotation and translation in the same least squares), so that the landmarks'
        definitions do not bias the fit and a face of the model is recovered.

    Examples
    --------
    >>> sfm = load_model("sfm")  # doctest: +SKIP
    >>> alpha, beta = fit_surface(sfm, scan, expression=True, pose="joint")  # doctest: +SKIP
    """
    from scipy.optimize import lsq_linear
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    from morphable.metrics import Similarity, align_landmarks
    from morphable.normals import vertex_normals

    from .scans import outer_skin

    if pose not in ("landmarks", "joint"):
        raise InputError(f"pose: expected 'landmarks' or 'joint', got {pose!r}")
    ids = np.asarray(model.landmark_ids)
    ok = (ids >= 0) & np.isfinite(scan.landmarks).all(1)
    if ok.sum() < 4:
        raise InputError(f"{scan.source}: fewer than 4 landmarks shared with model {model.name}")
    joint = pose == "joint"
    K, E = model.n_identity, model.n_expression if expression else 0
    basis = np.concatenate([model.identity_basis, model.expression_basis[:E]]).astype(np.float64)
    mean = np.asarray(model.mean, dtype=np.float64)
    normals = vertex_normals(scan.vertices, scan.triangles, weighting="angle")
    # the rotation and translation (joint pose) go unregularised, before the coefficients
    P = 6 if joint else 0
    bounded = bool(E) and model.expression_kind == "blendshapes"
    lower, upper = np.full(P + K + E, -np.inf), np.full(P + K + E, np.inf)
    if bounded:
        lower[P + K:], upper[P + K:] = 0.0, 1.0
    ridge = np.sqrt(prior_weight) * np.eye(P + K + E)[P:]
    coeffs = np.zeros(K + E)
    # only the outer skin can meet the scan: teeth behind the lips would pull them inwards
    skin = np.flatnonzero(outer_skin(model))
    to_model = align_landmarks(scan.landmarks[ok], mean[ids[ok]], scale=False)
    for _ in range(iterations):
        v = model.vertices(identity=coeffs[:K], expression=coeffs[K:] if E else None)
        if not joint:
            to_model = align_landmarks(scan.landmarks[ok], v[ids[ok]])
        S, Sn = to_model.apply(scan.vertices), normals @ to_model.rotation.T
        sel = skin[np.linalg.norm(v[skin] - v[ids[30]], axis=1) < radius_mm]
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


def fit_landmarks_3d(model, scan, iterations: int = 10, prior_weight: float = 1.0,
                     expression_weight: float = 1.0, definition_std_mm=None):
    """Coefficients fitting ``model`` to the scan's own 3D landmarks -> identity (K,),
    expression (E,).

    What the landmarks say about the face's shape under this model, without images: where a
    landmark fit goes with ever more noise-free views (when its definition offsets are
    right). Only the landmarks a landmark fit has fixed vertices for are used (not the sliding
    jaw points); each round moves the scan's landmarks onto the current face's landmark
    vertices by a similarity (a landmark fit cannot tell a face's size from its distance
    either) and solves, by least squares, the landmark positions weighted by ``1 /
    definition_std_mm^2`` with the landmark fit's priors: ``prior_weight |alpha|^2`` and
    ``expression_weight * expression_precision(model) |beta|^2``, blendshape weights in
    [0, 1].

    Parameters
    ----------
    definition_std_mm : (68,) mm per coordinate, default the landmark fit's
        :data:`~morphable.fitting.noise.DEFINITION_STD_MM`

    Examples
    --------
    >>> alpha, beta = fit_landmarks_3d(load_model("sfm"), scan)  # doctest: +SKIP
    """
    from scipy.optimize import lsq_linear

    from morphable.fitting.correspondences import landmark_bank
    from morphable.fitting.noise import DEFINITION_STD_MM, expression_precision
    from morphable.metrics import align_landmarks

    sd = DEFINITION_STD_MM if definition_std_mm is None else np.asarray(definition_std_mm, float)
    ok = (landmark_bank(model).fixed_row >= 0) & np.isfinite(scan.landmarks).all(1) & (sd > 0)
    if ok.sum() < 4:
        raise InputError(f"{scan.source}: fewer than 4 landmarks shared with model {model.name}")
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
    for _ in range(iterations):
        face = mean + (basis @ coeffs).reshape(-1, 3)
        target = align_landmarks(scan.landmarks[ok], face).apply(scan.landmarks[ok])
        b = np.r_[w * (target - mean).ravel(), np.zeros(K + E)]
        coeffs = (lsq_linear(A, b, bounds=bounds).x if bounded
                  else np.linalg.lstsq(A, b, rcond=None)[0])
    return coeffs[:K], coeffs[K:]


def definition_offsets(model, scan, **fit_kw) -> np.ndarray:
    """(68, 3) mm: scan landmark minus the fitted face's landmark vertex, after moving the scan
    landmarks rigidly onto those vertices (model axes); NaN where either is missing."""
    from morphable.metrics import align_landmarks

    alpha, _ = fit_surface(model, scan, **fit_kw)
    ids = np.asarray(model.landmark_ids)
    ok = (ids >= 0) & np.isfinite(scan.landmarks).all(1)
    v = model.vertices(identity=alpha)
    T = align_landmarks(scan.landmarks[ok], v[ids[ok]], scale=False)
    out = np.full((68, 3), np.nan)
    out[ok] = T.apply(scan.landmarks[ok]) - v[ids[ok]]
    return out


def group_rms(offsets) -> dict:
    """``{group: {"xyz_mm": [x, y, z], "per_coordinate_mm": r, "n": n}}`` over the stacked
    (S, 68, 3) or (68, 3) offsets; groups without values are left out."""
    d = np.asarray(offsets, dtype=np.float64).reshape(-1, 68, 3)
    out = {}
    for name, ids in DEFINITION_GROUPS.items():
        g = d[:, ids].reshape(-1, 3)
        g = g[np.isfinite(g).all(1)]
        if len(g):
            out[name] = {"xyz_mm": np.sqrt((g ** 2).mean(0)).round(2).tolist(),
                         "per_coordinate_mm": round(float(np.sqrt((g ** 2).mean())), 2),
                         "n": int(len(g))}
    return out


def _parser():
    p = argparse.ArgumentParser(prog="python -m evaluation.definition_error",
                                description=__doc__.split("\n")[0])
    p.add_argument("--scan", help="scan mesh (OBJ, PLY, STL...)")
    p.add_argument("--scan-landmarks", help="its 68 or 51 3D landmarks")
    p.add_argument("--scan-units", default="auto")
    p.add_argument("--synthetic-scan", metavar="MODEL",
                   help="instead of --scan: subjects sampled from this model (e.g. ict)")
    p.add_argument("--n-scans", type=int, default=6)
    p.add_argument("--scan-seed", type=int, default=100, help="seed of the first subject")
    p.add_argument("--model", default="sfm", help="the model whose landmark vertices are compared")
    p.add_argument("--report", help="JSON to write")
    return p


@one_line_errors("evaluation.definition_error")
def main(argv=None) -> int:
    from morphable import load_model

    from .scans import load_scan, model_scan

    args = _parser().parse_args(argv)
    if (args.synthetic_scan is None) == (args.scan is None):
        raise InputError("give either --scan with --scan-landmarks, or --synthetic-scan")
    if args.scan is not None and args.scan_landmarks is None:
        raise InputError(f"--scan {args.scan}: --scan-landmarks is required")
    if args.report and not Path(args.report).resolve().parent.is_dir():
        raise InputError(f"{args.report}: output folder does not exist")
    if args.n_scans < 1:
        raise InputError(f"--n-scans: need at least 1, got {args.n_scans}")
    model = load_model(args.model)
    if args.synthetic_scan:
        source = load_model(args.synthetic_scan)
        scans = [model_scan(source, args.scan_seed + i) for i in range(args.n_scans)]
    else:
        scans = [load_scan(args.scan, args.scan_landmarks, args.scan_units)]
    offsets = np.stack([definition_offsets(model, s) for s in scans])
    table = group_rms(offsets)
    print(f"{'group':<11s} {'x':>6s} {'y':>6s} {'z':>6s} {'per coord':>10s}  (mm, RMS over "
          f"{len(scans)} scan{'s' * (len(scans) > 1)})")
    for name, row in table.items():
        x, y, z = row["xyz_mm"]
        print(f"{name:<11s} {x:6.2f} {y:6.2f} {z:6.2f} {row['per_coordinate_mm']:10.2f}")
    if args.report:
        from morphable.io.atomic import atomic_path

        with atomic_path(Path(args.report)) as tmp:
            tmp.write_text(json.dumps({"model": model.name, "scans": [s.source for s in scans],
                                       "groups": table, "command": "python -m evaluation.definition_error "
                                       + " ".join(sys.argv[1:] if argv is None else argv)}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
