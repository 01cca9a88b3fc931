"""Visibility: per pixel (or texel) the triangle seen and its barycentric coordinates.

Rays are cast with open3d's ``RaycastingScene`` (Embree, CPU, multi-threaded). Only the
pixels inside the mesh's projected bounding box are cast, only the hits are kept, and the
Embree scene and vertex normals of the last few meshes are cached (found by comparing their
vertices and triangles), so rendering the same mesh from many cameras builds them once.

Conventions
-----------
- Sample ``(i, j)`` of a visibility computed with ``supersample = s`` lies at image point
  ``x = (j + 0.5) / s - 0.5``, ``y = (i + 0.5) / s - 0.5`` (pixel centres at integers, as in
  :mod:`morphable.camera`); ``s = 1`` samples the pixel centres.
- Barycentric ``(w0, w1, w2)`` weight the triangle's corners in the order of ``triangles``;
  they are 3D (object-space) barycentrics, so interpolating any vertex attribute with them is
  perspective-correct.
- Depth is ``-Zc`` in mm (the camera module's depth), ``inf`` on background samples.
- Perspective: only what lies in front of the camera is seen (a mesh partly behind it is
  clipped). Affine: the camera sits at infinity, the whole mesh is seen and parts of it may
  have depth <= 0. Either way a mesh with depth <= 0 everywhere is an error (a camera
  looking the wrong way).
- Both sides of a triangle are visible (no back-face culling).
"""
from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from functools import cached_property

import numpy as np

from ..errors import InputError
from ..logs import import_open3d

__all__ = ["Visibility", "visibility", "uv_visibility", "check_mesh", "scene", "closest_points",
           "points_in_view"]

_MESHES: "list[CachedMesh]" = []  # most recently used last
_MESH_CACHE_SIZE = 4
_UV_TABLES: "OrderedDict[bytes, Visibility]" = OrderedDict()
_UV_CACHE_SIZE = 8
_MAX_SAMPLES = 1 << 27  # 134 M samples: about 10 GB of rays and results
_LOCK = threading.Lock()  # the caches are shared by threads (batch engines, data loaders)


class Visibility:
    """What each sample of an image (or UV layout) sees.

    Attributes
    ----------
    triangle_id : (Hs, Ws) int64
        Triangle index per sample, -1 on background.
    barycentric : (Hs, Ws, 3) float32
        Weights of the triangle's three corners (sum 1), zeros on background.
    depth : (Hs, Ws) float64, mm
        ``-Zc`` of the surface point, ``inf`` on background (UV tables: zeros).
    triangles : (F, 3) int64
        The triangles that ``triangle_id`` indexes (their corners are what the weights weigh).
    camera : morphable.camera.Camera or None
        None for a UV-layout table.
    supersample : int
        Samples per pixel along each axis; ``Hs = H * supersample``, ``Ws = W * supersample``.

    :func:`visibility` stores only the foreground samples (:attr:`pixels`, :attr:`weights`
    and their triangles and depths); the three images are built from them on first use, so
    that a bake, which needs only the foreground, never allocates them.
    """

    def __init__(self, triangle_id, barycentric, depth, triangles, camera=None,
                 supersample: int = 1):
        self.triangle_id, self.barycentric, self.depth = triangle_id, barycentric, depth
        self.triangles, self.camera, self.supersample = triangles, camera, supersample
        self._shape = tuple(triangle_id.shape)
        self._extra = {}

    @classmethod
    def from_samples(cls, shape, pixels, ids, weights, depth, triangles, camera=None,
                     supersample: int = 1):
        """A visibility from its foreground samples only.

        ``shape`` (Hs, Ws); ``pixels`` (N,) int64 increasing flat sample indices; ``ids`` (N,)
        int triangle ids; ``weights`` (N, 3) float32; ``depth`` (N,) mm, or a pair (t, z0)
        for ``t - z0`` (computed in float64 when the depth image is first used).
        """
        vis = cls.__new__(cls)
        vis.triangles, vis.camera, vis.supersample = triangles, camera, supersample
        vis._shape = tuple(shape)
        vis._extra, vis._foreground_depth = {}, depth
        # the cached properties below read these first
        vis.__dict__.update(pixels=pixels, _ids=ids, weights=weights)
        return vis

    @cached_property
    def triangle_id(self) -> np.ndarray:
        out = np.full(self._shape, -1, dtype=np.int64)
        out.ravel()[self.pixels] = self._ids
        return out

    @cached_property
    def barycentric(self) -> np.ndarray:
        out = np.zeros(self._shape + (3,), dtype=np.float32)
        flat = out.reshape(-1, 3)
        for c in range(3):  # columns: numpy scatters rows of 3 several times slower
            flat[:, c][self.pixels] = self.weights[:, c]
        return out

    @cached_property
    def depth(self) -> np.ndarray:
        out = np.full(self._shape, np.inf)
        d = self._foreground_depth
        out.ravel()[self.pixels] = d[0] - d[1] if isinstance(d, tuple) else d
        return out

    def __repr__(self):
        return (f"Visibility(shape={self._shape}, foreground={len(self.pixels)}, "
                f"supersample={self.supersample}, camera={self.camera!r})")

    @property
    def mask(self) -> np.ndarray:
        """(Hs, Ws) bool: True where a triangle is seen."""
        return self.triangle_id >= 0

    @property
    def shape(self) -> tuple:
        """(Hs, Ws): the sample grid."""
        return self._shape

    @property
    def image_shape(self) -> tuple:
        """(H, W): the pixel grid (the sample grid divided by ``supersample``)."""
        s = self.supersample
        return self.shape[0] // s, self.shape[1] // s

    @cached_property
    def pixels(self) -> np.ndarray:
        """(N,) int64 flat indices of the foreground samples (row-major)."""
        return np.flatnonzero(self.triangle_id.ravel() >= 0)

    @cached_property
    def weights(self) -> np.ndarray:
        """(N, 3) barycentric weights of the foreground samples."""
        # np.take, not fancy indexing: numpy's row gather is ~10x slower than take's
        return np.take(self.barycentric.reshape(-1, 3), self.pixels, axis=0)

    def corners(self, triangles=None) -> np.ndarray:
        """(N, 3) int64 corner ids of the foreground samples' triangles.

        ``triangles`` (F, 3) replaces :attr:`triangles`, e.g. ``triangle_uv`` to look up
        per-corner texture coordinates.
        """
        if triangles is None:
            return self.cached("corners", lambda: np.take(self.triangles, self._ids, axis=0))
        return np.take(np.asarray(triangles), self._ids, axis=0)

    @cached_property
    def _ids(self) -> np.ndarray:
        """(N,) triangle ids of the foreground samples."""
        return np.take(self.triangle_id.ravel(), self.pixels)

    def matrix(self, n_rows: int, triangles=None, dtype=np.float64, foreground: bool = False):
        """Sparse (Hs * Ws, n_rows) interpolation matrix: row p holds the barycentric weights
        of sample p on the corner ids of its triangle (empty rows on background), so that
        ``matrix @ attributes`` interpolates. ``foreground=True``: only the rows of
        :attr:`pixels`, (N, n_rows). scipy CSR, cached per arguments."""
        key = ("matrix", n_rows, None if triangles is None else array_key(np.asarray(triangles)),
               np.dtype(dtype).str, foreground)
        return self.cached(key, lambda: self._matrix(n_rows, triangles, dtype, foreground))

    def _matrix(self, n_rows, triangles, dtype, foreground):
        import scipy.sparse as sp

        tri = self.triangles if triangles is None else np.asarray(triangles)
        # scipy keeps int32 indices as they are and copies int64 ones down to int32
        small = max(n_rows, 3 * len(self.pixels) + 1, len(tri)) < 2 ** 31
        itype = np.int32 if small else np.int64
        idx = np.take(tri.astype(itype, copy=False), self._ids, axis=0)
        if idx.size and idx.max() >= n_rows:
            raise InputError(f"attributes have {n_rows} rows, the triangles index up to "
                             f"{idx.max()}")
        if foreground:
            indptr, rows = np.arange(0, 3 * len(idx) + 1, 3, dtype=itype), len(idx)
        else:
            size = self._shape[0] * self._shape[1]
            count = np.zeros(size + 1, dtype=np.int64)
            count[self.pixels + 1] = 3
            indptr, rows = np.cumsum(count), size
        return sp.csr_matrix(
            (self.weights.astype(dtype, copy=False).ravel(), idx.ravel(), indptr),
            shape=(rows, n_rows))

    def cached(self, key, make):
        """A value derived from this visibility (an interpolation matrix, say): ``make()``
        on the first call with ``key`` (hashable), the kept value after."""
        extra = self._extra
        if key not in extra:
            extra[key] = make()
        return extra[key]

    def coverage(self) -> np.ndarray:
        """(H, W) float in [0, 1]: the fraction of each pixel's samples on the mesh."""
        return self.downsample(self.mask.astype(np.float64))

    def downsample(self, image):
        """Box-filter a sample-grid image to the pixel grid.

        ``image``: (..., Hs, Ws, C) or (Hs, Ws) numpy array or torch tensor -> (..., H, W, C)
        or (H, W), the mean of each pixel's ``supersample**2`` samples.
        """
        s = self.supersample
        if s == 1:
            return image
        flat = image.ndim == 2
        x = image[..., None] if flat else image
        # a sum of s * s strided views: several times faster than a mean over reshaped axes
        out = None
        for i in range(s):
            for j in range(s):
                part = x[..., i::s, j::s, :]
                out = part * 1.0 if out is None else out + part
        out = out / (s * s)
        return out[..., 0] if flat else out


def check_mesh(vertices, triangles, what: str = "mesh"):
    """Validate a triangle mesh -> (vertices float (V, 3), triangles int64 (F, 3)).

    Raises InputError for empty meshes, bad shapes, out-of-range ids and NaN/inf.
    """
    v = np.asarray(vertices)
    if v.dtype.kind != "f":
        v = v.astype(np.float64)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise InputError(f"{what}: vertices must be a non-empty (V, 3) array, got {v.shape}")
    if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise InputError(f"{what}: triangles must be a non-empty (F, 3) array, got {t.shape}")
    if t.dtype.kind not in "iu":
        raise InputError(f"{what}: triangles must be integer vertex ids")
    t = t.astype(np.int64, copy=False)
    if t.min() < 0 or t.max() >= len(v):
        raise InputError(f"{what}: triangle ids out of range [0, {len(v)})")
    if not np.isfinite(v).all():
        raise InputError(f"{what}: vertices contain NaN or inf")
    return v, t


def array_key(*arrays) -> bytes:
    """A cache key of arrays: a hash of their dtypes, shapes and bytes (20 bytes)."""
    h = hashlib.blake2b(digest_size=20)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.data)
    return h.digest()


def _cached(cache: OrderedDict, size: int, key: bytes, make):
    with _LOCK:
        if key in cache:
            cache.move_to_end(key)
            return cache[key]
    value = make()  # outside the lock: two threads may both build, one result is kept
    with _LOCK:
        cache[key] = value
        while len(cache) > size:
            cache.popitem(last=False)
    return value


def _import_open3d():
    try:
        open3d = import_open3d()
    except ImportError:  # pragma: no cover - the raster extra is missing
        raise InputError("rasterisation needs open3d: pip install 'morphable[raster]'") from None
    return open3d


class CachedMesh:
    """A mesh seen before: its Embree scene and vertex normals, each built on first use.

    Found again by comparing the arrays themselves (a few microseconds), not a hash of them.
    """

    def __init__(self, vertices, triangles):
        self.vertices, self.triangles = vertices.copy(), triangles.copy()
        self._normals = {}

    def matches(self, vertices, triangles) -> bool:
        return (vertices.dtype == self.vertices.dtype and triangles.dtype == self.triangles.dtype
                and np.array_equal(vertices, self.vertices)
                and np.array_equal(triangles, self.triangles))

    @cached_property
    def scene(self):
        o3d = _import_open3d()
        sc = o3d.t.geometry.RaycastingScene()
        sc.add_triangles(o3d.core.Tensor(np.ascontiguousarray(self.vertices, dtype=np.float32)),
                         o3d.core.Tensor(np.ascontiguousarray(self.triangles, dtype=np.uint32)))
        return sc

    def normals(self, weighting: str) -> np.ndarray:
        """(V, 3) unit vertex normals (read-only), see :func:`morphable.normals.vertex_normals`."""
        if weighting not in self._normals:
            from ..normals import vertex_normals

            n = vertex_normals(self.vertices, self.triangles, weighting=weighting)
            n.flags.writeable = False
            self._normals[weighting] = n
        return self._normals[weighting]


def cached_mesh(vertices, triangles, add: bool = True):
    """The cached :class:`CachedMesh` of these arrays; a new one (cached if ``add``, else None)
    when they were not seen among the last few meshes."""
    v, t = np.asarray(vertices), np.asarray(triangles)
    with _LOCK:
        for i, m in enumerate(_MESHES):
            if m.matches(v, t):
                _MESHES.append(_MESHES.pop(i))
                return m
        if not add:
            return None
        m = CachedMesh(v, t)
        _MESHES.append(m)
        del _MESHES[:-_MESH_CACHE_SIZE]
    return m


def scene(vertices, triangles):
    """The (cached) Embree scene of a mesh in world coordinates (float32).

    ``vertices`` (V, 3) mm, ``triangles`` (F, 3) int -> ``open3d.t.geometry.RaycastingScene``.
    """
    return cached_mesh(vertices, triangles).scene


def _barycentric(uv, seen):
    """Embree's (u, v) -> (..., 3) float32 weights, zero where not ``seen`` (...,1) bool."""
    bary = np.empty(uv.shape[:-1] + (3,), dtype=np.float32)
    # (u, v) weight corners 1 and 2: p = (1 - u - v) p0 + u p1 + v p2; products with the hit
    # mask rather than a masked assignment, which is several times slower
    np.multiply(uv, seen, out=bary[..., 1:])
    np.subtract(1.0, uv[..., 0:1], out=bary[..., 0:1])
    bary[..., 0:1] -= uv[..., 1:2]
    bary[..., 0:1] *= seen
    return bary


def _cast_rays(sc, rays):
    o3d = _import_open3d()
    hit = sc.cast_rays(o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays, dtype=np.float32)))
    # INVALID_ID is 2**32 - 1, i.e. -1 read as int32 (triangle counts stay below 2**31)
    return (hit["t_hit"].numpy(), hit["primitive_ids"].numpy().view(np.int32),
            hit["primitive_uvs"].numpy())


def cast(sc, rays):
    """Cast rays (..., 6) = origin, direction -> (t_hit (...) float32, triangle (...) int64
    with -1 for misses, barycentric (..., 3) float32)."""
    t_hit, tri, uv = _cast_rays(sc, rays)
    return t_hit, tri.astype(np.int64), _barycentric(uv, (tri >= 0)[..., None])


def cast_foreground(sc, rays):
    """Cast rays (..., 6) and keep the hits only -> (index (N,) int64 into the flattened
    rays, triangle (N,) int32, barycentric (N, 3) float32, t_hit (N,) float32)."""
    t_hit, tri, uv = _cast_rays(sc, rays)
    hits = np.flatnonzero(tri.ravel() >= 0)
    # np.take, not fancy indexing, which gathers rows ~10x slower; each (u, v) pair read as
    # one 8-byte item
    uv = np.take(uv.reshape(-1, 2).view(np.float64).ravel(), hits).view(np.float32)
    u, v = uv[0::2], uv[1::2]
    # Embree's (u, v) weight corners 1 and 2: p = (1 - u - v) p0 + u p1 + v p2
    bary = np.stack([1.0 - u - v, u, v], 1)
    return hits, np.take(tri.ravel(), hits), bary, np.take(t_hit.ravel(), hits)


def points_in_view(vertices, triangles, camera, points, normals, offset_mm=None) -> np.ndarray:
    """Which surface points the camera sees: nothing of the mesh lies between them and it.

    Parameters
    ----------
    vertices : (V, 3) float, mm; triangles : (F, 3) int
    camera : morphable.camera.Camera
    points : (N, 3) float, mm, points on the mesh's surface
    normals : (N, 3) unit surface normals at them (the ray starts just off the surface so
        that it does not hit its own triangle)
    offset_mm : None: the ray starts ``1e-3`` of the mesh's size along normal + view
        direction (robust for texels; a point within that distance of a silhouette may be
        taken as seen); a float: it starts ``offset_mm`` along the view direction only and
        points whose normal faces away from the camera are not seen (exact labels)

    Returns
    -------
    (N,) bool: a ray from just off each point towards the camera (the pinhole, or along the
    axis for an affine camera) hits no triangle before the camera. Points behind a
    perspective camera, or NaN points, are False. Faces turned away are not excluded here
    (a point on a back face whose ray escapes counts as seen).
    """
    points = np.asarray(points, dtype=np.float64)
    out = np.zeros(len(points), dtype=bool)
    ok = np.isfinite(points).all(1) & np.isfinite(normals).all(1)
    if camera.kind != "affine":
        with np.errstate(invalid="ignore"):
            ok &= camera.depth(points) > 0
    k = np.flatnonzero(ok)
    if not len(k):
        return out
    d = camera.view_directions(points[k])
    n = np.asarray(normals, dtype=np.float64)[k]
    if offset_mm is None:
        eps = 1e-3 * float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
        origins = points[k] + eps * (d + n)
    else:
        facing = np.einsum("nc,nc->n", n, d) > 0
        k, d = k[facing], d[facing]
        origins = points[k] + float(offset_mm) * d
    t_hit, _, _ = cast(scene(vertices, triangles),
                       np.concatenate([origins, d], 1).astype(np.float32))
    if camera.kind == "affine":
        hidden = np.isfinite(t_hit)
    else:
        hidden = t_hit < np.linalg.norm(camera.centre - origins, axis=1)
    out[k[~hidden]] = True
    return out


def closest_points(vertices, triangles, points):
    """The nearest surface point of a mesh to each query point.

    Parameters
    ----------
    vertices : (V, 3) float, mm
    triangles : (F, 3) int
    points : (N, 3) float, mm

    Returns
    -------
    triangle : (N,) int64, the triangle of the nearest point
    barycentric : (N, 3) float32, its weights on the triangle's corners
    distance : (N,) float64, mm, from the query point

    Examples
    --------
    >>> tri = np.array([[0., 0, 0], [10, 0, 0], [0, 10, 0]])
    >>> t, b, d = closest_points(tri, [[0, 1, 2]], np.array([[2., 3, 5]]))
    >>> int(t[0]), b.astype(float).round(2).tolist(), d.round(2).tolist()
    (0, [[0.5, 0.2, 0.3]], [5.0])
    """
    o3d = _import_open3d()
    v, t = check_mesh(vertices, triangles)
    q = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ans = scene(v, t).compute_closest_points(o3d.core.Tensor(q.astype(np.float32)))
    tri = ans["primitive_ids"].numpy().view(np.int32).astype(np.int64)
    bary = _barycentric(ans["primitive_uvs"].numpy(), np.ones((len(q), 1), dtype=bool))
    return tri, bary, np.linalg.norm(ans["points"].numpy() - q, axis=1)


def _window_rays(camera, x0, x1, y0, y1, s, z0):
    """World-frame float32 rays (h, w, 6) through the samples of a pixel window.

    Rays are defined in the camera frame and rotated to the world frame, where the cached
    scene lives. Perspective: from the camera centre with directions ``(Xc/-Zc, Yc/-Zc, -1)``
    (unnormalised, so the hit distance is the depth). Affine: parallel rays along -z from
    the plane ``Zc = z0`` just in front of the mesh, so float32 hit distances stay small.
    """
    R, tr = camera.rotation, camera.translation
    k = camera.scale if camera.kind == "affine" else camera.focal
    # camera-frame x and y of the sample columns and rows (per mm, or per unit depth)
    xc = ((np.arange(x0 * s, x1 * s) + 0.5) / s - 0.5 - camera.principal[0]) / k
    yc = (camera.principal[1] - ((np.arange(y0 * s, y1 * s) + 0.5) / s - 0.5)) / k
    # the varying half of a ray (affine: origin, perspective: direction) is row(j) + col(i)
    # in world coordinates, the other half a constant
    if camera.kind == "affine":
        row = xc[:, None] * R[0] + (np.array([0.0, 0.0, z0]) - tr) @ R
        const, varying, fixed = -R[2], slice(0, 3), 3
    else:
        row = xc[:, None] * R[0] - R[2]
        const, varying, fixed = -tr @ R, slice(3, 6), 0
    row = row.astype(np.float32)
    col = (yc[:, None] * R[1]).astype(np.float32)
    rays = np.empty((len(yc), len(xc), 6), dtype=np.float32)
    # one coordinate at a time: numpy is several times faster at this than at a broadcast
    # over a last axis of length 3
    for c in range(3):
        np.add(col[:, None, c], row[None, :, c], out=rays[..., varying.start + c])
        rays[..., fixed + c] = const[c]
    return rays


def _window(camera, cam_points, width, height):
    """Pixel rectangle (x0, x1, y0, y1), x1/y1 exclusive, that contains the projection of the
    camera-frame points (V, 3) mm."""
    uv = camera.project_camera_frame(cam_points)
    if not np.isfinite(uv).all():
        return 0, width, 0, height  # points at or behind the camera: no finite bound
    u, v = uv[:, 0], uv[:, 1]
    # a pixel's samples reach half a pixel beyond its centre
    x0 = int(np.clip(np.floor(u.min() - 0.5), 0, width))
    x1 = int(np.clip(np.ceil(u.max() + 1.5), 0, width))
    y0 = int(np.clip(np.floor(v.min() - 0.5), 0, height))
    y1 = int(np.clip(np.ceil(v.max() + 1.5), 0, height))
    return x0, x1, y0, y1


def visibility(vertices, triangles, camera, supersample: int = 1) -> Visibility:
    """Cast one ray per sample and record the triangle hit and its barycentrics.

    Parameters
    ----------
    vertices : (V, 3) float array, mm, world frame
    triangles : (F, 3) int array
    camera : morphable.camera.Camera
        Affine or perspective; its ``image_size`` (W, H) sets the image.
    supersample : int
        Samples per pixel along each axis (antialiasing; 1 = pixel centres).

    Returns
    -------
    Visibility on an (H * supersample, W * supersample) grid.

    Raises
    ------
    InputError
        Empty mesh, NaN/inf vertices, bad ids, ``supersample < 1``, or a mesh entirely
        behind the camera (depth <= 0 for every vertex).

    Examples
    --------
    >>> import numpy as np
    >>> from morphable.camera import Camera
    >>> square = np.array([[-50., -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]])
    >>> cam = Camera.looking_at_face(image_size=(64, 48))
    >>> vis = visibility(square, [[0, 1, 2], [0, 2, 3]], cam)
    >>> vis.shape, int(vis.mask.sum()), float(vis.depth[24, 32])
    ((48, 64), 256, 600.0)
    """
    from ..camera import Camera

    if not isinstance(camera, Camera):
        raise InputError(f"camera must be a morphable.camera.Camera, got {type(camera).__name__}")
    v, t = check_mesh(vertices, triangles)
    k = camera.scale if camera.kind == "affine" else camera.focal
    if not k > 0:
        what = "scale" if camera.kind == "affine" else "focal length"
        raise InputError(f"camera {what} must be positive, got {k}")
    try:
        s = int(supersample)
    except (TypeError, ValueError):
        raise InputError(f"supersample must be an integer >= 1, got {supersample!r}") from None
    if s < 1 or s != supersample:
        raise InputError(f"supersample must be an integer >= 1, got {supersample!r}")
    W, H = camera.image_size
    Ws, Hs = W * s, H * s
    if Ws * Hs > _MAX_SAMPLES:
        raise InputError(f"{W}x{H} pixels with supersample {s} are {Ws * Hs} samples, more than "
                         f"the {_MAX_SAMPLES} this rasteriser takes at once")
    pc = camera.to_camera(v.astype(np.float64, copy=False))
    if (pc[:, 2] >= 0).all():
        raise InputError("mesh is entirely behind the camera (depth <= 0 for every vertex); "
                         "check the camera translation and rotation")

    x0, x1, y0, y1 = _window(camera, pc, W, H)
    z0 = pc[:, 2].max() + 1.0 if camera.kind == "affine" else 0.0
    rays = _window_rays(camera, x0, x1, y0, y1, s, z0)
    pixels, ids, weights, t_hit = cast_foreground(scene(v, t), rays)
    # window-local -> image flat sample index, in place
    w = rays.shape[1]
    del rays
    rows = pixels // max(w, 1)
    rows *= Ws - w
    pixels += rows
    pixels += y0 * s * Ws + x0 * s
    # perspective: t_hit is -Zc; affine: the rays start at Zc = z0
    return Visibility.from_samples((Hs, Ws), pixels, ids, weights, (t_hit, z0), t,
                                   camera=camera, supersample=s)


def uv_visibility(triangles, uv, triangle_uv=None, size: int = 256) -> Visibility:
    """Texel -> triangle and barycentrics of a UV layout (cached per layout and size).

    Parameters
    ----------
    triangles : (F, 3) int
        The mesh's vertex ids; the returned table indexes them.
    uv : (T, 2) float in [0, 1], v up
    triangle_uv : (F, 3) int ids into ``uv``, or None when ``uv`` is per vertex
    size : int
        The map is size x size texels; texel ``(i, j)`` has its centre at
        ``u = (j + 0.5) / size``, ``v = 1 - (i + 0.5) / size`` (row 0 is the top, v = 1).

    Returns
    -------
    Visibility with ``camera=None`` and ``depth`` zero; where UV triangles overlap one of them
    is taken.

    Examples
    --------
    >>> uv = np.array([[0., 0], [1, 0], [1, 1], [0, 1]])
    >>> table = uv_visibility([[0, 1, 2], [0, 2, 3]], uv, size=8)
    >>> int(table.mask.sum())
    64
    """
    t = np.asarray(triangles, dtype=np.int64)
    uv = np.asarray(uv, dtype=np.float64)
    try:
        size = int(size)
    except (TypeError, ValueError):
        raise InputError(f"UV map size must be a positive integer, got {size!r}") from None
    if size < 1 or size * size > _MAX_SAMPLES:
        raise InputError(f"UV map size must be a positive integer up to "
                         f"{int(_MAX_SAMPLES ** 0.5)}, got {size}")
    if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise InputError(f"triangles must be a non-empty (F, 3) array, got {t.shape}")
    if uv.ndim != 2 or uv.shape[1] != 2 or not np.isfinite(uv).all():
        raise InputError(f"uv must be a finite (T, 2) array, got {uv.shape}")
    tuv = t if triangle_uv is None else np.asarray(triangle_uv, dtype=np.int64)
    if tuv.shape != t.shape or tuv.min() < 0 or tuv.max() >= len(uv):
        raise InputError(f"triangle_uv must be {t.shape} ids into uv (T = {len(uv)})")

    def make():
        plane = np.concatenate([uv, np.zeros((len(uv), 1))], 1)
        sc = scene(plane, tuv)
        c = (np.arange(size) + 0.5) / size
        uu, vv = np.meshgrid(c, 1.0 - c)
        rays = np.stack([uu, vv, np.ones_like(uu)] + [np.zeros_like(uu)] * 2 + [-np.ones_like(uu)], -1)
        _, tid, b = cast(sc, rays)
        return Visibility(tid, b,
                          np.zeros((size, size)), t, camera=None, supersample=1)

    return _cached(_UV_TABLES, _UV_CACHE_SIZE, array_key(t, uv, tuv, np.array([size])), make)
