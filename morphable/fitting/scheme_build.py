"""Derive a model's ``facemesh478`` landmark scheme from mediapipe's canonical face mesh.

mediapipe's face-mesh detector gives 478 points in the order of the vertices of its canonical
face mesh (``face_model_with_iris.obj``: 468 mesh vertices, then 5 per iris; cm, x to the
subject's left, y up, z towards the viewer, like the models). The scheme says where each of these
points lies on a model's surface. It is derived, not placed by hand:

1. a similarity (Umeyama) takes the canonical mesh onto the model's mean, from the points both
   name: eye and mouth corners, nose tip, chin (the model's ``landmark_ids`` for iBUG 36, 39, 42,
   45, 30, 48, 54, 8, whichever exist) against the canonical vertices found for them by geometry
   (:func:`anchor_indices`);
2. a non-rigid registration (Amberg et al.'s optimal-step ICP,
   ``trimesh.registration.nricp_amberg``) bends the 468-vertex mesh onto the model's skin, the
   anchors held to their landmarks; the irises follow the displacement of their eye's lid points;
3. each of the 478 registered points is projected onto the model's surface (the skin; ICT's
   irises onto its eyeballs, SFM's, which has none, onto its eyelids) -> a triangle's vertex ids
   and barycentric weights.

The face oval (:data:`FACE_OVAL`) below the eyes slides along the model's outline in a fit, split
into the subject's right and left side by the sign of x, its lowest midline point the chin; the
forehead's oval points stay fixed. ``mirror`` comes from the canonical mesh's left-right
symmetry, ``ibug68`` from the nearest registered points to the model's iBUG-68 landmarks
(:func:`ibug68_counterparts`), ``definition_std_mm`` from :func:`definition_std`.

Command::

    python -m morphable.fitting.scheme_build --model sfm|ict|PATH [--out FILE]

writes ``morphable/data/facemesh478_<model>.npz`` for SFM and ICT (the committed sidecars), else
the file :func:`~morphable.fitting.schemes.scheme_path` looks for (beside the model's file).
"""
from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, one_line_errors
from ..io.registry import MODELS
from .schemes import DATA_DIR, LandmarkScheme, save_scheme, scheme_path

__all__ = ["CANONICAL_OBJ", "N_MESH", "IRISES", "FACE_OVAL", "ANCHOR_IBUG", "ANCHOR_MEDIAPIPE",
           "read_obj", "canonical_mesh", "anchor_indices", "closest_points", "similarity",
           "register", "project_to_surface", "mirror_indices", "outline_split",
           "ibug68_counterparts", "definition_std", "build_scheme", "Build", "main"]

CANONICAL_OBJ = Path("mediapipe") / "face_model_with_iris.obj"
"""mediapipe's canonical 478-point face mesh (Apache-2.0), looked for under each folder of the
model search path (:func:`morphable.io.registry.search_path`: ``$MORPHABLE_DATA``,
``../shared/data/models``, the user cache)."""

FACE_OVAL = np.array([
    10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377,
    152, 148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109])
"""mediapipe's 36 face-oval points as one closed loop from the forehead's top over the subject's
left, the chin and the right: the edges of ``mediapipe.python.solutions.face_mesh_connections.
FACEMESH_FACE_OVAL`` (mediapipe 0.10.14) chained. They are the canonical mesh's boundary."""

ANCHOR_IBUG = np.array([36, 39, 42, 45, 30, 48, 54, 8])
"""iBUG-68 points (0-based) whose canonical counterparts anchor the registration: eye corners,
nose tip, mouth corners, chin."""

ANCHOR_MEDIAPIPE = np.array([33, 133, 362, 263, 4, 61, 291, 152])
"""mediapipe's face-mesh numbers of the :data:`ANCHOR_IBUG` points (mediapipe's landmark map:
33/133 the right eye's outer/inner corner, 362/263 the left's inner/outer, 4 the nose tip, 61/291
the mouth corners, 152 the chin), checked by :func:`anchor_indices`."""

N_MESH = 468
IRISES = (np.arange(468, 473), np.arange(473, 478))
"""The two irises' points (centre first), the subject's right then left."""

_FIXED_STD_MM = 2.5
_OVAL_STD_MM = 2.0


def read_obj(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and triangles (f, 3), 0-based, of a triangle OBJ file."""
    V, F = [], []
    try:
        with open(path) as f:
            for line in f:
                if line.startswith("v "):
                    V.append([float(t) for t in line.split()[1:4]])
                elif line.startswith("f "):
                    F.append([int(t.split("/")[0]) - 1 for t in line.split()[1:4]])
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read OBJ ({e})") from None
    return np.array(V, dtype=np.float64), np.array(F, dtype=np.int64)


def canonical_mesh(path=None) -> tuple[np.ndarray, np.ndarray]:
    """mediapipe's canonical mesh: (478, 3) vertices (cm), (F, 3) triangles of the 468 mesh
    vertices (the iris triangles left out: the irises are registered with their eyes)."""
    from ..io.registry import search_path

    if path is None:
        found = [r / CANONICAL_OBJ for r in search_path() if (r / CANONICAL_OBJ).is_file()]
        if not found:
            raise InputError(f"{CANONICAL_OBJ}: mediapipe's canonical mesh not found in "
                             f"{', '.join(map(str, search_path()))}")
        path = found[0]
    V, F = read_obj(path)
    if V.shape != (478, 3):
        raise InputError(f"{path}: expected 478 vertices, got {len(V)}")
    return V, F[np.all(F < N_MESH, axis=1)]


def similarity(src, dst) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (Umeyama 1991) taking points ``src`` (n, 3) onto ``dst`` (n, 3):
    -> scale s, rotation R (3, 3), translation t (3,) with ``dst ~ s * src @ R.T + t``."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (a ** 2).sum(1).mean())
    return s, R, md - s * ms @ R.T


def _apply(sim, X) -> np.ndarray:
    s, R, t = sim
    return s * np.asarray(X) @ R.T + t


def anchor_indices(V, model) -> np.ndarray:
    """Canonical vertices of the :data:`ANCHOR_IBUG` points -> (8,) int, -1 where ``model`` has
    no landmark vertex for that point: :data:`ANCHOR_MEDIAPIPE`, checked against the canonical
    mesh's geometry (the nose tip its most forward vertex, the chin its lowest, the right eye's
    and mouth's corners at negative x, the left ones their mirror images)."""
    V = np.asarray(V)
    a = dict(zip(ANCHOR_IBUG.tolist(), ANCHOR_MEDIAPIPE.tolist()))
    checks = (int(np.argmax(V[:N_MESH, 2])) == a[30], int(np.argmin(V[:N_MESH, 1])) == a[8],
              all(V[a[k], 0] < 0 < V[a[m], 0] and np.allclose(V[a[k]] * [-1, 1, 1], V[a[m]])
                  for k, m in ((36, 45), (39, 42), (48, 54))))
    if not all(checks):
        raise InputError("canonical mesh: its anchor vertices are not where mediapipe's "
                         "numbering puts them (not mediapipe's canonical face mesh?)")
    ids = np.asarray(model.landmark_ids)[ANCHOR_IBUG]
    return np.where(ids >= 0, ANCHOR_MEDIAPIPE, -1)


def closest_points(points, vertices, triangles, k: int = 16):
    """Closest points on a triangle mesh: ``points`` (n, 3), ``vertices`` (V, 3), ``triangles``
    (F, 3) -> triangle index (n,), the closest points (n, 3). The candidates are the ``k``
    triangles with the nearest centroids, then the ones whose centroid is no farther than the
    best point found plus the triangle's radius (so the answer is exact)."""
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point as on_triangles

    P = np.asarray(points, np.float64)
    T = np.asarray(vertices, np.float64)[triangles]
    cent = T.mean(1)
    radius = np.sqrt(((T - cent[:, None]) ** 2).sum(2).max(1))
    tree = cKDTree(cent)
    k = min(k, len(cent))
    _, cand = tree.query(P, k=k)
    cand = cand.reshape(len(P), k)
    best_tri = np.empty(len(P), np.int64)
    best = np.empty_like(P)
    for i, p in enumerate(P):
        c = cand[i]
        q = on_triangles(T[c], np.repeat(p[None], len(c), 0))
        d = ((q - p) ** 2).sum(1)
        j = int(np.argmin(d))
        # any triangle holding a closer point has its centroid within dist + its radius
        more = np.setdiff1d(tree.query_ball_point(p, np.sqrt(d[j]) + radius.max()), c)
        if len(more):
            q2 = on_triangles(T[more], np.repeat(p[None], len(more), 0))
            d2 = ((q2 - p) ** 2).sum(1)
            if d2.min() < d[j]:
                c, q, d, j = more, q2, d2, int(np.argmin(d2))
        best_tri[i], best[i] = c[j], q[j]
    return best_tri, best


def _triangles_within(model, vertex_set) -> np.ndarray:
    """Ids of the model's triangles whose three vertices are in ``vertex_set``."""
    keep = np.zeros(model.n_vertices, bool)
    keep[vertex_set] = True
    return np.flatnonzero(keep[model.triangles].all(1))


def project_to_surface(points, model, vertex_set=None):
    """Closest points of the model mean's surface (the triangles within ``vertex_set``, default
    all) to ``points`` (n, 3) mm -> vertex ids (n, 3), barycentric weights (n, 3), the surface
    points (n, 3) mm."""
    from trimesh.triangles import points_to_barycentric

    tri_ids = _triangles_within(model, np.arange(model.n_vertices) if vertex_set is None
                                else vertex_set)
    tri, near = closest_points(points, model.mean, model.triangles[tri_ids])
    verts = model.triangles[tri_ids[tri]].astype(np.int64)
    bary = points_to_barycentric(model.mean[verts].astype(np.float64), near)
    # the closest point lies in its triangle: clip rounding, and keep rows summing to 1 exactly
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(1, keepdims=True)
    return verts, bary, np.einsum("nkc,nk->nc", model.mean[verts].astype(np.float64), bary)


_NRICP_STEPS = (
    # (stiffness, landmark weight, normal weight, iterations), from stiff to supple (Amberg et
    # al.); the anchors held firmly throughout: with a landmark weight falling to 1, ICT's mouth
    # corners drifted 4.9 mm off its landmarks, with 10 they stay within 1.4 mm
    (10.0, 10.0, 0.5, 10), (3.0, 10.0, 0.5, 10), (1.0, 10.0, 0.5, 10), (0.3, 10.0, 0.0, 10))


def register(model, V, F, anchors):
    """Place mediapipe's canonical mesh on the model mean -> (aligned (478, 3), registered
    (478, 3)) mm: the similarity from the anchors, then the non-rigid registration onto the
    model's skin (the irises moved with their eyes' lid points)."""
    from trimesh import Trimesh
    from trimesh.registration import nricp_amberg

    ids = np.asarray(model.landmark_ids)
    ok = anchors >= 0
    target = model.mean[ids[ANCHOR_IBUG[ok]]].astype(np.float64)
    aligned = _apply(similarity(V[anchors[ok]], target), V)
    # matches to the skin's vertices (use_faces=False: trimesh's closest point on faces needs
    # rtree); the final projection (project_to_surface) is onto the triangles
    skin = model.mean[model.skin_vertices()].astype(np.float64)
    reg = nricp_amberg(Trimesh(aligned[:N_MESH], F, process=False), skin,
                       source_landmarks=anchors[ok], target_positions=target,
                       steps=[list(s) for s in _NRICP_STEPS], distance_threshold=20.0,
                       use_faces=False)
    registered = np.vstack([reg, aligned[N_MESH:]])
    for iris in IRISES:
        # the lid points around the iris carry it: their mean displacement
        near = np.argsort(((aligned[:N_MESH] - aligned[iris[0]]) ** 2).sum(1))[:16]
        registered[iris] += (reg[near] - aligned[near]).mean(0)
    return aligned, registered


def mirror_indices(V) -> np.ndarray:
    """Each canonical point's mirror image: the point nearest its reflection in x -> (478,)
    int; InputError unless that is a permutation that is its own inverse."""
    from scipy.spatial import cKDTree

    V = np.asarray(V, np.float64)
    d, m = cKDTree(V).query(V * [-1.0, 1.0, 1.0])
    ids = np.arange(len(V))
    if not (np.array_equal(np.sort(m), ids) and np.array_equal(m[m], ids)
            and d.max() < 1e-3 * np.ptp(V, 0).max()):
        raise InputError("canonical mesh: not left-right symmetric (the mirror is no permutation)")
    return m.astype(np.int64)


def outline_split(V) -> tuple[np.ndarray, np.ndarray, int]:
    """The sliding part of the face oval -> (right, left, chin): the :data:`FACE_OVAL` points
    below the eyes' height (the iris centres), the subject's right (x < 0) and left (x > 0)
    each from the top to the chin, and the chin, the lowest point of the midline."""
    V = np.asarray(V)
    eye_y = V[[IRISES[0][0], IRISES[1][0]], 1].mean()
    chin_at = int(np.argmin(V[FACE_OVAL, 1]))
    chin = int(FACE_OVAL[chin_at])
    # the loop runs from the forehead over the subject's left to the chin, then up the right
    left = [i for i in FACE_OVAL[:chin_at] if V[i, 1] < eye_y and V[i, 0] > 0]
    right = [i for i in FACE_OVAL[chin_at + 1:][::-1] if V[i, 1] < eye_y and V[i, 0] < 0]
    return np.array(right, np.int64), np.array(left, np.int64), chin


def _resample(poly, fractions) -> np.ndarray:
    """Points at ``fractions`` of the arc length along the polyline ``poly`` (n, 3)."""
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)] / seg.sum()
    return np.stack([np.interp(fractions, s, poly[:, c]) for c in range(poly.shape[1])], 1)


def _cut_below(poly, y) -> np.ndarray:
    """The part of the polyline ``poly`` (top to bottom) below height ``y``, starting at y."""
    below = np.flatnonzero(poly[:, 1] < y)
    if len(below) == 0 or below[0] == 0:
        return poly
    i = below[0]
    a, b = poly[i - 1], poly[i]
    start = a + (b - a) * (a[1] - y) / (a[1] - b[1])
    return np.vstack([start, poly[i:]])


def ibug68_counterparts(model, P, right, left, chin) -> np.ndarray:
    """The facemesh point closest in meaning to each iBUG-68 point -> (68,) int.

    ``P`` (478, 3) are the scheme's points on the model mean (mm). Inner points (and jaw points
    the model has a vertex for): the nearest facemesh point to the model's landmark vertex, among
    the mesh points (irises excluded; for the jaw, that side's sliding oval points). Jaw points
    without a vertex (SFM): iBUG spaces them evenly along the outline from the eyes' height down
    to the chin, so they are placed at k/8 of the arc length of the model's contour
    (``contour_right``/``contour_left``, else the oval itself) below the outer eye corner's
    height, and take the nearest oval point of that side seen from the front (x, y).
    """
    ids = np.asarray(model.landmark_ids)
    mean = np.asarray(model.mean, np.float64)
    out = np.full(68, -1, dtype=np.int64)
    sliding = np.r_[right, left, chin]
    inner = np.setdiff1d(np.arange(N_MESH), sliding)
    for k in range(17, 68):
        if ids[k] >= 0:
            out[k] = inner[np.argmin(((P[inner] - mean[ids[k]]) ** 2).sum(1))]
    out[8] = chin
    eye_y = {"right": mean[ids[36], 1] if ids[36] >= 0 else P[33, 1],
             "left": mean[ids[45], 1] if ids[45] >= 0 else P[263, 1]}
    chin_point = mean[ids[8]] if ids[8] >= 0 else P[chin]
    for side, jaw, cand, contour in (("right", range(0, 8), right, model.contour_right),
                                     ("left", range(16, 8, -1), left, model.contour_left)):
        poly = mean[contour] if len(contour) else P[cand]
        poly = _cut_below(np.vstack([poly, chin_point]), eye_y[side])
        for step, k in enumerate(jaw):
            target = mean[ids[k]] if ids[k] >= 0 else _resample(poly, [step / 8])[0]
            out[k] = cand[np.argmin(((P[cand, :2] - target[:2]) ** 2).sum(1))]
    return out


def definition_std(residual_mm, right, left, chin) -> np.ndarray:
    """A first per-point definition error (mm per coordinate) -> (478,): 2.5 mm for fixed
    points, 2.0 mm for the sliding oval points (only their distance across the outline counts),
    raised to the per-coordinate RMS of the group's registration residual ``residual_mm`` (478,)
    (the distance between the similarity-placed canonical point and its surface point: how far
    mediapipe's average face disagrees with the model's) where that is larger. Provisional until
    the calibration with the detector on renders."""
    r = np.asarray(residual_mm, np.float64)
    sliding = np.zeros(len(r), bool)
    sliding[np.r_[right, left, chin]] = True
    std = np.empty(len(r))
    for mask, base in ((sliding, _OVAL_STD_MM), (~sliding, _FIXED_STD_MM)):
        std[mask] = max(base, float(np.sqrt((r[mask] ** 2).mean() / 3.0)))
    return std


@dataclass
class Build:
    """A built scheme and its registration figures (mm)."""

    scheme: LandmarkScheme
    aligned: np.ndarray
    """(478, 3) the similarity-placed canonical mesh, mm."""
    surface: np.ndarray
    """(478, 3) the scheme's points on the model mean, mm."""
    anchors: np.ndarray
    """(8,) the canonical anchor vertices (-1: the model lacks the landmark)."""
    anchor_rms_mm: float
    """RMS distance of the similarity-placed anchors to the model's landmarks."""

    @property
    def residual_mm(self) -> np.ndarray:
        """(478,) distance of each surface point to its similarity-placed canonical point."""
        return np.linalg.norm(self.surface - self.aligned, axis=1)

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt((self.residual_mm ** 2).mean()))


def _iris_surfaces(model) -> list[np.ndarray]:
    """Vertex sets the right and left iris are projected onto: the model's eyeballs where it
    has them (ICT), else its skin (SFM: the eyelid surface)."""
    balls = [model.segments[k] for k in ("eyeball_left", "eyeball_right") if k in model.segments]
    if len(balls) < 2:
        return [model.skin_vertices()] * 2
    return sorted(balls, key=lambda b: float(model.mean[b, 0].mean()))


def build_scheme(model, canonical=None) -> Build:
    """Derive ``model``'s facemesh478 scheme (see the module's docstring) -> :class:`Build`."""
    V, F = canonical_mesh(canonical)
    anchors = anchor_indices(V, model)
    aligned, registered = register(model, V, F, anchors)
    verts = np.empty((478, 3), np.int64)
    bary = np.empty((478, 3))
    surf = np.empty((478, 3))
    groups = [(np.arange(N_MESH), model.skin_vertices())] + list(zip(IRISES, _iris_surfaces(model)))
    for pts, vset in groups:
        verts[pts], bary[pts], surf[pts] = project_to_surface(registered[pts], model, vset)
    right, left, chin = outline_split(V)
    ok = anchors >= 0
    lm = model.mean[np.asarray(model.landmark_ids)[ANCHOR_IBUG[ok]]]
    residual = np.linalg.norm(surf - aligned, axis=1)
    scheme = LandmarkScheme(
        name="facemesh478", model_name=model.name, vertices=verts, barycentric=bary,
        outline_right=right, outline_left=left, chin=chin,
        definition_std_mm=definition_std(residual, right, left, chin),
        mirror=mirror_indices(V), ibug68=ibug68_counterparts(model, surf, right, left, chin))
    return Build(scheme=scheme, aligned=aligned, surface=surf, anchors=anchors,
                 anchor_rms_mm=float(np.sqrt(((aligned[anchors[ok]] - lm) ** 2).sum(1).mean())))


@one_line_errors("python -m morphable.fitting.scheme_build")
def main(argv=None) -> int:
    from ..io.registry import load_model
    from ..logs import add_verbosity_arguments, configure, verbosity

    p = argparse.ArgumentParser(prog="python -m morphable.fitting.scheme_build",
                                description="derive a model's facemesh478 landmark scheme from "
                                            "mediapipe's canonical face mesh")
    p.add_argument("--model", required=True, help="sfm, ict or a model file")
    p.add_argument("--out", help="sidecar to write (default: morphable/data/facemesh478_<model>"
                                 ".npz for sfm and ict, else beside the model's file)")
    p.add_argument("--canonical", help="mediapipe's face_model_with_iris.obj (default: found "
                                       "on the model search path)")
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    model = load_model(args.model)
    out = Path(args.out) if args.out else (
        DATA_DIR / f"facemesh478_{model.name}.npz" if model.name in MODELS
        else scheme_path(model, "facemesh478"))
    if not out.parent.is_dir():  # before the work, not after
        raise InputError(f"{out}: output folder {out.parent} does not exist")
    t0 = time.perf_counter()
    b = build_scheme(model, args.canonical)
    save_scheme(b.scheme, out, model)
    print(f"{out}: {model.name} facemesh478 in {time.perf_counter() - t0:.1f} s; anchors "
          f"RMS {b.anchor_rms_mm:.2f} mm after the similarity, surface points "
          f"RMS {b.rms_mm:.2f} mm from the similarity-placed canonical mesh")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
