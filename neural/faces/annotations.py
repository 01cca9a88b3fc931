"""Sparse annotations of real photos as rows of the landmark network's 546 points
(:mod:`neural.faces.points`), the readers of the annotated sets under ``../shared/data``, model
fits to them, and the square face crops of the landmark packs.

Sets (licences: docs/landmark_packs.md):

- ``aflw``: ``faces/aflw_crops`` (11,000 crops 120 x 120, AFLW's 21 manual points, -1 = not
  annotated; **research use only**); 19 of the 21 map to rows (:data:`AFLW21_ROWS`; the ears
  do not); no person ids.
- ``london``: ``faces/frl_london/neutral_front`` (102 people, 512 x 512, CC BY 4.0), the
  189-point template (``.tem``, point ``k`` is row ``k`` of ``FRL.csv``); :data:`FRL_ROWS`
  maps the template points that are fixed points of the face to rows, :data:`FRL_OUTLINE`
  the jaw points that slide along the face's outline in a fit (2D convention: not labels).
- ``300w``: ``images/300w`` (667 photos, iBUG-68 ``.pts``, 1-based, 2D convention: the jaw
  follows the visible outline; **research use only**).
- ``aflw2000``: ``aflw2000`` (1000 photos, ``pts68_3d``, 0-based, 3D convention;
  **research use only**).

"Left" and "right" below are the image's (x grows to the right): iBUG 36 is the outer corner
of the eye on the image's left (the subject's right), mediapipe's 468 the centre of the iris
on the image's left.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from morphable.errors import InputError

from .points import IBUG_START, N_POINTS

__all__ = ["AFLW21_ROWS", "FRL_ROWS", "FRL_OUTLINE", "FRL_CHIN", "SETS", "row_scheme",
           "point_schemes", "model_points", "crop_face", "CROP_SCALE", "aflw_items",
           "london_items", "w300_items", "aflw2000_items", "set_items", "read_template", "to_crop"]

SETS = ("aflw", "london", "300w", "aflw2000")
"""The annotated photo sets by name (:func:`set_items`)."""


def _ib(i: int) -> int:
    return IBUG_START + i


AFLW21_ROWS = np.array([
    _ib(17),  # 0 brow, image-left, outer corner
    _ib(19),  # 1 brow, image-left, centre
    _ib(21),  # 2 brow, image-left, inner corner
    _ib(22),  # 3 brow, image-right, inner corner
    _ib(24),  # 4 brow, image-right, centre
    _ib(26),  # 5 brow, image-right, outer corner
    _ib(36),  # 6 eye, image-left, outer corner
    468,      # 7 eye, image-left, centre -> iris centre
    _ib(39),  # 8 eye, image-left, inner corner
    _ib(42),  # 9 eye, image-right, inner corner
    473,      # 10 eye, image-right, centre -> iris centre
    _ib(45),  # 11 eye, image-right, outer corner
    -1,       # 12 ear, image-left: no row
    98,       # 13 nose, image-left: the nostril's wing (mediapipe 98)
    _ib(30),  # 14 nose centre: the tip
    327,      # 15 nose, image-right: the nostril's wing (mediapipe 327)
    -1,       # 16 ear, image-right: no row
    _ib(48),  # 17 mouth corner, image-left
    _ib(62),  # 18 mouth centre: the inner upper lip's centre
    _ib(54),  # 19 mouth corner, image-right
    _ib(8),   # 20 chin
])
"""(21,) int: the row of each AFLW point, -1 for the ears."""

FRL_ROWS = {
    0: 468, 1: 473,                        # pupils -> iris centres
    4: 471, 8: 469, 12: 476, 16: 474,      # iris, image-left and -right edges
    18: _ib(36), 22: _ib(39), 23: _ib(42), 27: _ib(45),   # eye corners
    20: 159, 29: 145, 25: 386, 32: 374,    # upper and lower lid centres
    71: _ib(17), 82: _ib(26),              # brow outer corners
    55: _ib(33),                           # bottom centre of the nose (subnasale)
    87: _ib(48), 93: _ib(54),              # mouth corners
    89: _ib(50), 91: _ib(52), 90: _ib(51), # upper lip: its two peaks, centre of its top
    96: _ib(62), 101: _ib(66),             # inner lips, centre
    106: _ib(57),                          # centre of the bottom of the lower lip
    129: _ib(8),                           # bottom centre of the chin
}
"""FRL template point -> row, for points that are one fixed point of the face."""

FRL_OUTLINE = ((125, 126, 127, 128), (133, 132, 131, 130))
"""FRL jaw points, image-left then image-right side, each from the top down to the chin:
outline points (they slide in a fit; 2D convention, so they are not labels)."""
FRL_CHIN = 129


def row_scheme(model, rows, name: str, outline=((), ()), chin_row: int = -1):
    """A :class:`morphable.fitting.schemes.LandmarkScheme` of ``model`` whose points are
    ``rows`` of the 546 (:mod:`neural.faces.points`), followed by sliding outline points.

    Parameters
    ----------
    model : MorphableModel
    rows : (L,) int, rows of the 546 points (fixed surface points of the model)
    name : the scheme's name
    outline : (image-left side (J1,), image-right side (J2,)) of landmark indices
        *into the scheme* (``L + k`` for the k-th outline point), each from the top down to
        the chin; they get no fixed model point and slide along the outline (as iBUG-68's jaw)
    chin_row : index into ``rows`` of the chin, the fixed point that ends both outline sides
        (-1: none)

    Returns
    -------
    LandmarkScheme
        With ``L + len(outline points)`` landmarks; ``mirror`` maps a point to its mirror where
        the mirror is in the scheme (else to itself); ``ibug68`` names the scheme points that
        are iBUG rows.
    """
    from morphable.fitting.noise import DEFINITION_STD_MM
    from morphable.fitting.schemes import LandmarkScheme
    from morphable.labels import label_schemes

    from .points import mirror_index

    rows = np.asarray(rows, dtype=np.int64)
    if rows.ndim != 1 or (rows < 0).any() or (rows >= N_POINTS).any():
        raise InputError(f"scheme {name!r}: rows must be indices into the {N_POINTS} points")
    ls = label_schemes(model)
    mesh, ibug = ls["478"], ls["68"]
    vert = np.concatenate([mesh.vertices, ibug.vertices])[rows]
    bary = np.concatenate([mesh.barycentric, ibug.barycentric])[rows]
    std = np.concatenate([mesh.definition_std_mm, ibug.definition_std_mm])[rows]
    n_out = sum(len(s) for s in outline)
    L = len(rows) + n_out
    vert = np.concatenate([vert, np.full((n_out, 3), -1, np.int64)])
    bary = np.concatenate([bary, np.tile([1.0, 0.0, 0.0], (n_out, 1))])
    # outline points: the jaw's definition error of iBUG-68
    std = np.concatenate([std, np.full(n_out, DEFINITION_STD_MM[0])])
    where = {int(r): i for i, r in enumerate(rows)}
    mirror = np.array([where.get(int(m), i) for i, m in enumerate(mirror_index()[rows])]
                      + list(range(len(rows), L)), dtype=np.int64)
    left, right = (np.asarray(s, dtype=np.int64) for s in outline)
    if n_out and len(left) == len(right):
        mirror[left], mirror[right] = right, left
    ib = np.array([where.get(_ib(i), -1) for i in range(68)], dtype=np.int64)
    # iBUG's outline points 0-7 are on the subject's right = the image's left
    return LandmarkScheme(name=name, model_name=model.name, vertices=vert, barycentric=bary,
                          outline_right=left, outline_left=right, chin=int(chin_row),
                          definition_std_mm=std, mirror=mirror, ibug68=ib)


def point_schemes(model) -> tuple:
    """The 546 points of ``model`` as (face-mesh scheme, iBUG-68 scheme) of
    :func:`morphable.labels.label_schemes` (rows 0-477, 478-545)."""
    from morphable.labels import label_schemes

    ls = label_schemes(model)
    return ls["478"], ls["68"]


def model_points(model, vertices) -> np.ndarray:
    """(546, 3) mm: the 546 points of ``vertices`` (V, 3) mm (NaN rows the model lacks)."""
    mesh, ibug = point_schemes(model)
    return np.concatenate([mesh.points(vertices), ibug.points(vertices)])


CROP_SCALE = 1.5
"""A crop shows the face box grown by this factor about its centre."""


def crop_face(image, box, resolution: int, scale: float = CROP_SCALE) -> tuple:
    """A square crop about a face box, resampled (PIL's antialiased bilinear); pixels outside
    the photo are black.

    Parameters
    ----------
    image : (H, W, 3) uint8
    box : (4,) px (x0, y0, x1, y1), the face box (:func:`neural.faces.points.face_box`)
    resolution : R, the crop's side, px
    scale : the crop's side over the box's

    Returns
    -------
    (crop (R, R, 3) uint8, (origin (2,) px, s px/px)): a photo point ``p`` (px, 0-based pixel
    centres) is at ``(p - origin) * s - 0.5`` in the crop (0-based pixel centres).
    """
    from PIL import Image

    box = np.asarray(box, dtype=np.float64)
    c = (box[:2] + box[2:]) / 2
    side = scale * float(np.max(box[2:] - box[:2]))
    if not (np.isfinite(box).all() and side > 0):
        raise InputError(f"face box {box.tolist()}: not a box")
    # the crop's edges, in pixel-edge coordinates (pixel centres at integers)
    origin = c - side / 2
    H, W = image.shape[:2]
    lo = np.floor(origin).astype(int) - 1
    hi = np.ceil(origin + side).astype(int) + 2
    pad_lo = np.maximum(-lo, 0)
    pad_hi = np.maximum(hi - np.array([W, H]), 0)
    # black padding so that the resampling sees black outside the photo, not an edge
    if pad_lo.any() or pad_hi.any():
        image = np.pad(image, ((pad_lo[1], pad_hi[1]), (pad_lo[0], pad_hi[0]), (0, 0)))
    # PIL's pixel k covers [k, k + 1]: our pixel centre x is PIL's x + 0.5
    x0, y0 = origin + 0.5 + pad_lo
    img = Image.fromarray(np.ascontiguousarray(image))
    crop = img.resize((resolution, resolution), Image.Resampling.BILINEAR,
                      box=(x0, y0, x0 + side, y0 + side))
    return np.asarray(crop), (origin, resolution / side)


def to_crop(points, transform) -> np.ndarray:
    """Photo px (..., 2) -> crop px (..., 2) by the ``transform`` of :func:`crop_face`."""
    origin, s = transform
    return (np.asarray(points, dtype=np.float64) - origin) * s - 0.5


def read_template(path) -> np.ndarray:
    """A WebMorph ``.tem`` file of the FRL template -> (189, 2) px, 0-based pixel centres (the
    file's continuous coordinates minus 0.5). InputError naming the file when it is not one."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
        n = int(lines[0])
        xy = np.array([[float(v) for v in ln.split()[:2]] for ln in lines[1:1 + n]])
    except (OSError, UnicodeDecodeError, ValueError, IndexError) as e:
        raise InputError(f"{path}: not a template file ({e})") from None
    if n != 189 or xy.shape != (189, 2) or not np.isfinite(xy).all():
        raise InputError(f"{path}: expected the 189-point FRL template, got {xy.shape[0]} points")
    return xy - 0.5


def _item(set_name, path, name, key, rows, points, fit_points, scheme, *, person=-1, test=False,
          convention=0, own68=None, yaw_deg=np.nan) -> dict:
    return {"set": set_name, "path": str(path), "name": name, "key": key, "person": int(person),
            "test": bool(test), "rows": np.asarray(rows, np.int64),
            "points": np.asarray(points, np.float64), "fit_points": np.asarray(fit_points, np.float64),
            "scheme": scheme, "convention": int(convention), "own68": own68,
            # True where the annotation labels hidden points too (AFLW2000-3D's pts68_3d); the
            # others annotate what is seen
            "labels_hidden": own68 is not None,
            "yaw_deg": float(yaw_deg)}


def aflw_items(data) -> list:
    """The AFLW crops with their 19 mapped points (crop px, NaN where AFLW has -1), one item
    per crop; split key ``aflw/<src_index>`` (no person ids); the dataset's yaw, negated into
    the fit's convention (AFLW's +yaw turns the nose to the image's left, the fit's to its
    right)."""
    root = Path(data) / "faces" / "aflw_crops"
    try:
        with np.load(root / "index.npz", allow_pickle=False) as z:
            names, src, yaw, roi, pts = (z[k] for k in ("names", "src_index", "yaw_deg", "roi_box", "pts21"))
    except (OSError, ValueError, KeyError) as e:
        raise InputError(f"{root / 'index.npz'}: cannot read the AFLW index ({e})") from None
    p = pts.transpose(0, 2, 1).astype(np.float64)                 # (N, 21, 2) photo px
    missing = (p < 0).any(-1)
    box = roi.astype(np.float64)
    # the crops are 120 px of the box (sx, sy, ex, ey); 0-based both ways (README)
    crop = (p - box[:, None, :2]) * 120.0 / (box[:, None, 2:] - box[:, None, :2])
    crop[missing] = np.nan
    keep = AFLW21_ROWS >= 0
    return [_item("aflw", root / "crops" / str(n), f"aflw/{n}", f"aflw/{int(s)}",
                  AFLW21_ROWS[keep], c[keep], c[keep], "aflw21", yaw_deg=-float(y))
            for n, s, y, c in zip(names, src, yaw, crop)]


def _frl_points(t) -> tuple:
    keys = list(FRL_ROWS)
    rows = [FRL_ROWS[k] for k in keys]
    fit = np.concatenate([t[keys], t[list(FRL_OUTLINE[0])], t[list(FRL_OUTLINE[1])]])
    return rows, t[keys], fit


def london_items(data) -> list:
    """The London neutral front photos with a template: :data:`FRL_ROWS` as labels, those
    and the jaw (:data:`FRL_OUTLINE`) for the fit; person = the 3-digit id, split key
    ``london/<id>``."""
    root = Path(data) / "faces" / "frl_london" / "neutral_front"
    items = []
    for tem in sorted(root.glob("*.tem")):
        photo = tem.with_suffix(".jpg")
        if not (photo.is_file() and tem.name[:3].isdigit()):
            continue
        rows, labels, fit = _frl_points(read_template(tem))
        items.append(_item("london", photo, f"london/{photo.name}", f"london/{tem.name[:3]}", rows,
                           labels, fit, "frl", person=int(tem.name[:3])))
    return items


def w300_items(data) -> list:
    """The 300-W photos (AFW, HELEN test) with their 68 points (2D convention, ``.pts``
    1-based, read 0-based): test split."""
    from morphable.io.landmark_files import read_pts

    root = Path(data) / "images" / "300w"
    items = []
    for photo in sorted(p for p in root.rglob("*") if p.suffix.lower() in (".jpg", ".png")):
        pts = photo.with_suffix(".pts")
        if not pts.is_file():
            continue
        xy = read_pts(pts)
        if xy.shape != (68, 2):
            raise InputError(f"{pts}: expected 68 points, got {len(xy)}")
        rel = photo.relative_to(root).as_posix()
        items.append(_item("300w", photo, f"300w/{rel}", f"300w/{rel}", IBUG_START + np.arange(68),
                           xy, xy, "ibug68", test=True, convention=1))
    return items


def aflw2000_items(data) -> list:
    """AFLW2000-3D's photos with ``pts68_3d`` (3D convention, 0-based): test split; the
    dataset's yaw, negated into the fit's convention."""
    root = Path(data) / "aflw2000"
    try:
        with np.load(root / "landmarks.npz", allow_pickle=False) as z:
            names, pts, yaw = z["names"], z["pts68_3d"][..., :2].astype(np.float64), z["yaw_deg"]
    except (OSError, ValueError, KeyError) as e:
        raise InputError(f"{root / 'landmarks.npz'}: cannot read AFLW2000-3D's landmarks ({e})") from None
    # a few stored yaws are unwrapped (e.g. -351 deg): back into (-180, 180]
    yaw = (np.asarray(yaw, np.float64) + 180.0) % 360.0 - 180.0
    return [_item("aflw2000", root / str(n), f"aflw2000/{n}", f"aflw2000/{n}",
                  IBUG_START + np.arange(68), p, p, "ibug68_3d", test=True, convention=0, own68=p,
                  yaw_deg=-float(y)) for n, p, y in zip(names, pts, yaw)]


_READERS = {"aflw": aflw_items, "london": london_items, "300w": w300_items, "aflw2000": aflw2000_items}
_WHERE = {"aflw": "faces/aflw_crops/index.npz", "london": "faces/frl_london/neutral_front/*.tem",
          "300w": "images/300w/**/*.pts", "aflw2000": "aflw2000/landmarks.npz"}


def set_items(data, name: str) -> list:
    """The items of set ``name`` (:data:`SETS`) under the data folder; InputError (one line,
    naming the folder) when the folder lacks the set."""
    if name not in _READERS:
        raise InputError(f"set {name!r}: expected one of {', '.join(SETS)}")
    data = Path(data)
    if not data.is_dir():
        raise InputError(f"{data}: data folder not found")
    where = _WHERE[name]
    if not any(data.glob(where)):
        raise InputError(f"{data}: no {name} data under it ({where})")
    return _READERS[name](data)


MAX_RESIDUAL = 0.03
"""A fit fails when its RMS landmark residual exceeds this fraction of its face box's side
(:func:`neural.faces.points.face_box`; 0.03 of a 192-px box is 5.8 px)."""

_SCHEMES: dict = {}   # per process: (model name, scheme name) -> LandmarkScheme or None


def item_scheme(model, name: str):
    """The fit scheme ``name`` of an item (``aflw21``, ``frl``, ``ibug68``: iBUG-68 with its jaw
    sliding, for 2D-convention points; ``ibug68_3d``: the 68 rows of the 546 as fixed points,
    for 3D-convention points), made once per process and model."""
    key = (model.name, name)
    if key not in _SCHEMES:
        if name == "aflw21":
            s = row_scheme(model, AFLW21_ROWS[AFLW21_ROWS >= 0], name)
        elif name == "frl":
            rows = [FRL_ROWS[k] for k in FRL_ROWS]
            L, (a, b) = len(rows), FRL_OUTLINE
            s = row_scheme(model, rows, name,
                           outline=(np.arange(L, L + len(a)), np.arange(L + len(a), L + len(a) + len(b))),
                           chin_row=list(FRL_ROWS).index(FRL_CHIN))
        elif name == "ibug68":
            s = None        # fit_landmarks' own for 68 points
        elif name == "ibug68_3d":
            s = row_scheme(model, IBUG_START + np.arange(68), name)
        else:
            raise InputError(f"fit scheme {name!r}: unknown")
        _SCHEMES[key] = s
    return _SCHEMES[key]


def fit_item(model, item: dict, image_size) -> tuple:
    """Fit ``model`` to an item's ``fit_points`` (:func:`morphable.fitting.fit_landmarks`,
    affine camera) -> (FitResult, its 546 points projected (546, 2) px, RMS residual px).
    FitError when the points cannot determine a fit."""
    from morphable.fitting import fit_landmarks

    fit = fit_landmarks(model, item["fit_points"], image_size, scheme=item_scheme(model, item["scheme"]))
    P = fit.cameras[0].project(model_points(model, fit.vertices(0, np.float64)))
    return fit, P, float(fit.landmark_rmse_px[0])


def face_record(image, points, labelled, visible, box, resolution: int) -> dict:
    """One face of a landmark pack (docs/landmark_packs.md): the crop about ``box`` and the
    labels moved into it.

    Parameters
    ----------
    image : (H, W, 3) uint8 photo
    points : (546, 2) px in the photo (NaN where not labelled)
    labelled, visible : (546,) bool
    box : (4,) px, the face box in the photo
    resolution : R px

    Returns
    -------
    dict: ``image`` (R, R, 3) uint8, ``box`` (4,) float32 and ``points`` (546, 2) float32 crop
    px, ``labelled``, ``visible`` (546,) bool.
    """
    crop, tr = crop_face(image, box, resolution)
    pts = np.where(labelled[:, None], to_crop(points, tr), np.nan)
    b = to_crop(np.reshape(box, (2, 2)), tr).ravel()
    return {"image": crop, "box": b.astype(np.float32), "points": pts.astype(np.float32),
            "labelled": np.asarray(labelled, bool), "visible": np.asarray(visible, bool) & labelled}


RECORD_KEYS = {"image": None, "box": (4,), "points": (N_POINTS, 2), "labelled": (N_POINTS,),
               "visible": (N_POINTS,), "convention": (), "person": (), "split": (), "source": (),
               "yaw_deg": (), "name": (), "residual_px": ()}
_DTYPES = {"image": np.uint8, "box": np.float32, "points": np.float32, "labelled": bool,
           "visible": bool, "convention": np.uint8, "person": np.int32, "split": np.uint8,
           "source": np.uint8, "yaw_deg": np.float32, "name": str, "residual_px": np.float32}


def stack_records(records: list, resolution: int, failures=()) -> dict:
    """The arrays of a landmark pack shard from its faces' records (each a
    :func:`face_record` with ``convention``, ``person``, ``split``, ``source``, ``yaw_deg``,
    ``name``, ``residual_px``) and ``failures`` (``(name, reason)`` pairs):
    ``failed_name``, ``failed_reason`` (k,) str."""
    out = {}
    for k, shape in RECORD_KEYS.items():
        shape = (resolution, resolution, 3) if k == "image" else shape
        out[k] = (np.array([r[k] for r in records], dtype=_DTYPES[k]) if records
                  else np.zeros((0,) + shape, dtype=_DTYPES[k]))
    out["failed_name"] = np.array([f[0] for f in failures], dtype=str)
    out["failed_reason"] = np.array([f[1] for f in failures], dtype=str)
    return out
