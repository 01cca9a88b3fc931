"""Reader for FLAME (``generic_model.pkl``: ``v_template`` and ``shapedirs`` in metres,
300 shape + 100 expression directions, ``f`` triangles).

Only the linear part is read (shape and expression); the skinned jaw, neck and eye joints
are not part of a linear morphable model. The original files pickle chumpy arrays: they are
read without chumpy by keeping the array each chumpy object wraps. The FLAME licence
forbids redistribution: users point ``--model`` at their own copy.
"""
from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["load_flame_pkl"]

M_TO_MM = 1000.0
N_SHAPE = 300


class _ChumpyStub:
    """Stands in for any chumpy class while unpickling; keeps the wrapped array ``x``."""

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        self.__dict__.update(state if isinstance(state, dict) else {})


class _Unpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module.startswith("chumpy"):
            return _ChumpyStub
        if module.startswith(("numpy", "scipy", "copy_reg", "copyreg", "__builtin__", "builtins")):
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}")


def _array(value) -> np.ndarray:
    if isinstance(value, _ChumpyStub):
        value = getattr(value, "x", None)
    if hasattr(value, "toarray"):
        value = value.toarray()
    return np.asarray(value)


def load_flame_pkl(path, name: str | None = None, n_shape: int = N_SHAPE):
    """Load a FLAME ``.pkl`` -> MorphableModel in mm (identity = first ``n_shape`` directions)."""
    from ..model import MorphableModel

    path = Path(path)
    try:
        with open(path, "rb") as fh:
            d = _Unpickler(fh, encoding="latin1").load()
        template = _array(d["v_template"]).astype(np.float64)
        dirs = _array(d["shapedirs"]).astype(np.float64)  # (V, 3, n_shape + n_expression)
        faces = _array(d["f"]).astype(np.int64)
    except KeyError as e:
        raise InputError(f"{path}: not a FLAME model (missing {e})") from None
    except (OSError, pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError) as e:
        raise InputError(f"{path}: cannot read FLAME pkl ({e})") from None
    if dirs.ndim != 3 or dirs.shape[:2] != template.shape:
        raise InputError(f"{path}: shapedirs {dirs.shape} do not match v_template {template.shape}")
    modes = np.moveaxis(dirs, 2, 0) * M_TO_MM
    n_exp = modes.shape[0] - min(n_shape, modes.shape[0])
    return MorphableModel.from_arrays(
        mean=template * M_TO_MM, triangles=faces, identity_basis=modes[:n_shape],
        expression_basis=modes[n_shape:], expression_names=[f"exp{i}" for i in range(n_exp)],
        expression_kind="pca" if n_exp else "none", name=name or path.stem, source=str(path))
