"""The morphable model: mean shape plus linear identity and expression bases.

One class serves every model (SFM, ICT, BFM, FLAME, native files). Coefficients are in
units of one standard deviation, so the Gaussian prior of a fit is simply ``||alpha||^2``;
the bases are stored already scaled, in millimetres per unit coefficient.
"""
from __future__ import annotations

import sys
import weakref
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError
from .threads import single_blas_thread

__all__ = ["MorphableModel", "SKIN_SEGMENTS"]

SKIN_SEGMENTS = ("face", "head_neck")
"""Segments that make up a model's outer skin, when it also holds eyeballs, teeth and a mouth
interior (ICT FaceKit)."""


def _torch_tensor(x) -> bool:
    """Whether ``x`` is a torch tensor (only possible once torch has been imported)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


# per model: its mean and bases as torch tensors, keyed by (what, modes, dtype, device), so
# that an optimisation calling the forward pass every step converts them once
_TORCH_ARRAYS = weakref.WeakKeyDictionary()


def _check_modes(shape, n_modes: int, what: str) -> None:
    if len(shape) == 0:
        raise InputError(f"{what} coefficients must be a vector (..., k), got a scalar")
    if shape[-1] > n_modes:
        raise InputError(f"{what}: {shape[-1]} coefficients given, the model has {n_modes} modes")


def _as_coefficients(coeffs, n_modes: int, what: str, dtype) -> np.ndarray | None:
    if coeffs is None:
        return None
    c = np.asarray(coeffs, dtype=dtype)
    _check_modes(c.shape, n_modes, what)
    if not np.all(np.isfinite(c)):
        raise InputError(f"{what} coefficients contain NaN or inf")
    return c


@dataclass(eq=False)
class MorphableModel:
    """A linear 3D morphable face model in millimetres.

    ``vertices = mean + identity . identity_basis + expression . expression_basis``

    Attributes
    ----------
    name : str
        Short name (``"sfm"``, ``"ict"``, a file stem...).
    mean : (V, 3) float array, mm
        Mean shape. Axes: x to the subject's left, y up, z out of the face towards a viewer.
    triangles : (F, 3) int array
        Vertex ids of each triangle, counter-clockwise seen from outside.
    identity_basis : (K, V, 3) float array, mm per unit coefficient
        Identity modes scaled by their standard deviation (coefficients ~ N(0, 1)).
    expression_basis : (E, V, 3) float array, mm per unit coefficient
        Expression modes: PCA modes scaled by std, or blendshape offsets (weights in [0, 1]).
    expression_names : list of str
        One name per expression mode (``"happiness"``, ``"jawOpen"``, ``"pc0"``...).
    expression_kind : {"blendshapes", "pca", "none"}
    landmark_ids : (68,) int array
        Vertex id of each iBUG-68 landmark (0-based landmark order), ``-1`` where the model
        has no fixed vertex (e.g. SFM's jaw contour, which moves with the pose).
    contour_right, contour_left : (C,) int arrays
        Candidate vertices of the jaw outline on the subject's right / left side, top to chin;
        empty when the model defines none.
    uv : (T, 2) float array or None
        Texture coordinates in [0, 1], v up.
    triangle_uv : (F, 3) int array or None
        Per-triangle indices into ``uv``; None means ``uv`` is per vertex (T == V).
    segments : dict of str to (n,) int arrays
        Named vertex sets (``"face"``, ``"head"``, ``"eyes"``...).
    symmetry : (V,) int array or None
        Vertex id of each vertex's mirror image.
    source : str
        Where the model was read from (for messages).

    Examples
    --------
    >>> import numpy as np
    >>> m = MorphableModel.from_arrays(
    ...     mean=np.zeros((3, 3)), triangles=[[0, 1, 2]], identity_basis=np.ones((2, 3, 3)))
    >>> m.vertices([1.0, 0.5]).shape
    (3, 3)
    >>> m.vertices(np.zeros((4, 2))).shape
    (4, 3, 3)
    """

    name: str
    mean: np.ndarray
    triangles: np.ndarray
    identity_basis: np.ndarray
    expression_basis: np.ndarray
    expression_names: list = field(default_factory=list)
    expression_kind: str = "none"
    landmark_ids: np.ndarray = field(default_factory=lambda: np.full(68, -1, dtype=np.int64))
    contour_right: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    contour_left: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    uv: np.ndarray | None = None
    triangle_uv: np.ndarray | None = None
    segments: dict = field(default_factory=dict)
    symmetry: np.ndarray | None = None
    source: str = ""

    def __post_init__(self):
        where = self.source or self.name
        V = self.mean.shape[0] if self.mean.ndim == 2 else -1
        if self.mean.ndim != 2 or self.mean.shape[1] != 3 or V == 0:
            raise InputError(f"{where}: mean shape must be (V, 3) with V > 0, got {self.mean.shape}")
        for what, basis in (("identity", self.identity_basis), ("expression", self.expression_basis)):
            if basis.ndim != 3 or basis.shape[1:] != (V, 3):
                raise InputError(f"{where}: {what} basis must be (K, {V}, 3), got {basis.shape}")
        if not (np.isfinite(self.mean).all() and np.isfinite(self.identity_basis).all()
                and np.isfinite(self.expression_basis).all()):
            raise InputError(f"{where}: model arrays contain NaN or inf")
        t = self.triangles
        if t.ndim != 2 or t.shape[1] != 3 or (t.size and (t.min() < 0 or t.max() >= V)):
            raise InputError(f"{where}: triangles must be (F, 3) vertex ids in [0, {V})")
        if len(self.expression_names) != self.expression_basis.shape[0]:
            raise InputError(f"{where}: {len(self.expression_names)} expression names for "
                             f"{self.expression_basis.shape[0]} expression modes")
        if self.landmark_ids.shape != (68,) or self.landmark_ids.max() >= V:
            raise InputError(f"{where}: landmark_ids must be 68 vertex ids (-1 for none)")
        for ids in (self.contour_left, self.contour_right, *self.segments.values()):
            if ids.size and (ids.min() < 0 or ids.max() >= V):
                raise InputError(f"{where}: contour or segment vertex id out of range [0, {V})")
        if self.uv is not None:
            if self.uv.ndim != 2 or self.uv.shape[1] != 2:
                raise InputError(f"{where}: uv must be (T, 2), got {self.uv.shape}")
            if self.triangle_uv is None and len(self.uv) != V:
                raise InputError(f"{where}: per-vertex uv needs {V} rows, got {len(self.uv)}")
            if self.triangle_uv is not None and (self.triangle_uv.shape != t.shape
                                                 or self.triangle_uv.max() >= len(self.uv)):
                raise InputError(f"{where}: triangle_uv must be {t.shape} ids into uv")

    @classmethod
    def from_arrays(cls, mean, triangles, identity_basis=None, expression_basis=None, **kwargs):
        """Build a model from array-likes; missing bases become empty (0, V, 3).

        Parameters
        ----------
        mean : (V, 3) array-like, mm
        triangles : (F, 3) array-like of int
        identity_basis, expression_basis : (K, V, 3) array-like, mm per unit coefficient
        **kwargs
            Any other attribute (``name`` defaults to ``"model"``).
        """
        mean = np.asarray(mean)
        if mean.dtype.kind != "f":
            mean = mean.astype(np.float64)
        V = mean.shape[0] if mean.ndim == 2 else 0
        empty = np.zeros((0, V, 3), dtype=mean.dtype)
        ib = empty if identity_basis is None else np.asarray(identity_basis, dtype=mean.dtype)
        eb = empty if expression_basis is None else np.asarray(expression_basis, dtype=mean.dtype)
        kwargs.setdefault("name", "model")
        if "expression_names" not in kwargs:
            kwargs["expression_names"] = [f"e{i}" for i in range(eb.shape[0])]
        if eb.shape[0] and "expression_kind" not in kwargs:
            kwargs["expression_kind"] = "pca"
        for key in ("landmark_ids", "contour_right", "contour_left", "symmetry", "triangle_uv"):
            if kwargs.get(key) is not None:
                kwargs[key] = np.asarray(kwargs[key], dtype=np.int64)
        if kwargs.get("uv") is not None:
            kwargs["uv"] = np.asarray(kwargs["uv"], dtype=np.float64)
        if "segments" in kwargs:
            kwargs["segments"] = {k: np.asarray(v, dtype=np.int64) for k, v in kwargs["segments"].items()}
        return cls(mean=mean, triangles=np.asarray(triangles, dtype=np.int64).reshape(-1, 3),
                   identity_basis=ib, expression_basis=eb, **kwargs)

    # --- sizes ------------------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        return self.mean.shape[0]

    @property
    def n_triangles(self) -> int:
        return self.triangles.shape[0]

    @property
    def n_identity(self) -> int:
        return self.identity_basis.shape[0]

    @property
    def n_expression(self) -> int:
        return self.expression_basis.shape[0]

    @property
    def identity_std(self) -> np.ndarray:
        """(K,) mm: the standard deviation of each identity mode (norm of its scaled mode)."""
        return np.linalg.norm(self.identity_basis.reshape(self.n_identity, -1), axis=1)

    @property
    def units(self) -> str:
        return "mm"

    def info(self) -> dict:
        """A JSON-ready summary: name, sizes, units, landmark count."""
        return {
            "name": self.name,
            "source": self.source,
            "n_vertices": self.n_vertices,
            "n_triangles": self.n_triangles,
            "n_identity": self.n_identity,
            "n_expression": self.n_expression,
            "expression_kind": self.expression_kind,
            "expression_names": list(self.expression_names),
            "units": self.units,
            "n_landmarks": int((self.landmark_ids >= 0).sum()),
            "n_contour": [int(self.contour_right.size), int(self.contour_left.size)],
            "has_uv": self.uv is not None,
            "segments": sorted(self.segments),
        }

    def expression_index(self, name: str) -> int:
        """Index of the expression mode called ``name`` (InputError listing the names if unknown)."""
        try:
            return list(self.expression_names).index(name)
        except ValueError:
            raise InputError(f"{self.name}: no expression {name!r}; choose from "
                             f"{', '.join(self.expression_names) or '(none)'}") from None

    def skin_vertices(self) -> np.ndarray:
        """(n,) int, sorted: the vertices of the outer skin, what a scan of the face can be
        compared with — the :data:`SKIN_SEGMENTS` the model names (ICT: not its eyeballs,
        teeth, gums or mouth interior), else every vertex.

        >>> m = MorphableModel.from_arrays(mean=np.zeros((4, 3)), triangles=[[0, 1, 2]],
        ...                                segments={"face": [0, 1], "teeth": [2, 3]})
        >>> m.skin_vertices()
        array([0, 1])
        """
        skin = [self.segments[k] for k in SKIN_SEGMENTS if k in self.segments]
        return np.unique(np.concatenate(skin)) if skin else np.arange(self.n_vertices)

    # --- evaluation -------------------------------------------------------------------
    def vertices(self, identity=None, expression=None, dtype=np.float64) -> np.ndarray:
        """Vertex positions for the given coefficients.

        Parameters
        ----------
        identity : (..., k) array-like, k <= n_identity, or None
            Identity coefficients in units of std; the first k modes are used, None is the mean.
        expression : (..., e) array-like, e <= n_expression, or None
            Expression coefficients (blendshape weights or PCA coefficients).
        dtype : numpy dtype
            float64 (default) or float32; the computation runs in this type.

        Returns
        -------
        (..., V, 3) array, mm; the leading dimensions broadcast between ``identity``
        and ``expression``.

        Torch tensors in (either coefficient, batch first) give a torch tensor out, in the
        first tensor's dtype and device and differentiable in the coefficients: the forward
        pass of photometric refinement (:mod:`morphable.refinement`). ``dtype`` is then
        ignored, and the coefficients are not checked for NaN (they are optimisation
        variables; the optimiser checks its loss). The model's arrays are converted once per
        dtype and device and kept with the model, which must then not be changed in place.

        >>> import torch
        >>> m = MorphableModel.from_arrays(mean=np.zeros((3, 3)), triangles=[[0, 1, 2]],
        ...                                identity_basis=np.ones((2, 3, 3)))
        >>> a = torch.tensor([[1.0, 0.5]], requires_grad=True)
        >>> v = m.vertices(a)
        >>> v.shape, v.requires_grad, bool((v == 1.5).all())
        (torch.Size([1, 3, 3]), True, True)
        """
        if _torch_tensor(identity) or _torch_tensor(expression):
            return self._evaluate_torch(identity, expression)
        # one BLAS thread: the whole mesh is a GEMV (or a thin GEMM) that two threads ran 7x
        # slower (SFM, 2 cores), and whose idle threads spin against other work afterwards
        with single_blas_thread():
            return self._evaluate(slice(None), identity, expression, dtype)

    def vertices_at(self, ids, identity=None, expression=None, dtype=np.float64) -> np.ndarray:
        """Vertex positions of the rows ``ids`` only (never builds the whole mesh).

        Parameters
        ----------
        ids : (n,) int array-like
            Vertex ids (may repeat).
        identity, expression, dtype
            As in :meth:`vertices`.

        Returns
        -------
        (..., n, 3) array, mm.
        """
        ids = np.asarray(ids, dtype=np.int64)
        if ids.ndim != 1 or (ids.size and (ids.min() < 0 or ids.max() >= self.n_vertices)):
            raise InputError(f"{self.name}: vertex ids must be a vector in [0, {self.n_vertices})")
        return self._evaluate(ids, identity, expression, dtype)

    def _evaluate(self, rows, identity, expression, dtype) -> np.ndarray:
        dtype = np.dtype(dtype)
        a = _as_coefficients(identity, self.n_identity, "identity", dtype)
        b = _as_coefficients(expression, self.n_expression, "expression", dtype)
        out = self.mean[rows].astype(dtype)
        n = out.shape[0]
        for c, basis in ((a, self.identity_basis), (b, self.expression_basis)):
            if c is None or c.shape[-1] == 0:
                continue
            k = c.shape[-1]
            # one GEMM over the requested rows only: (..., k) @ (k, n*3)
            B = basis[:k, rows].reshape(k, n * 3).astype(dtype, copy=False)
            out = out + (c @ B).reshape(*c.shape[:-1], n, 3)
        return out

    def _evaluate_torch(self, identity, expression):
        like = identity if _torch_tensor(identity) else expression
        coeffs = []
        for c, what, n_modes in ((identity, "identity", self.n_identity),
                                 (expression, "expression", self.n_expression)):
            if c is not None:
                c = like.new_tensor(c) if not _torch_tensor(c) else c.to(like.dtype)
                _check_modes(c.shape, n_modes, what)
            coeffs.append(c)
        out = self._torch_array("mean", 0, like)
        for c, what in zip(coeffs, ("identity", "expression")):
            if c is not None and c.shape[-1]:
                # (..., k) @ (k, V*3): the first k modes
                out = out + c @ self._torch_array(what, c.shape[-1], like)
        return out.reshape(*out.shape[:-1], self.n_vertices, 3)

    def _torch_array(self, what: str, k: int, like):
        """The mean (V*3,) or the first ``k`` modes of a basis (k, V*3) as a tensor like ``like``."""
        import torch

        cache = _TORCH_ARRAYS.setdefault(self, {})
        key = (what, k, like.dtype, like.device)
        if key not in cache:
            a = self.mean.reshape(-1) if what == "mean" else \
                getattr(self, f"{what}_basis")[:k].reshape(k, -1)
            cache[key] = torch.tensor(np.asarray(a), dtype=like.dtype, device=like.device)
        return cache[key]

    def sample(self, rng=None, identity_std: float = 1.0, expression=None, n_identity=None):
        """Random identity coefficients (and the given expression) -> vertices.

        Parameters
        ----------
        rng : numpy Generator or int seed
        identity_std : float
            Standard deviation of the sampled coefficients (1 = the model's own spread).
        expression : (E,) array-like or None
        n_identity : int or None
            Sample only the first modes.

        Returns
        -------
        vertices : (V, 3) float64, mm
        identity : (K,) float64
        """
        rng = np.random.default_rng(rng)
        k = self.n_identity if n_identity is None else min(n_identity, self.n_identity)
        alpha = rng.standard_normal(k) * identity_std
        return self.vertices(alpha, expression), alpha

    def landmark_positions(self, identity=None, expression=None, dtype=np.float64):
        """(..., 68, 3) mm positions of the fixed iBUG-68 landmarks, NaN where undefined."""
        ids = self.landmark_ids
        ok = ids >= 0
        pts = self.vertices_at(ids[ok], identity, expression, dtype)
        out = np.full(pts.shape[:-2] + (68, 3), np.nan, dtype=pts.dtype)
        out[..., ok, :] = pts
        return out
