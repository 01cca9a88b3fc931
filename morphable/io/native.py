"""The toolkit's own model file: one ``.npz`` written by ``morphable convert``."""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_path

__all__ = ["save_model_npz", "load_model_npz", "FORMAT"]

FORMAT = "morphable-npz-1"
_OPTIONAL = ("uv", "triangle_uv", "symmetry")


def save_model_npz(model, path) -> Path:
    """Write ``model`` to ``path`` (a compressed npz, millimetres), atomically.

    Examples
    --------
    >>> import tempfile
    >>> from morphable import load_model
    >>> path = save_model_npz(load_model("sfm"), f"{tempfile.mkdtemp()}/sfm.npz")
    >>> load_model(path).n_vertices
    3448
    """
    arrays = {
        "format": np.array(FORMAT), "name": np.array(model.name),
        "mean": model.mean, "triangles": model.triangles,
        "identity_basis": model.identity_basis, "expression_basis": model.expression_basis,
        "expression_names": np.array(list(model.expression_names), dtype=str),
        "expression_kind": np.array(model.expression_kind),
        "landmark_ids": model.landmark_ids,
        "contour_right": model.contour_right, "contour_left": model.contour_left,
        "segment_names": np.array(sorted(model.segments), dtype=str),
    }
    arrays.update({f"segment_{k}": v for k, v in model.segments.items()})
    arrays.update({k: getattr(model, k) for k in _OPTIONAL if getattr(model, k) is not None})
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    return Path(path)


def load_model_npz(path, name: str | None = None):
    """Read a file written by :func:`save_model_npz` -> MorphableModel (``name`` overrides)."""
    from ..model import MorphableModel

    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as d:
            if "format" not in d.files or str(d["format"]) != FORMAT:
                raise InputError(f"{path}: not a morphable model npz (format {FORMAT} expected)")
            segs = {str(k): d[f"segment_{k}"] for k in d["segment_names"]}
            return MorphableModel.from_arrays(
                mean=d["mean"], triangles=d["triangles"], identity_basis=d["identity_basis"],
                expression_basis=d["expression_basis"],
                expression_names=[str(s) for s in d["expression_names"]],
                expression_kind=str(d["expression_kind"]), landmark_ids=d["landmark_ids"],
                contour_right=d["contour_right"], contour_left=d["contour_left"],
                segments=segs, name=name or str(d["name"]), source=str(path),
                **{k: d[k] for k in _OPTIONAL if k in d.files})
    except KeyError as e:
        raise InputError(f"{path}: incomplete model npz (missing {e})") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise InputError(f"{path}: cannot read npz ({e})") from None
