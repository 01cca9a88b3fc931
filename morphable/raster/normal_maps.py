"""Normal maps: screen space (camera or world frame) and UV space (world or tangent frame).

Both interpolate smooth per-vertex normals (:func:`morphable.normals.vertex_normals`) with a
fixed visibility and renormalise them; background is zero. Torch vertices give a
differentiable torch map (gradients reach the vertices through the vertex normals).
"""
from __future__ import annotations

import numpy as np

from ..arrays import is_torch
from ..errors import InputError
from ..normals import vertex_normals
from .interpolate import interpolate
from .visibility import Visibility, cached_mesh, check_mesh, uv_visibility, visibility

__all__ = ["layout_faces", "normal_map", "uv_normal_map", "uv_layout", "tangent_frames"]

_TINY = 1e-24


def _normalize(n, mask):
    """Unit vectors where ``mask``, zero elsewhere (numpy or torch, never NaN)."""
    if is_torch(n):
        import torch

        m = torch.as_tensor(mask, device=n.device)
        unit = n * torch.rsqrt((n * n).sum(-1, keepdim=True) + _TINY)
        return unit * m[..., None].to(n.dtype)
    norm = np.sqrt(np.einsum("...i,...i->...", n, n) + _TINY)[..., None]
    return np.divide(n, norm, out=np.zeros_like(n), where=np.asarray(mask)[..., None])


def _resolve(vis, n):
    """Sample grid -> pixel grid: average the samples, keep pixels at least half covered."""
    if isinstance(vis, (list, tuple)):
        mask = np.stack([v.mask for v in vis])
        s = vis[0]
    else:
        mask, s = vis.mask, vis
    if s.supersample == 1:
        return _normalize(n, mask)
    cover = s.downsample(mask[..., None].astype(np.float64))[..., 0]
    return _normalize(s.downsample(n), cover >= 0.5)


def _rotate(n, R):
    """n (..., 3) @ R^T with R (3, 3) or, for a batch, (B, 3, 3) against n (B, ..., 3)."""
    if is_torch(n):
        import torch

        R = torch.as_tensor(R, dtype=n.dtype, device=n.device)
        if R.ndim == 3:
            return torch.einsum("bij,b...j->b...i", R, n)
        return n @ R.T
    R = np.asarray(R, dtype=n.dtype)
    if R.ndim == 3:
        return np.einsum("bij,b...j->b...i", R, n)
    return n @ R.T


def normal_map(vertices, triangles, camera=None, frame: str = "camera", vis=None,
               supersample: int = 1, weighting: str = "area", rotation=None):
    """Per-pixel unit surface normals of a mesh seen by a camera.

    Parameters
    ----------
    vertices : (V, 3) float array, mm; or a torch tensor (V, 3) / (B, V, 3)
    triangles : (F, 3) int
    camera : morphable.camera.Camera or None
        Needed unless ``vis`` is given (then ``vis.camera`` is used).
    frame : {"camera", "world"}
        "camera": OpenGL camera frame (+x right, +y up, +z towards the viewer), so visible
        surfaces have n_z > 0. "world": the model's frame.
    vis : Visibility, list of B Visibility (torch batch), or None
        Fixed visibility to reuse (required for a torch batch B > 1); None computes it.
    supersample : int
        Antialiasing when ``vis`` is None: normals are averaged over supersample^2 samples
        per pixel and renormalised; pixels less than half covered are background.
    weighting : {"area", "angle"}
        Vertex normal weighting.
    rotation : (3, 3) or (B, 3, 3) array or torch tensor, optional
        World -> camera rotation to use instead of the visibility's camera rotation; on the
        torch path pass the differentiable pose to get gradients with respect to it.

    Returns
    -------
    (H, W, 3) array (float dtype of ``vertices``), or torch (H, W, 3) / (B, H, W, 3); unit
    vectors on the mesh, zero on background.

    Examples
    --------
    >>> from morphable.camera import Camera
    >>> sq = np.array([[-50., -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]])
    >>> nmap = normal_map(sq, [[0, 1, 2], [0, 2, 3]], Camera.looking_at_face((32, 32)))
    >>> nmap[16, 16], nmap[0, 0]
    (array([0., 0., 1.]), array([0., 0., 0.]))
    """
    if frame not in ("camera", "world"):
        raise InputError(f"frame must be 'camera' or 'world', got {frame!r}")
    torch_in = is_torch(vertices)
    if vis is None:
        if torch_in and vertices.ndim == 3 and vertices.shape[0] != 1:
            raise InputError("a torch batch needs a list of visibilities (vis=[...])")
        if camera is None:
            raise InputError("normal_map needs a camera or a visibility")
        v_np = vertices.detach().cpu().numpy().reshape(-1, 3) if torch_in else vertices
        vis = visibility(v_np, triangles, camera, supersample)
        if torch_in and vertices.ndim == 3:
            vis = [vis]
    first = vis[0] if isinstance(vis, (list, tuple)) else vis
    if not isinstance(first, Visibility) or first.camera is None:
        raise InputError("vis must be a camera Visibility (from visibility())")
    if torch_in:
        import torch

        if not torch.isfinite(vertices).all():
            raise InputError("vertices contain NaN or inf")
        tri = torch.as_tensor(np.asarray(triangles, dtype=np.int64), device=vertices.device)
    else:
        vertices, tri = check_mesh(vertices, triangles)
    if not torch_in and first.supersample == 1 and rotation is None:
        return _foreground_normal_map(vertices, tri, first, frame, weighting)
    return _resolve(vis, _interpolated_normals(vertices, tri, vis, frame, rotation, weighting))


def _foreground_normal_map(vertices, triangles, vis, frame, weighting):
    """The numpy normal map of a visibility without supersampling: interpolation and
    normalisation run on the foreground samples only. The vertex normals of a mesh that
    :func:`visibility` has just seen come from its cache."""
    mesh = cached_mesh(vertices, triangles, add=False)
    if mesh is None:
        n = vertex_normals(vertices, triangles, weighting=weighting)
    else:
        n = mesh.normals(weighting)
    if frame == "camera":
        n = n @ vis.camera.rotation.T.astype(n.dtype)
    dtype = np.result_type(n.dtype, np.float32)
    fg = vis.matrix(len(n), dtype=dtype, foreground=True) @ n.astype(dtype, copy=False)
    norm = fg[:, 0] * fg[:, 0]
    norm += fg[:, 1] * fg[:, 1]
    norm += fg[:, 2] * fg[:, 2]
    norm += _TINY
    np.sqrt(norm, out=norm)
    out = np.zeros((vis.shape[0] * vis.shape[1], 3), dtype=dtype)
    # column by column (numpy scatters rows of 3 several times slower), normalising on the way
    for c in range(3):
        out[:, c][vis.pixels] = fg[:, c] / norm
    return out.reshape(vis.shape + (3,))


def _interpolated_normals(vertices, triangles, vis, frame, rotation, weighting, foreground=False):
    n = vertex_normals(vertices, triangles, weighting=weighting)
    if frame == "camera":
        # rotation and interpolation are linear: rotating the V vertex normals is cheaper
        # than rotating every sample
        R = camera_rotation(vis, rotation)
        if is_torch(n) and getattr(R, "ndim", 2) == 3 and n.ndim == 2:
            n = n.expand(R.shape[0], *n.shape)
        elif not is_torch(n) and np.ndim(R) == 3 and n.ndim == 2:
            n = np.broadcast_to(n, (len(R),) + n.shape)
        n = _rotate(n, R)
    return interpolate(vis, n, foreground=foreground)


def camera_rotation(vis, rotation=None):
    """The world -> camera rotation(s) of a visibility (list: stacked (B, 3, 3)), unless
    ``rotation`` overrides it."""
    if rotation is not None:
        return rotation
    if isinstance(vis, (list, tuple)):
        return np.stack([v.camera.rotation for v in vis])
    return vis.camera.rotation


def sample_normals(vertices, triangles, vis, frame="camera", rotation=None, weighting="area",
                   foreground=False):
    """Unit normals on the sample grid of ``vis`` (no downsampling), zero on background.

    ``vertices`` (V, 3) numpy or torch (V, 3) / (B, V, 3); ``triangles`` (F, 3) numpy or
    tensor; returns (Hs, Ws, 3) or (B, Hs, Ws, 3); with ``foreground=True`` only the samples
    ``vis.pixels``: (N, 3) or (B, N, 3).
    """
    n = _interpolated_normals(vertices, triangles, vis, frame, rotation, weighting, foreground)
    if foreground:
        mask = np.ones(n.shape[:-1], dtype=bool)
    else:
        mask = np.stack([v.mask for v in vis]) if isinstance(vis, (list, tuple)) else vis.mask
    return _normalize(n, mask)


def uv_layout(model_or_mesh):
    """(triangles (F, 3), uv (T, 2), triangle_uv (F, 3) or None, reference vertices (V, 3))
    of a MorphableModel, a trimesh.Trimesh with UVs, or a tuple (triangles, uv,
    triangle_uv[, vertices])."""
    from ..model import MorphableModel

    if isinstance(model_or_mesh, MorphableModel):
        m = model_or_mesh
        if m.uv is None:
            raise InputError(f"{m.name}: the model has no UV coordinates")
        return m.triangles, m.uv, m.triangle_uv, m.mean
    if isinstance(model_or_mesh, tuple) and len(model_or_mesh) in (3, 4):
        t, uv, tuv = model_or_mesh[:3]
        ref = model_or_mesh[3] if len(model_or_mesh) == 4 else None
        return np.asarray(t, dtype=np.int64), np.asarray(uv, dtype=np.float64), tuv, ref
    uv = getattr(getattr(model_or_mesh, "visual", None), "uv", None)
    if hasattr(model_or_mesh, "faces") and uv is not None:
        return (np.asarray(model_or_mesh.faces, dtype=np.int64), np.asarray(uv, dtype=np.float64),
                None, np.asarray(model_or_mesh.vertices))
    raise InputError(f"cannot take a UV layout from {type(model_or_mesh).__name__} "
                     "(a model, a mesh with UVs, or (triangles, uv, triangle_uv) are needed)")


def tangent_frames(vertices, triangles, uv, triangle_uv=None):
    """Per-UV-corner tangent and bitangent directions from the UV parametrisation.

    Parameters
    ----------
    vertices : (V, 3) mm; triangles : (F, 3); uv : (T, 2), v up; triangle_uv : (F, 3) or None

    Returns
    -------
    tangent, bitangent : (T, 3) float64, the (unnormalised, area-weighted) directions of
    increasing u and v on the surface, summed over the triangles that share each UV corner
    (so mirrored UV islands keep their own handedness).
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    tuv = t if triangle_uv is None else np.asarray(triangle_uv, dtype=np.int64)
    p = v[t]
    q = np.asarray(uv, dtype=np.float64)[tuv]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    # dp/du and dp/dv times det; multiplying by sign(det) instead of dividing by det keeps
    # UV-degenerate triangles finite (they add nothing) and weights by area
    sgn = np.sign(det)[:, None]
    tan = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * sgn
    bit = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * sgn
    T = np.zeros((len(uv), 3))
    B = np.zeros((len(uv), 3))
    for k in range(3):
        np.add.at(T, tuv[:, k], tan)
        np.add.at(B, tuv[:, k], bit)
    return T, B


def layout_faces(model_or_mesh) -> np.ndarray:
    """(F,) bool: the triangles that one map of the UV layout holds — for a model with a
    ``"face"`` segment (ICT) only that segment's, since its eyes and mouth interior share the
    face's UV tile; else all of them.

    >>> import morphable
    >>> int(layout_faces(morphable.load_model("sfm")).sum())
    6736
    """
    from ..model import MorphableModel

    triangles = np.asarray(uv_layout(model_or_mesh)[0], dtype=np.int64)
    if not (isinstance(model_or_mesh, MorphableModel) and "face" in model_or_mesh.segments):
        return np.ones(len(triangles), dtype=bool)
    inside = np.zeros(model_or_mesh.n_vertices, dtype=bool)
    inside[model_or_mesh.segments["face"]] = True
    return inside[triangles].all(1)


def _select_faces(model_or_mesh, triangles, triangle_uv, faces):
    from ..model import MorphableModel

    if faces is None:
        if not (isinstance(model_or_mesh, MorphableModel) and "face" in model_or_mesh.segments):
            return triangles, triangle_uv
        faces = layout_faces(model_or_mesh)
    faces = np.asarray(faces)
    if faces.dtype == bool and faces.shape != (len(triangles),):
        raise InputError(f"faces mask must have {len(triangles)} entries, got {faces.shape}")
    if faces.dtype != bool and (faces.dtype.kind not in "iu" or faces.ndim != 1
                                or (faces.size and (faces.min() < 0 or faces.max() >= len(triangles)))):
        raise InputError(f"faces must be a bool mask or triangle ids in [0, {len(triangles)})")
    sel = np.asarray(triangles)[faces]
    return sel, None if triangle_uv is None else np.asarray(triangle_uv)[faces]


def _all_triangles(model_or_mesh):
    """Every triangle of the mesh (vertex normals need all of them, not only the baked ones)."""
    return np.asarray(uv_layout(model_or_mesh)[0], dtype=np.int64)


def uv_normal_map(model_or_mesh, vertices=None, size: int = 256, tangent: bool = False,
                  base=None, weighting: str = "area", faces=None):
    """Bake vertex normals into a UV layout.

    Parameters
    ----------
    model_or_mesh : MorphableModel, trimesh.Trimesh with UVs, or (triangles, uv, triangle_uv)
        Gives the triangles and the UV layout; the texel table is computed once per layout
        and size and cached.
    vertices : (V, 3) float mm, torch (V, 3) / (B, V, 3), or None (the model's mean / the
        mesh's own vertices)
    size : int
        Output is size x size; row 0 is v = 1 (image convention, v up).
    tangent : bool
        False: world-frame normals. True: tangent-space normals (x along +u, y along +v,
        z along the base surface normal) relative to the surface ``base``.
    base : (V, 3) float mm or None
        Surface whose tangent frames are used (default: the model's mean / mesh vertices).
        Baking ``vertices == base`` gives (0, 0, 1) everywhere.
    weighting : {"area", "angle"}
    faces : (F,) bool mask or (n,) triangle ids, or None
        Triangles to bake (normals still come from the whole mesh). Default: all, except for
        a model with a ``"face"`` segment (ICT), where only triangles of that segment are
        baked, because the eyes and the mouth interior share its UV tile.

    Returns
    -------
    (size, size, 3) array (or torch (..., size, size, 3)): unit vectors, zero outside the
    layout.

    Examples
    --------
    >>> sq = np.array([[0., 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]])
    >>> layout = ([[0, 1, 2], [0, 2, 3]], sq[:, :2] / 10, None)
    >>> m = uv_normal_map(layout, sq, size=4)
    >>> float(m[..., 2].min()), m.shape
    (1.0, (4, 4, 3))
    """
    triangles, uv, triangle_uv, ref = uv_layout(model_or_mesh)
    if vertices is None:
        if ref is None:
            raise InputError("uv_normal_map needs vertices for a (triangles, uv, triangle_uv) "
                             "layout")
        vertices = ref
    triangles, triangle_uv = _select_faces(model_or_mesh, triangles, triangle_uv, faces)
    table = uv_visibility(triangles, uv, triangle_uv, size)
    torch_in = is_torch(vertices)
    if torch_in:
        import torch

        if not torch.isfinite(vertices).all():
            raise InputError("vertices contain NaN or inf")
        all_tri = torch.as_tensor(_all_triangles(model_or_mesh), device=vertices.device)
    else:
        all_tri = _all_triangles(model_or_mesh)
        vertices, _ = check_mesh(vertices, all_tri)
    n = _normalize(interpolate(table, vertex_normals(vertices, all_tri, weighting=weighting)),
                   table.mask)
    if not tangent:
        return n
    b = ref if base is None else base
    if b is None:
        raise InputError("tangent space needs a base surface (base=...)")
    b, _ = check_mesh(b, _all_triangles(model_or_mesh), what="base")
    if len(b) != (vertices.shape[-2]):
        raise InputError(f"base has {len(b)} vertices, the mesh {vertices.shape[-2]}")
    T, B = tangent_frames(b, table.triangles, uv, triangle_uv)
    tuv = table.triangles if triangle_uv is None else triangle_uv
    N = _normalize(interpolate(table, vertex_normals(b, _all_triangles(model_or_mesh),
                                                     weighting=weighting)), table.mask)
    Tt = interpolate(table, T, tuv)
    Bt = interpolate(table, B, tuv)
    # Gram-Schmidt: tangent orthogonal to the normal, bitangent completing a frame whose
    # handedness follows the UV layout (mirrored islands flip it)
    Tt = _normalize(Tt - (Tt * N).sum(-1, keepdims=True) * N, table.mask)
    hand = np.where((np.cross(N, Tt) * Bt).sum(-1, keepdims=True) < 0, -1.0, 1.0)
    Bt = hand * np.cross(N, Tt)
    frame = np.stack([Tt, Bt, N], -2)  # (S, S, 3, 3), rows = tangent axes in world coords
    if torch_in:
        frame = torch.as_tensor(frame, dtype=n.dtype, device=n.device)
    return (frame * n[..., None, :]).sum(-1)
