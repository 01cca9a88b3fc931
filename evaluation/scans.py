"""Ground-truth scans for the Florence protocol: mesh, units and landmarks in iBUG order.

A scan is any OBJ/PLY/STL (textured or not) in any units; its landmarks are 68 iBUG points
or the 51 inner ones (iBUG 18-68) in menpo ``.ljson``, ``.npy``/``.txt`` (N x 3) or a
three-column ``.pts``. Units are given or detected from the inter-ocular distance.

Examples
--------
>>> scan = load_scan("../shared/data/scans/james/james.obj",
...                  "../shared/data/scans/james/james.ljson")
>>> scan.units, round(scan.interocular_mm)
('mm', 67)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from morphable.errors import InputError
from morphable.ibug68 import GROUPS, INNER, N_LANDMARKS, from_menpo_labels
from morphable.metrics import submesh

__all__ = ["Scan", "load_scan", "read_scan_landmarks", "detect_units", "interocular",
           "model_scan", "photo_colors", "UNITS", "TYPICAL_INTEROCULAR_MM"]

UNITS = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
"""Millimetres per unit."""
TYPICAL_INTEROCULAR_MM = 63.0
"""Adult distance between the eye centres (about 60-65 mm), used to detect units."""


@dataclass
class Scan:
    """A face scan in millimetres.

    Attributes
    ----------
    vertices : (S, 3) float64, mm
    triangles : (G, 3) int64
    landmarks : (68, 3) float64, mm, iBUG order, NaN rows where not given
    units : str — the file's units (``mm``, ``cm``, ``m``), given or detected
    source : str — the mesh path
    uv : (T, 2) float64 texture coordinates in [0, 1] (v up) or None
    triangle_uv : (G, 3) int64 ids into ``uv`` per triangle corner, or None (``uv`` per vertex)
    texture : (H, W, 3) float64 in [0, 1] or None
    colors : (S, 3) float64 in [0, 1], a colour per vertex (used where there is no texture), or None
    """

    vertices: np.ndarray
    triangles: np.ndarray
    landmarks: np.ndarray
    units: str = "mm"
    source: str = ""
    uv: np.ndarray | None = None
    triangle_uv: np.ndarray | None = None
    texture: np.ndarray | None = None
    colors: np.ndarray | None = None

    @property
    def nose_tip(self) -> np.ndarray:
        """(3,) mm, iBUG point 31."""
        return self.landmarks[30]

    @property
    def interocular_mm(self) -> float:
        return interocular(self.landmarks)


def interocular(landmarks) -> float:
    """Distance between the two eye centres (means of iBUG 37-42 and 43-48), in the
    landmarks' units."""
    lm = np.asarray(landmarks, dtype=np.float64)
    right = np.nanmean(lm[GROUPS["right_eye"]], 0)
    left = np.nanmean(lm[GROUPS["left_eye"]], 0)
    return float(np.linalg.norm(left - right))


def detect_units(landmarks, source: str = "scan") -> str:
    """The unit (``mm``, ``cm`` or ``m``) that makes the inter-ocular distance closest to
    63 mm.

    >>> detect_units(np.r_[np.zeros((36, 3)), np.tile([[0.0, 0, 0]], (6, 1)),
    ...                    np.tile([[0.064, 0, 0]], (6, 1)), np.zeros((20, 3))])
    'm'
    """
    d = interocular(landmarks)
    if not np.isfinite(d) or d <= 0:
        raise InputError(f"{source}: cannot detect units: the eye landmarks are missing or coincide")
    name = min(UNITS, key=lambda u: abs(np.log(d * UNITS[u] / TYPICAL_INTEROCULAR_MM)))
    mm = d * UNITS[name]
    if not 35.0 <= mm <= 110.0:
        raise InputError(f"{source}: cannot detect units: inter-ocular distance {d:.4g} is not "
                         f"that of a face in mm, cm or m; pass --scan-units")
    return name


def _read_pts3(path: Path) -> np.ndarray:
    text = path.read_text()
    head, _, rest = text.partition("{")
    body, close, _ = rest.partition("}")
    if not close:
        raise InputError(f"{path}: not a .pts file (no {{ ... }} block)")
    return np.array([[float(x) for x in ln.split()] for ln in body.splitlines() if ln.strip()])


def read_scan_landmarks(path) -> np.ndarray:
    """Read 3D scan landmarks -> (68, 3) float64 in iBUG order, NaN rows where missing.

    68 points are taken in iBUG order, 51 as the inner points (iBUG 18-68); a menpo
    ``.ljson`` with labels (``chin``, ``leye``, ...) is reordered by its label groups.
    Units are those of the file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such landmark file")
    suffix = path.suffix.lower()
    labels = None
    try:
        if suffix == ".ljson":
            from morphable.io.landmark_files import read_ljson

            pts, labels = read_ljson(path)
        elif suffix == ".npy":
            pts = np.load(path, allow_pickle=False)
        elif suffix == ".txt":
            pts = np.loadtxt(path, ndmin=2)
        elif suffix == ".pts":
            pts = _read_pts3(path)
        else:
            raise InputError(f"{path}: unknown landmark format {suffix!r} (.ljson .npy .txt .pts)")
    except (OSError, ValueError, UnicodeDecodeError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError(f"{path}: cannot read landmarks ({type(e).__name__}: {e})") from None
    pts = np.asarray(pts, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"{path}: expected N x 3 landmarks, got shape {pts.shape}")
    if labels and len(pts) == N_LANDMARKS and len(labels) > 1:
        return from_menpo_labels(pts, labels, source=str(path))
    if len(pts) == N_LANDMARKS:
        return pts
    if len(pts) == len(INNER):
        out = np.full((N_LANDMARKS, 3), np.nan)
        out[INNER] = pts
        return out
    raise InputError(f"{path}: expected 68 or 51 landmarks, got {len(pts)}")


def load_scan(path, landmarks, units: str = "auto") -> Scan:
    """Load a scan and its landmarks, converted to millimetres.

    Parameters
    ----------
    path : OBJ, PLY, STL... (anything trimesh reads)
    landmarks : path of the landmark file (see :func:`read_scan_landmarks`) or a (68, 3) array
    units : ``"mm"``, ``"cm"``, ``"m"`` or ``"auto"`` (from the inter-ocular distance)

    Returns
    -------
    Scan in mm; unreferenced vertices are kept (they do not affect any metric).
    """
    from morphable.io.mesh import read_mesh

    mesh = read_mesh(path)
    lm = (read_scan_landmarks(landmarks) if isinstance(landmarks, (str, Path))
          else np.asarray(landmarks, dtype=np.float64))
    where = str(landmarks) if isinstance(landmarks, (str, Path)) else f"{path} landmarks"
    if lm.shape != (N_LANDMARKS, 3):
        raise InputError(f"{where}: expected (68, 3) landmarks, got {lm.shape}")
    if np.isnan(lm[30]).any():
        raise InputError(f"{where}: the nose tip (iBUG 31) is missing; the crop needs it")
    if units == "auto":
        units = detect_units(lm, source=where)
    if units not in UNITS:
        raise InputError(f"{path}: unknown units {units!r} (mm, cm, m or auto)")
    k = UNITS[units]
    iod = interocular(lm) * k
    if np.isfinite(iod) and not 35.0 <= iod <= 110.0:
        raise InputError(f"{where}: in {units} the inter-ocular distance is {iod:.4g} mm, not a "
                         f"face's (about 63 mm); check --scan-units (or use auto)")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.faces, dtype=np.int64)
    uv = triangle_uv = texture = None
    visual = getattr(mesh, "visual", None)
    image = getattr(getattr(visual, "material", None), "image", None)
    if image is not None:
        texture = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
        if Path(path).suffix.lower() == ".obj":
            from morphable.io.obj import read_obj

            # trimesh gives one UV per vertex, wrong along seams: take the file's UV indexing
            obj = read_obj(path)
            if obj.triangle_uv is not None and obj.triangles.shape == triangles.shape:
                vertices, triangles = obj.vertices, obj.triangles
                uv, triangle_uv = obj.uv, obj.triangle_uv
        if uv is None and getattr(visual, "uv", None) is not None and len(visual.uv) == len(vertices):
            uv = np.asarray(visual.uv, dtype=np.float64)
        if uv is None:
            texture = None
    colors = None
    if texture is None and getattr(visual, "kind", None) == "vertex":
        # a PLY with per-vertex colours: they dress the scan in rendered frames
        c = np.asarray(visual.vertex_colors)
        if c.shape[0] == len(vertices):
            colors = c[:, :3].astype(np.float64) / 255.0
    return Scan(vertices=vertices * k, triangles=triangles, landmarks=lm * k, units=units,
                source=str(path), uv=uv, triangle_uv=triangle_uv, texture=texture, colors=colors)


def model_scan(model, rng=None, identity_std: float = 1.0, expression_std: float = 0.0,
               segment: str = "face", definition_mm: float = 0.0, colors=None) -> Scan:
    """A "scan" sampled from a morphable model: a validation subject that is not a real scan.

    Sampled from a model other than the one being fitted (e.g. ICT FaceKit for SFM fits),
    its landmarks are that model's own iBUG-68 vertices, so they differ from the fitted
    model's landmark definition the way a real scan's annotation does. Sampled from the fitted
    model itself, ``definition_mm`` gives its landmarks such a difference: one fixed 3D offset
    per landmark, N(0, definition_mm^2) per coordinate, and jaw points moved along the jaw line
    by N(0, (2 definition_mm)^2) mm.

    Parameters
    ----------
    model : MorphableModel whose landmarks are defined (all but at most 4; SFM lacks the inner
        mouth corners): by ``landmark_ids``, or for the jaw by its contour (SFM: jaw points
        spaced along the jaw line from the height of the outer eye corners to the chin,
        :func:`morphable.fitting.synthetic.expected_jaw_points`)
    rng : numpy Generator or int seed
    identity_std : standard deviation of the identity coefficients (1 = the model's spread)
    expression_std : blendshape weights ``|N(0, expression_std)|`` (clipped to 1), or PCA
        coefficients ``N(0, expression_std)``; 0 = neutral
    segment : the model segment kept as the scan surface (the whole mesh when the model has
        no such segment); the landmarks need not lie on it
    definition_mm : landmark definition error added to the model's own landmarks, mm
    colors : (V, 3) in [0, 1] per model vertex, or None: the subject's skin in rendered frames
        (:func:`photo_colors` gives a photo's; None renders it untextured grey)

    Returns
    -------
    Scan in mm, ``source`` naming the model and the coefficients' seed.

    Examples
    --------
    >>> from morphable import load_model
    >>> scan = model_scan(load_model("ict"), rng=0)
    >>> scan.landmarks.shape, round(scan.interocular_mm, 1)
    ((68, 3), 62.4)
    """
    seed = rng if isinstance(rng, (int, np.integer)) else None
    rng = np.random.default_rng(rng)
    alpha = rng.standard_normal(model.n_identity) * identity_std
    beta = None
    if expression_std > 0 and model.n_expression:
        beta = rng.standard_normal(model.n_expression) * expression_std
        if model.expression_kind == "blendshapes":
            beta = np.clip(np.abs(beta), 0.0, 1.0)
    vertices = model.vertices(alpha, beta)
    landmarks = model.landmark_positions(alpha, beta)
    jaw_arc = rng.normal(0.0, 2.0 * definition_mm, 68) if definition_mm > 0 else np.zeros(68)
    _jaw_on_contour(model, vertices, landmarks, jaw_arc)
    defined = np.isfinite(landmarks).all(1)
    if not defined[:17].all() or defined.sum() < 64:
        raise InputError(f"model {model.name}: {int((~defined).sum())} iBUG-68 landmarks are "
                         f"undefined; a model scan needs the jaw and at least 64 in all")
    if definition_mm > 0:
        inner = np.r_[8, np.arange(17, 68)]
        landmarks[inner] += rng.normal(0.0, definition_mm, (len(inner), 3))
    keep = np.ones(model.n_vertices, dtype=bool)
    if segment in (model.segments or {}):
        keep[:] = False
        keep[model.segments[segment]] = True
    # only the surface's vertices: silhouettes and visibility must not see eyeballs or teeth
    ids, triangles = submesh(model.triangles, keep)
    source = f"{model.name} sample (seed {seed})"
    if definition_mm > 0:
        source += f", landmark definition error {definition_mm:g} mm"
    if colors is not None:
        colors = np.asarray(colors, dtype=np.float64)
        if colors.shape != (model.n_vertices, 3):
            raise InputError(f"model {model.name}: colors must be ({model.n_vertices}, 3), got "
                             f"{colors.shape}")
        colors = colors[ids]
    return Scan(vertices=vertices[ids], triangles=triangles, landmarks=landmarks,
                units="mm", source=source, colors=colors)


def photo_colors(model, photo, landmarks=None) -> np.ndarray:
    """A model's vertex colours taken from a photo of a face -> (V, 3) in [0, 1].

    The model is fitted to the photo's landmarks (``landmarks``: a landmark file; default the
    ``.pts`` beside the photo, else detected by :mod:`morphable.detection`'s default) and each
    vertex takes the colour the fit's camera sees (:func:`morphable.raster.vertex_colors`; hidden ones their mirror's or the median).
    Any subject of the model (:func:`model_scan`) then wears that face's skin, brows, eyes
    and lips where the model puts them, so that a detector run on its rendered frames sees a
    face, not shaded clay.

    Examples
    --------
    >>> from morphable import load_model
    >>> ict = load_model("ict")
    >>> colors = photo_colors(ict, "../shared/data/images/image_0010.png")
    >>> colors.shape, bool(colors.min() >= 0 and colors.max() <= 1)
    ((26719, 3), True)
    >>> scan = model_scan(ict, 100, colors=colors)          # the face segment, wearing them
    >>> scan.colors.shape == scan.vertices.shape
    True
    """
    from morphable.pipeline import fit_images
    from morphable.raster import vertex_colors

    photo = Path(photo)
    if landmarks is None and photo.with_suffix(".pts").is_file():
        landmarks = photo.with_suffix(".pts")
    res = fit_images(photo, landmarks, model=model).fit
    try:
        colors, _ = vertex_colors(res.vertices(0), model.triangles, res.cameras[0], photo,
                                  model.symmetry)
    except InputError as e:
        raise InputError(f"{photo}: {e}") from None
    return colors


def _jaw_on_contour(model, vertices, landmarks, arc_offset):
    """Fill undefined jaw landmarks (in place) from the model's jaw contour: evenly spaced
    along the subject's jaw line as the mean face expects them, moved by ``arc_offset`` mm."""
    if not np.isnan(landmarks[:17]).any():
        return
    from morphable.fitting.correspondences import eye_corner_height, interpolate_arc, landmark_bank
    from morphable.fitting.synthetic import jaw_arc_positions

    bank = landmark_bank(model)
    eye_y = eye_corner_height(model, bank.scheme)
    for lms, chain in bank.polylines:
        P, arc, at = jaw_arc_positions(model, lms, bank.vertex_ids[chain], vertices, eye_y)
        at = np.clip(at + arc_offset[lms], 0.0, arc[-1])
        fill = np.isnan(landmarks[lms]).any(1)
        landmarks[lms[fill]] = interpolate_arc(P, arc, at)[fill]

