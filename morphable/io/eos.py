"""Readers for the eos library's files: cereal-binary models and blendshapes, landmark
mappings (TOML) and contour definitions (JSON).

The binary layout follows eos' cereal serialisation (little endian): Eigen matrices are
``int32 rows, int32 cols`` then column-major float32 data; ``std::vector`` is a ``uint64``
count then its items; ``std::string`` is a ``uint64`` length then bytes; ``optional`` is a
one-byte 'nullopt' flag (0 = a value follows); ``variant`` an ``int32`` index then the value.
"""
from __future__ import annotations

import json
import struct
import tomllib
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["read_eos_model", "read_eos_blendshapes", "read_landmark_mapping", "read_contours",
           "read_symmetry", "load_eos"]


class _Reader:
    """A cursor over bytes that names the file and offset when the data run out or look wrong."""

    def __init__(self, path):
        self.path = Path(path)
        try:
            self.buf = self.path.read_bytes()
        except OSError as e:
            raise InputError(f"{self.path}: cannot read ({e.strerror or e})") from None
        self.pos = 0

    def fail(self, problem):
        raise InputError(f"{self.path}: {problem} at byte {self.pos}")

    def take(self, n: int) -> memoryview:
        if n < 0 or self.pos + n > len(self.buf):
            self.fail(f"truncated or corrupt (needs {n} more bytes, {len(self.buf) - self.pos} left)")
        out = memoryview(self.buf)[self.pos:self.pos + n]
        self.pos += n
        return out

    def scalar(self, fmt: str):
        return struct.unpack("<" + fmt, self.take(struct.calcsize(fmt)))[0]

    def count(self, item_size: int) -> int:
        n = self.scalar("Q")
        if n * item_size > len(self.buf) - self.pos:
            self.fail(f"corrupt: a list of {n} items does not fit in the file")
        return n

    def matrix(self) -> np.ndarray:
        rows, cols = self.scalar("i"), self.scalar("i")
        if rows < 0 or cols < 0 or rows * cols * 4 > len(self.buf) - self.pos:
            self.fail(f"corrupt matrix header ({rows} x {cols}: {max(rows * cols * 4, 0)} bytes, "
                      f"{len(self.buf) - self.pos} left; truncated file?)")
        data = np.frombuffer(self.take(rows * cols * 4), dtype="<f4")
        return data.reshape(cols, rows).T  # column-major on disk

    def string(self) -> str:
        raw = bytes(self.take(self.count(1)))
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            self.fail("corrupt string")

    def triangles(self) -> np.ndarray:
        n = self.count(12)
        return np.frombuffer(self.take(12 * n), dtype="<i4").reshape(n, 3).astype(np.int64)

    def has_value(self) -> bool:
        """cereal writes an optional as a 'nullopt' byte: 0 when a value follows."""
        b = self.scalar("B")
        if b > 1:
            self.fail(f"corrupt optional flag {b}")
        return b == 0


def _pca_model(r: _Reader) -> dict:
    mean = r.matrix()
    basis = r.matrix()  # orthonormal, (3V, K)
    eigenvalues = r.matrix()
    tris = r.triangles()
    n = mean.shape[0]
    if mean.shape[1] not in (0, 1) or (n and basis.shape[0] != n) or eigenvalues.size != basis.shape[1]:
        r.fail(f"inconsistent PCA model (mean {mean.shape}, basis {basis.shape}, "
               f"eigenvalues {eigenvalues.shape})")
    if (eigenvalues < 0).any():
        r.fail("negative PCA eigenvalue")
    k = basis.shape[1]
    scaled = (basis * np.sqrt(eigenvalues.ravel())).T.reshape(k, n // 3, 3) if n else np.zeros((0, 0, 3))
    return {"mean": mean.reshape(-1, 3), "basis": scaled, "triangles": tris}


def _blendshapes(r: _Reader) -> tuple[list, np.ndarray]:
    n = r.count(16)
    names, offsets = [], []
    for _ in range(n):
        names.append(r.string())
        d = r.matrix()
        if d.shape[1] != 1 or d.shape[0] % 3:
            r.fail(f"blendshape {names[-1]!r} is not a 3V vector ({d.shape})")
        offsets.append(d.reshape(-1, 3))
    if len({o.shape for o in offsets}) > 1:
        r.fail("blendshapes of different vertex counts")
    return names, (np.stack(offsets) if offsets else np.zeros((0, 0, 3), np.float32))


def read_eos_blendshapes(path) -> tuple[list, np.ndarray]:
    """Read an eos blendshapes file (``expression_blendshapes_3448.bin``).

    Returns
    -------
    names : list of str
    offsets : (E, V, 3) float32, model units (mm for SFM)
    """
    r = _Reader(path)
    out = _blendshapes(r)
    if r.pos != len(r.buf):
        r.fail("unexpected trailing data")
    return out


def read_eos_model(path) -> dict:
    """Read an eos cereal-binary MorphableModel (versions 1 to 4).

    Returns
    -------
    dict with ``mean`` (V, 3) float32, ``identity_basis`` (K, V, 3) float32 scaled by std,
    ``triangles`` (F, 3) int64, ``uv`` (V or T, 2) float64 or None, ``triangle_uv`` (F, 3) or
    None, and where present ``expression_basis``/``expression_names``/``expression_kind`` and
    ``landmarks`` (dict name -> vertex id).
    """
    r = _Reader(path)
    version = r.scalar("I")
    if not 1 <= version <= 4:
        r.fail(f"unknown eos model version {version} (known: 1 to 4)")
    shape = _pca_model(r)
    _pca_model(r)  # colour model: not used by a geometry toolkit
    out = {"mean": shape["mean"], "identity_basis": shape["basis"], "triangles": shape["triangles"]}
    V = out["mean"].shape[0]
    if V == 0:
        r.fail("the shape model is empty")
    if version >= 2 and r.has_value():
        kind = r.scalar("i")
        if kind == 0:
            pca = _pca_model(r)
            out.update(expression_basis=pca["basis"], expression_kind="pca",
                       expression_names=[f"pc{i}" for i in range(len(pca["basis"]))])
        elif kind == 1:
            names, offsets = _blendshapes(r)
            out.update(expression_basis=offsets, expression_kind="blendshapes", expression_names=names)
        else:
            r.fail(f"unknown expression model type {kind}")
        if out["expression_basis"].shape[1] != V:
            r.fail("expression model vertex count differs from the shape model")
    if version >= 3 and r.has_value():
        out["landmarks"] = {r.string(): r.scalar("i") for _ in range(r.count(12))}
    n = r.count(16)
    uv = np.frombuffer(r.take(16 * n), dtype="<f8").reshape(n, 2).copy()
    out["uv"] = uv if n else None
    out["triangle_uv"] = None
    if version >= 4:
        tti = r.triangles()
        out["triangle_uv"] = tti if len(tti) else None
    if r.pos != len(r.buf):
        r.fail("unexpected trailing data")
    return out


def read_landmark_mapping(path) -> dict:
    """Read an eos landmark mapping (``ibug_to_sfm.txt``, TOML ``[landmark_mappings]``).

    Returns
    -------
    dict of int (1-based iBUG landmark number) -> int (vertex id)
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
        return {int(k): int(v) for k, v in data["landmark_mappings"].items()}
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    except (tomllib.TOMLDecodeError, KeyError, ValueError, TypeError, AttributeError) as e:
        raise InputError(f"{path}: not an eos landmark mapping ({e})") from None


def read_contours(path) -> tuple[np.ndarray, np.ndarray]:
    """Read eos model contours (``sfm_model_contours.json``).

    Returns
    -------
    right, left : (C,) int64 vertex ids, from the top of the face down to the chin.
    """
    path = Path(path)
    try:
        c = json.loads(path.read_text())["model_contour"]
        return (np.asarray(c["right_contour"], dtype=np.int64),
                np.asarray(c["left_contour"], dtype=np.int64))
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"{path}: not an eos contour file ({e})") from None


def read_symmetry(path, n_vertices: int) -> np.ndarray:
    """Read an eos symmetry file (one 1-based vertex id per line) -> (V,) 0-based ids.

    The file may cover only the first vertices (SFM's covers the 845 of its reference
    level); the others get ``-1``.
    """
    path = Path(path)
    try:
        ids = np.loadtxt(path, dtype=np.int64, comments="#", usecols=0, ndmin=1) - 1
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    except ValueError as e:
        raise InputError(f"{path}: not a symmetry list ({e})") from None
    n = len(ids)
    if n == 0 or n > n_vertices or ids.min() < 0 or ids.max() >= n:
        raise InputError(f"{path}: expected at most {n_vertices} vertex ids, each in 1..{n}")
    return np.concatenate([ids, np.full(n_vertices - n, -1, dtype=np.int64)])


def load_eos(path, name: str | None = None):
    """Assemble a :class:`~morphable.model.MorphableModel` from an eos model ``.bin`` or
    ``share/``-style folder.

    ``path`` is the model ``.bin`` or a folder holding exactly one; the folder's
    ``expression_blendshapes_*.bin``, ``ibug_to_*.txt``, ``*_model_contours.json`` and
    ``*_reference_symmetry.txt`` are used when present. Texture coordinates are flipped from
    eos' v-down to the toolkit's v-up convention (as in OBJ files).
    """
    from ..model import MorphableModel

    path = Path(path)
    if path.is_dir():
        folder = path
        bins = sorted(p for p in folder.glob("*.bin") if not p.name.startswith("expression_blendshapes"))
        if len(bins) != 1:
            raise InputError(f"{folder}: expected one eos model .bin, found {len(bins)}")
        path = bins[0]
    folder = path.parent
    m = read_eos_model(path)
    V = m["mean"].shape[0]
    if "expression_basis" not in m:
        shapes = sorted(folder.glob(f"expression_blendshapes_{V}.bin")) or sorted(
            folder.glob("expression_blendshapes*.bin"))
        if shapes:
            names, offsets = read_eos_blendshapes(shapes[0])
            if offsets.shape[1] != V:
                raise InputError(f"{shapes[0]}: {offsets.shape[1]} vertices, the model has {V}")
            m.update(expression_basis=offsets, expression_names=names, expression_kind="blendshapes")
    landmark_ids = np.full(68, -1, dtype=np.int64)
    # a model file may define landmarks itself; an iBUG mapping file beside it takes precedence
    defined = {int(k): v for k, v in m.get("landmarks", {}).items() if k.isdigit()}
    mapping = sorted(folder.glob("ibug_to_*.txt"))
    if mapping:
        defined.update(read_landmark_mapping(mapping[0]))
    if defined:
        for k, v in defined.items():
            if 1 <= k <= 68 and 0 <= v < V:
                landmark_ids[k - 1] = v
    contours = sorted(folder.glob("*model_contours.json"))
    right, left = read_contours(contours[0]) if contours else (np.zeros(0, np.int64),) * 2
    sym = sorted(folder.glob("*reference_symmetry.txt"))
    return MorphableModel.from_arrays(
        mean=m["mean"], triangles=m["triangles"], identity_basis=m["identity_basis"],
        expression_basis=m.get("expression_basis"),
        expression_names=m.get("expression_names", []),
        expression_kind=m.get("expression_kind", "none"),
        landmark_ids=landmark_ids, contour_right=right, contour_left=left,
        # eos texture coordinates have v pointing down (image rows); the toolkit's point up
        uv=None if m["uv"] is None else np.column_stack([m["uv"][:, 0], 1.0 - m["uv"][:, 1]]),
        triangle_uv=m["triangle_uv"],
        symmetry=read_symmetry(sym[0], V) if sym else None,
        name=name or path.stem, source=str(path))
