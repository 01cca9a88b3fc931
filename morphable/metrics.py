"""Compare a reconstructed face mesh with a ground-truth scan, as in the Florence protocol.

The steps are usable alone:

1. :func:`align_landmarks` — similarity (or rigid) transform from corresponding 3D landmarks
   (:func:`umeyama`, which serves 2D points too);
2. :func:`crop_sphere` / :func:`crop_mesh` — keep what lies within 95 mm of the nose tip;
3. :func:`icp_refine` — open3d ICP, point-to-plane (rigid), optionally preceded by a
   point-to-point ICP with scale;
4. :func:`point_to_plane`, :func:`point_to_surface` — per-point errors in mm.

:func:`compare_to_scan` chains them and returns a :class:`Comparison` holding per-vertex
errors (for heat maps) and their summary. Everything is in millimetres; open3d, scipy and
libigl are imported inside the functions that use them.

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> a = rng.normal(size=(10, 3))
>>> T = Similarity(scale=2.0, rotation=np.eye(3), translation=[1.0, 0.0, 0.0])
>>> S = align_landmarks(a, T.apply(a))
>>> round(S.scale, 6), np.allclose(S.translation, [1, 0, 0])
(2.0, True)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import FitError, InputError
from .logs import import_open3d

__all__ = ["Similarity", "umeyama", "align_landmarks", "crop_sphere", "crop_mesh", "submesh",
           "icp_refine", "point_to_plane", "point_to_surface", "compare_to_scan", "Comparison",
           "NOSE_TIP", "CROP_RADIUS_MM"]

NOSE_TIP = 30
"""0-based iBUG index of the nose tip (iBUG point 31), the centre of the Florence crop."""
CROP_RADIUS_MM = 95.0
"""Radius of the usual Florence crop around the nose tip, mm."""


def _points(x, what: str, allow_nan: bool = False) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"{what}: expected (N, 3) points, got shape {a.shape}")
    if np.isinf(a).any() or (not allow_nan and np.isnan(a).any()):
        raise InputError(f"{what}: points contain NaN or inf")
    return a


def _triangles(f, n_vertices: int, what: str) -> np.ndarray:
    t = np.asarray(f, dtype=np.int64)
    if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise InputError(f"{what}: expected a non-empty (F, 3) triangle array, got shape {t.shape}")
    if t.min() < 0 or t.max() >= n_vertices:
        raise InputError(f"{what}: triangle ids out of range [0, {n_vertices})")
    return t


@dataclass
class Similarity:
    """``x -> scale * rotation @ x + translation`` (mm in, mm out).

    Attributes
    ----------
    scale : float (1 for a rigid transform)
    rotation : (3, 3) float, a proper rotation
    translation : (3,) float, mm
    """

    scale: float = 1.0
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        self.scale = float(self.scale)
        self.rotation = np.asarray(self.rotation, dtype=np.float64).reshape(3, 3)
        self.translation = np.asarray(self.translation, dtype=np.float64).reshape(3)
        if not (np.isfinite(self.scale) and self.scale > 0 and np.isfinite(self.rotation).all()
                and np.isfinite(self.translation).all()):
            raise FitError("similarity transform is degenerate (non-finite or non-positive scale)")

    def apply(self, points) -> np.ndarray:
        """(..., N, 3) mm -> (..., N, 3) mm."""
        return self.scale * (np.asarray(points, dtype=np.float64) @ self.rotation.T) + self.translation

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = self.translation
        return m

    @classmethod
    def from_matrix(cls, m) -> "Similarity":
        """From a (4, 4) similarity matrix (uniform scale, no reflection)."""
        m = np.asarray(m, dtype=np.float64)
        s = np.cbrt(np.linalg.det(m[:3, :3]))
        if not np.isfinite(s) or s <= 0:
            raise FitError("transform matrix is singular or reflects")
        return cls(scale=s, rotation=m[:3, :3] / s, translation=m[:3, 3])

    def __matmul__(self, other: "Similarity") -> "Similarity":
        """``(self @ other).apply(x) == self.apply(other.apply(x))``."""
        return Similarity.from_matrix(self.matrix @ other.matrix)

    def inverse(self) -> "Similarity":
        Rt = self.rotation.T
        return Similarity(1.0 / self.scale, Rt, -(Rt @ self.translation) / self.scale)

    def to_dict(self) -> dict:
        from .camera import matrix_to_euler

        yaw, pitch, roll = (float(a) for a in matrix_to_euler(self.rotation))
        return {"scale": self.scale, "yaw_deg": yaw, "pitch_deg": pitch, "roll_deg": roll,
                "translation_mm": self.translation.tolist()}


def _o3d_cloud(points, normals=None):
    o3d = import_open3d()

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals))
    return pc


def umeyama(source, target, scale: bool = True):
    """Least-squares similarity (Umeyama) mapping points ``source`` onto ``target``, in 2D or 3D.

    Parameters
    ----------
    source, target : (N, D) array-like, D = 2 or 3, any unit (mm, px); rows with NaN in
        either are ignored
    scale : bool
        False fits a rigid transform (scale 1).

    Returns
    -------
    scale : float; rotation : (D, D), a proper rotation; translation : (D,) in the points'
    unit, with ``target ~ scale * source @ rotation.T + translation``.

    Raises
    ------
    FitError when fewer than D usable pairs remain, or they leave the rotation free (3D:
    collinear; 2D: coincident). The messages speak of landmarks: what all callers but a
    benchmark align.

    Examples
    --------
    >>> src = np.array([[0., 0], [1, 0], [0, 1]])
    >>> s, R, t = umeyama(src, 2 * src + 5)
    >>> round(s, 6), R.round(6) + 0.0, t.round(6)   # + 0.0 turns -0. into 0.
    (2.0, array([[1., 0.],
           [0., 1.]]), array([5., 5.]))
    """
    src, dst = np.asarray(source, dtype=np.float64), np.asarray(target, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] not in (2, 3) or src.shape != dst.shape:
        raise InputError(f"landmark alignment: expected two (N, 2) or (N, 3) point arrays of one "
                         f"shape, got {src.shape} and {dst.shape}")
    D = src.shape[1]
    ok = np.isfinite(src).all(1) & np.isfinite(dst).all(1)
    s, d = src[ok], dst[ok]
    if len(s) < D:
        raise FitError(f"landmark alignment needs {D} corresponding points, got {len(s)}")
    ms, md = s.mean(0), d.mean(0)
    s0, d0 = s - ms, d - md
    # points that span fewer than D - 1 directions leave a rotation free: refuse rather than guess
    for pts, what in ((s0, "source"), (d0, "target")):
        sv = np.linalg.svd(pts, compute_uv=False)
        if sv[0] <= 0 or sv[D - 2] < 1e-9 * max(sv[0], 1e-300):
            raise FitError(f"landmark alignment: the {what} landmarks are "
                           f"{'collinear or coincident' if D == 3 else 'coincident'}")
    U, S, Vt = np.linalg.svd(d0.T @ s0 / len(s))
    sign = np.diag([1.0] * (D - 1) + [np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ sign @ Vt
    c = np.trace(np.diag(S) @ sign) / ((s0 ** 2).sum() / len(s)) if scale else 1.0
    return float(c), R, md - c * R @ ms


def align_landmarks(source, target, scale: bool = True) -> Similarity:
    """Least-squares similarity (:func:`umeyama`) mapping ``source`` landmarks onto ``target``.

    Parameters
    ----------
    source, target : (N, 3) array-like, mm; rows with NaN in either are ignored
    scale : bool
        False fits a rigid transform (scale 1).

    Returns
    -------
    Similarity with ``target ~ T.apply(source)``.

    Raises
    ------
    FitError when fewer than 3 usable, non-collinear pairs remain.
    """
    src = _points(source, "source landmarks", allow_nan=True)
    dst = _points(target, "target landmarks", allow_nan=True)
    if src.shape != dst.shape:
        raise InputError(f"landmarks: source has {len(src)} points, target has {len(dst)}")
    return Similarity(*umeyama(src, dst, scale))


def crop_sphere(points, center, radius: float = CROP_RADIUS_MM) -> np.ndarray:
    """(N,) bool: which points lie within ``radius`` mm of ``center`` (3,)."""
    p = _points(points, "points")
    c = np.asarray(center, dtype=np.float64).reshape(3)
    if not np.isfinite(c).all():
        raise InputError("crop centre is NaN or inf (is the nose-tip landmark missing?)")
    return ((p - c) ** 2).sum(1) <= float(radius) ** 2


def crop_mesh(vertices, triangles, center, radius: float = CROP_RADIUS_MM):
    """Keep the triangles whose three vertices lie within ``radius`` mm of ``center``.

    Returns
    -------
    vertices : (n, 3) float64, mm — only vertices used by a kept triangle
    triangles : (m, 3) int64 into the returned vertices
    ids : (n,) int64 — index of each returned vertex in the input
    """
    v = _points(vertices, "mesh vertices")
    f = _triangles(triangles, len(v), "mesh")
    ids, f = submesh(f, crop_sphere(v, center, radius))
    return v[ids], f, ids


def submesh(triangles, keep):
    """The triangles whose three vertices are all kept, on the vertices they use.

    Parameters
    ----------
    triangles : (F, 3) int
    keep : (V,) bool, the vertices that may stay

    Returns
    -------
    ids : (n,) int64 — the vertices used by a kept triangle (indices into the input)
    triangles : (m, 3) int64 into ``ids``
    """
    f = triangles[keep[triangles].all(1)]
    ids = np.unique(f)
    remap = np.full(len(keep), -1, dtype=np.int64)
    remap[ids] = np.arange(len(ids))
    return ids, remap[f]


def point_to_plane(points, surface_points, surface_normals) -> np.ndarray:
    """Distance from each point to the tangent plane of its nearest surface point.

    Parameters
    ----------
    points : (N, 3) mm
    surface_points : (M, 3) mm, e.g. the scan's vertices
    surface_normals : (M, 3) unit normals of ``surface_points``; a zero normal falls back
        to the point-to-point distance

    Returns
    -------
    (N,) float64, mm, non-negative.
    """
    from scipy.spatial import cKDTree

    p = _points(points, "points")
    q = _points(surface_points, "surface points")
    n = _points(surface_normals, "surface normals")
    if len(q) == 0 or n.shape != q.shape:
        raise InputError(f"surface: need (M, 3) points and normals, got {q.shape} and {n.shape}")
    dist, idx = cKDTree(q).query(p)
    d = p - q[idx]
    nn = n[idx]
    length = np.linalg.norm(nn, axis=1)
    plane = np.abs((d * nn).sum(1)) / np.where(length > 0, length, 1.0)
    return np.where(length > 0, plane, dist)


def point_to_surface(points, vertices, triangles) -> np.ndarray:
    """(N,) distance in mm from each point to the closest point of the triangle mesh
    (libigl ``point_mesh_squared_distance``)."""
    import igl

    p = _points(points, "points")
    v = _points(vertices, "mesh vertices")
    f = _triangles(triangles, len(v), "mesh")
    sq, _, _ = igl.point_mesh_squared_distance(p, v, f)
    return np.sqrt(np.maximum(sq, 0.0))


def icp_refine(source, target, target_normals, max_distance: float = 10.0, scale: bool = False,
               max_iterations: int = 50):
    """Refine the alignment of ``source`` points onto a ``target`` surface with open3d ICP.

    Parameters
    ----------
    source : (N, 3) mm, e.g. the cropped reconstruction, already roughly aligned
    target, target_normals : (M, 3) mm and unit normals, e.g. the cropped scan
    max_distance : float, mm — pairs farther apart are ignored
    scale : bool
        True runs a point-to-point ICP with scale (open3d's point-to-plane is rigid only)
        before the rigid point-to-plane ICP.
    max_iterations : int, per ICP run

    Returns
    -------
    transform : Similarity mapping ``source`` onto ``target``
    info : dict — ``method``, ``fitness`` (fraction of source points paired), ``rmse_mm``
    """
    o3d = import_open3d()

    reg = o3d.pipelines.registration
    src = _o3d_cloud(_points(source, "ICP source"))
    dst = _o3d_cloud(_points(target, "ICP target"), _points(target_normals, "ICP target normals"))
    crit = reg.ICPConvergenceCriteria(max_iteration=int(max_iterations))
    init = np.eye(4)
    method = "point-to-plane ICP (rigid)"
    if scale:
        res = reg.registration_icp(src, dst, max_distance, init,
                                   reg.TransformationEstimationPointToPoint(with_scaling=True), crit)
        init = res.transformation
        method = "point-to-point ICP with scale, then " + method
    res = reg.registration_icp(src, dst, max_distance, init,
                               reg.TransformationEstimationPointToPlane(), crit)
    if res.fitness == 0:
        raise FitError(f"ICP found no point pairs closer than {max_distance} mm; the initial "
                       f"alignment is too far off")
    T = Similarity.from_matrix(res.transformation)
    return T, {"method": method, "fitness": float(res.fitness), "rmse_mm": float(res.inlier_rmse)}


def _stats(e: np.ndarray) -> dict:
    return {"mean_mm": float(e.mean()), "std_mm": float(e.std()), "median_mm": float(np.median(e)),
            "n": int(e.size)}


@dataclass
class Comparison:
    """The outcome of :func:`compare_to_scan`.

    Attributes
    ----------
    vertex_ids : (n,) int — reconstructed vertices inside the crop (the evaluated ones)
    point_to_plane_mm : (n,) — distance to the scan's tangent plane at the nearest scan point
    point_to_surface_mm : (n,) — distance to the scan's surface (libigl)
    scan_ids : (m,) int — scan vertices inside the crop whose closest reconstruction point
        is not on the reconstruction's border (farther points measure coverage, not shape)
    scan_to_recon_mm : (m,) — distance from those scan vertices to the reconstruction surface
    aligned_vertices : (V, 3) mm — the whole reconstruction in the scan's frame
    transform : Similarity — reconstruction -> scan
    alignment : dict — how the transform was found (landmarks, ICP method, fitness)
    """

    vertex_ids: np.ndarray
    point_to_plane_mm: np.ndarray
    point_to_surface_mm: np.ndarray
    scan_ids: np.ndarray
    scan_to_recon_mm: np.ndarray
    aligned_vertices: np.ndarray
    transform: Similarity
    alignment: dict

    def per_vertex(self, metric: str = "point_to_plane", n_vertices: int | None = None) -> np.ndarray:
        """(V,) errors in mm over all reconstructed vertices, NaN outside the crop (heat maps)."""
        V = n_vertices or len(self.aligned_vertices)
        out = np.full(V, np.nan)
        out[self.vertex_ids] = getattr(self, f"{metric}_mm")
        return out

    def summary(self) -> dict:
        """Mean, std, median (mm) of each metric; ``symmetric`` averages the two directions."""
        p2p = _stats(self.point_to_plane_mm)
        s2r = _stats(self.scan_to_recon_mm)
        return {"point_to_plane": p2p, "point_to_surface": _stats(self.point_to_surface_mm),
                "scan_to_recon": s2r,
                "symmetric": {"mean_mm": 0.5 * (float(self.point_to_surface_mm.mean())
                                                + s2r["mean_mm"])}}


def compare_to_scan(vertices, triangles, scan_vertices, scan_triangles, landmarks=None,
                    scan_landmarks=None, radius: float = CROP_RADIUS_MM, landmark_scale: bool = True,
                    icp: bool = True, icp_scale: bool = False, icp_max_distance: float = 10.0,
                    nose_tip=None, scan_nose_tip=None) -> Comparison:
    """Align a reconstruction to a scan and measure it on the face region (Florence protocol).

    Parameters
    ----------
    vertices : (V, 3) mm, the reconstruction; triangles : (F, 3) int
    scan_vertices : (S, 3) mm; scan_triangles : (G, 3) int — holes, non-manifold edges and
        unreferenced vertices are fine
    landmarks, scan_landmarks : (68, 3) mm in iBUG order, NaN rows for missing points, or None
        (then the two meshes must already be roughly aligned: ICP only)
    radius : crop radius around the nose tip, mm
    landmark_scale : fit a similarity (True) or a rigid transform to the landmarks
    icp, icp_scale, icp_max_distance : see :func:`icp_refine`
    nose_tip, scan_nose_tip : (3,) mm crop centres; default landmark 30 (iBUG 31)

    Returns
    -------
    Comparison (errors per evaluated vertex, transform, alignment description).

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(4, radius=50.0)
    >>> c = compare_to_scan(s.vertices * 1.02, s.faces, s.vertices, s.faces,
    ...                     nose_tip=[0, 0, 50], scan_nose_tip=[0, 0, 50], icp=False)
    >>> round(c.summary()["point_to_plane"]["mean_mm"], 2)
    1.0
    """
    v = _points(vertices, "reconstruction vertices")
    f = _triangles(triangles, len(v), "reconstruction")
    sv = _points(scan_vertices, "scan vertices")
    sf = _triangles(scan_triangles, len(sv), "scan")
    alignment = {}
    T = Similarity()
    if landmarks is not None and scan_landmarks is not None:
        lm = _points(landmarks, "reconstruction landmarks", allow_nan=True)
        slm = _points(scan_landmarks, "scan landmarks", allow_nan=True)
        T = align_landmarks(lm, slm, scale=landmark_scale)
        used = np.isfinite(lm).all(1) & np.isfinite(slm).all(1)
        rmse = float(np.sqrt(((T.apply(lm[used]) - slm[used]) ** 2).sum(1).mean()))
        alignment["landmarks"] = {"method": "similarity (Umeyama)" if landmark_scale else "rigid",
                                  "n": int(used.sum()), "rmse_mm": rmse}
        if nose_tip is None:
            nose_tip = lm[NOSE_TIP]
        if scan_nose_tip is None:
            scan_nose_tip = slm[NOSE_TIP]
    if nose_tip is None or scan_nose_tip is None:
        raise InputError("compare_to_scan: give both landmark sets or both nose tips (crop centres)")
    nose = T.apply(np.asarray(nose_tip, dtype=np.float64).reshape(1, 3))[0]
    snose = np.asarray(scan_nose_tip, dtype=np.float64).reshape(3)

    from .normals import vertex_normals

    scan_v, scan_f, scan_ids = crop_mesh(sv, sf, snose, radius)
    if len(scan_f) == 0:
        raise FitError(f"no scan triangle lies within {radius} mm of the scan's nose tip "
                       f"{np.round(snose, 1).tolist()} (wrong units or landmarks?)")
    scan_n = vertex_normals(scan_v, scan_f)
    av = T.apply(v)
    inside = crop_sphere(av, nose, radius)
    if not inside.any():
        raise FitError(f"no reconstructed vertex lies within {radius} mm of its nose tip")
    if icp:
        R, info = icp_refine(av[inside], scan_v, scan_n, max_distance=icp_max_distance, scale=icp_scale)
        T = R @ T
        av = R.apply(av)
        nose = R.apply(nose[None])[0]
        inside = crop_sphere(av, nose, radius)
        alignment["icp"] = info
    else:
        alignment["icp"] = None
    alignment["transform"] = T.to_dict()
    ids = np.flatnonzero(inside)
    if ids.size == 0:
        raise FitError(f"no reconstructed vertex lies within {radius} mm of its nose tip after ICP")
    p2p = point_to_plane(av[ids], scan_v, scan_n)
    p2s = point_to_surface(av[ids], scan_v, scan_f)
    rv, rf, _ = crop_mesh(av, f, nose, radius)
    if len(rf) == 0:
        raise FitError(f"no reconstructed triangle lies within {radius} mm of its nose tip")
    s2r, on_border = _to_surface_off_border(scan_v, rv, rf)
    return Comparison(vertex_ids=ids, point_to_plane_mm=p2p, point_to_surface_mm=p2s,
                      scan_ids=scan_ids[~on_border], scan_to_recon_mm=s2r[~on_border],
                      aligned_vertices=av, transform=T, alignment=alignment)


def _to_surface_off_border(points, vertices, triangles, tol_mm: float = 1e-3):
    """Distances to a mesh and whether each closest point lies on the mesh's border.

    Scan points whose closest reconstruction point is on its border lie beyond what the
    reconstruction covers (a face model has no ears, a crop has an edge); their distance
    measures coverage, not shape, so the scan -> reconstruction error leaves them out.
    """
    import igl

    sq, _, closest = igl.point_mesh_squared_distance(points, vertices, triangles)
    edges = np.asarray(igl.boundary_facets(triangles)[0], dtype=np.int64)
    if len(edges) == 0:
        return np.sqrt(np.maximum(sq, 0.0)), np.zeros(len(points), dtype=bool)
    to_border, _, _ = igl.point_mesh_squared_distance(closest, vertices, edges)
    on_border = to_border < tol_mm ** 2
    if on_border.all():
        raise FitError("every scan point lies beyond the reconstruction's border (no overlap)")
    return np.sqrt(np.maximum(sq, 0.0)), on_border
