"""Landmark schemes: a set of L landmarks defined on one model's surface.

A scheme says, for each of its L landmarks, which point of the model's surface it is (a triangle
of model vertices and barycentric weights), which landmarks lie on the face's outline and slide
along it in a fit (the jaw points of iBUG-68, the face-oval points of mediapipe's face mesh), how
well each point is defined (its definition error, mm) and which point is its mirror image.

Two schemes exist for any model: ``"ibug68"`` (from the model's own ``landmark_ids``) and
``"facemesh478"`` (mediapipe's 478 face-mesh points, in mediapipe's order: 468 mesh points, then
the two irises' 5 points each), read from a sidecar file: committed for SFM and ICT FaceKit in
``morphable/data/``, beside the model's file (or in the user cache) for any other model.

>>> from morphable import load_model
>>> model = load_model("sfm")
>>> ibug68_scheme(model).points(model.mean).shape
(68, 3)
>>> fit_scheme(model, 478).points(model.mean).shape
(478, 3)
"""
from __future__ import annotations

import dataclasses
import hashlib
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..ibug68 import JAW, MIRROR
from .noise import DEFINITION_STD_MM

__all__ = ["LandmarkScheme", "ibug68_scheme", "ibug68_3d_scheme", "load_scheme", "save_scheme", "scheme_path",
           "model_fingerprint", "fit_scheme", "SCHEME_NAMES", "SCHEME_SIZES", "DATA_DIR"]

SCHEME_NAMES = ("ibug68", "facemesh478")

SCHEME_SIZES = {68: "ibug68", 478: "facemesh478"}
"""The scheme a fit takes for a number of given landmarks when none is named."""

DATA_DIR = Path(__file__).resolve().parent.parent / "data"
"""The committed sidecars (``facemesh478_<model>.npz``)."""

_CHIN = 8


@dataclass(frozen=True, eq=False)
class LandmarkScheme:
    """L landmarks on one model's surface.

    Attributes
    ----------
    name : str
        ``"ibug68"``, ``"facemesh478"``...
    model_name : str
        The model it is defined on.
    vertices : (L, 3) int64
        Model vertex ids of the triangle holding each point; a row of -1: no fixed model point
        (a sliding point the model has no vertex for, e.g. SFM's jaw).
    barycentric : (L, 3) float64
        Weights of the three vertices, rows summing to 1.
    outline_right, outline_left : (J,) int64
        Landmarks on the subject's right / left face outline, from the top (about the height
        of the eyes) down to the chin: in a fit they slide along the model's outline.
    chin : int
        The chin landmark, -1 if none: in a fit a fixed point that ends both sides' outline.
    definition_std_mm : (L,) float64
        Per-point definition error, mm per coordinate: how far a detector's or annotator's point
        typically lies from the model point.
    mirror : (L,) int64
        Each point's mirror image.
    ibug68 : (68,) int64
        The scheme point closest in meaning to each iBUG-68 point, -1 if none.
    """

    name: str
    model_name: str
    vertices: np.ndarray
    barycentric: np.ndarray
    outline_right: np.ndarray
    outline_left: np.ndarray
    chin: int
    definition_std_mm: np.ndarray
    mirror: np.ndarray
    ibug68: np.ndarray

    def __post_init__(self):
        L = len(self.vertices)
        checks = (
            (self.vertices.shape == (L, 3), "vertices must be (L, 3)"),
            (self.barycentric.shape == (L, 3), "barycentric must be (L, 3)"),
            (np.all(np.isfinite(self.barycentric)), "barycentric weights must be finite"),
            (np.allclose(self.barycentric.sum(1), 1.0, atol=1e-6), "barycentric rows must sum to 1"),
            (self.definition_std_mm.shape == (L,), "definition_std_mm must be (L,)"),
            (self.mirror.shape == (L,) and np.all((self.mirror >= 0) & (self.mirror < L)),
             "mirror must be (L,) indices"),
            (self.ibug68.shape == (68,) and np.all(self.ibug68 < L), "ibug68 must be (68,) indices"),
        )
        for ok, what in checks:
            if not ok:
                raise InputError(f"landmark scheme {self.name!r}: {what}")

    @property
    def n(self) -> int:
        """L, the number of landmarks."""
        return len(self.vertices)

    @property
    def sliding(self) -> np.ndarray:
        """(L,) bool: landmarks that slide along the outline (the chin, which ends it, does not)."""
        s = np.zeros(self.n, bool)
        s[self.outline_right] = True
        s[self.outline_left] = True
        return s

    @property
    def defined(self) -> np.ndarray:
        """(L,) bool: landmarks with a fixed model point."""
        return self.vertices[:, 0] >= 0

    def points(self, vertices) -> np.ndarray:
        """Model points of the landmarks: ``vertices`` (V, 3) or (N, V, 3) mm -> (L, 3) or
        (N, L, 3) mm, NaN rows where a landmark has no fixed model point."""
        X = np.asarray(vertices, dtype=np.float64)
        v = np.maximum(self.vertices, 0)
        P = np.einsum("...lkc,lk->...lc", X[..., v, :], self.barycentric)
        return np.where(self.defined[:, None], P, np.nan)


def ibug68_scheme(model) -> LandmarkScheme:
    """The iBUG-68 scheme of ``model``: its ``landmark_ids`` as fixed points, the jaw points
    (0-7 and 16-9, top to chin) sliding along the outline, the chin 8 ending it,
    :data:`~morphable.fitting.noise.DEFINITION_STD_MM` as the definition error."""
    ids = np.asarray(model.landmark_ids, dtype=np.int64)
    right, left = JAW[JAW < _CHIN], JAW[JAW > _CHIN][::-1]
    return LandmarkScheme(
        name="ibug68", model_name=model.name,
        vertices=np.repeat(np.where(ids >= 0, ids, -1)[:, None], 3, 1),
        barycentric=np.tile([1.0, 0.0, 0.0], (68, 1)),
        outline_right=right, outline_left=left, chin=_CHIN,
        definition_std_mm=DEFINITION_STD_MM.copy(), mirror=np.asarray(MIRROR, dtype=np.int64),
        ibug68=np.arange(68))


def ibug68_3d_scheme(model) -> LandmarkScheme:
    """iBUG-68 in the 3D convention (AFLW2000-3D, 3DDFA, the landmark network's labels:
    every point on its own surface point, a hidden one where it projects), made once per
    model: :func:`ibug68_scheme` with the rows the model has no vertex for (SFM: the 17 jaw
    points and two inner-mouth points) at the face-mesh scheme's counterpart point
    (``LandmarkScheme.ibug68``: a fixed surface point near the jaw line). Without a face-mesh
    sidecar those rows stay undefined (a fit leaves them out)."""
    per_model = _FIT_SCHEMES.setdefault(model, {})
    if "ibug68_3d" not in per_model:
        ibug = ibug68_scheme(model)
        fill = ~ibug.defined
        if fill.any():
            try:
                mesh = per_model.get("facemesh478") or load_scheme(model, "facemesh478")
            except InputError:
                mesh = None
            if mesh is not None:
                fill &= mesh.ibug68 >= 0
                vertices, bary = ibug.vertices.copy(), ibug.barycentric.copy()
                vertices[fill] = mesh.vertices[mesh.ibug68[fill]]
                bary[fill] = mesh.barycentric[mesh.ibug68[fill]]
                ibug = dataclasses.replace(ibug, vertices=vertices, barycentric=bary)
        per_model["ibug68_3d"] = ibug
    return per_model["ibug68_3d"]


def model_fingerprint(model) -> str:
    """A short string identifying a model's topology: vertex count and sha256 of its triangles."""
    tri = np.ascontiguousarray(np.asarray(model.triangles, dtype=np.int64))
    return f"{model.n_vertices}:{hashlib.sha256(tri.tobytes()).hexdigest()[:16]}"


def scheme_path(model, name: str = "facemesh478") -> Path:
    """Where the sidecar of scheme ``name`` for ``model`` is looked for: ``morphable/data`` for a
    committed one, else beside the model's file (``<stem>.<name>.npz``)."""
    committed = DATA_DIR / f"{name}_{model.name}.npz"
    if committed.is_file():
        return committed
    src = Path(str(model.source))
    return src.with_name(f"{src.stem}.{name}.npz") if src.suffix else committed


def save_scheme(scheme: LandmarkScheme, path, model) -> Path:
    """Write ``scheme`` (defined on ``model``) to ``path`` (.npz) atomically -> the path."""
    from ..io.atomic import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, name=scheme.name, model_name=scheme.model_name,
                     model_fingerprint=model_fingerprint(model), vertices=scheme.vertices,
                     barycentric=scheme.barycentric, outline_right=scheme.outline_right,
                     outline_left=scheme.outline_left, chin=scheme.chin,
                     definition_std_mm=scheme.definition_std_mm, mirror=scheme.mirror,
                     ibug68=scheme.ibug68)
    return path


def load_scheme(model, name: str = "facemesh478", path=None) -> LandmarkScheme:
    """The landmark scheme ``name`` of ``model`` (``"ibug68"`` is built from the model; others
    are read from ``path`` or :func:`scheme_path`). InputError, naming the file, when it is
    missing, unreadable or made for another model."""
    if name == "ibug68":
        return ibug68_scheme(model)
    if name not in SCHEME_NAMES:
        raise InputError(f"landmark scheme: expected one of {', '.join(SCHEME_NAMES)}, got {name!r}")
    path = Path(path) if path is not None else scheme_path(model, name)
    if not path.is_file():
        raise InputError(f"{path}: no {name} landmark scheme for model {model.name!r} "
                         f"(build it with `python -m morphable.fitting.scheme_build --model ...`)")
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read landmark scheme ({e})") from None
    need = ("name", "model_fingerprint", "vertices", "barycentric", "outline_right", "outline_left",
            "chin", "definition_std_mm", "mirror", "ibug68")
    missing = [k for k in need if k not in d]
    if missing:
        raise InputError(f"{path}: landmark scheme lacks {', '.join(missing)}")
    if str(d["model_fingerprint"]) != model_fingerprint(model):
        raise InputError(f"{path}: landmark scheme was made for another model than {model.name!r} "
                         f"({d['model_fingerprint']} != {model_fingerprint(model)})")
    try:
        return LandmarkScheme(
            name=str(d["name"]), model_name=model.name,
            vertices=d["vertices"].astype(np.int64), barycentric=d["barycentric"].astype(np.float64),
            outline_right=d["outline_right"].astype(np.int64),
            outline_left=d["outline_left"].astype(np.int64), chin=int(d["chin"]),
            definition_std_mm=d["definition_std_mm"].astype(np.float64),
            mirror=d["mirror"].astype(np.int64), ibug68=d["ibug68"].astype(np.int64))
    except InputError as e:
        raise InputError(f"{path}: {e}") from None


# per model: the schemes fits take by landmark count (a fit's landmark rows are cached per scheme)
_FIT_SCHEMES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def fit_scheme(model, n_landmarks: int, scheme: LandmarkScheme | None = None) -> LandmarkScheme:
    """The scheme of ``n_landmarks`` given landmarks of ``model``: ``scheme`` when given, else
    by count (:data:`SCHEME_SIZES`: 68 iBUG-68, 478 the face mesh), made or read once per
    model. InputError when the count has no scheme, or ``scheme`` has another count or was
    made for another model."""
    if scheme is None:
        name = SCHEME_SIZES.get(int(n_landmarks))
        if name is None:
            raise InputError(f"landmarks: {n_landmarks} points, expected "
                             f"{' or '.join(map(str, SCHEME_SIZES))} or a landmark scheme")
        per_model = _FIT_SCHEMES.setdefault(model, {})
        if name not in per_model:
            per_model[name] = load_scheme(model, name)
        return per_model[name]
    if scheme.n != n_landmarks:
        raise InputError(f"landmarks: {n_landmarks} points for the {scheme.n}-point scheme "
                         f"{scheme.name!r}")
    if scheme.model_name != model.name or scheme.vertices.max(initial=-1) >= model.n_vertices:
        raise InputError(f"landmark scheme {scheme.name!r} was made for model "
                         f"{scheme.model_name!r}, not {model.name!r}")
    return scheme
