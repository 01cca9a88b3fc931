"""Reader for the Basel Face Model 2017 (statismo ``.h5``: ``shape/`` and ``expression/``
groups with ``model/{mean, pcaBasis, pcaVariance}`` and ``representer/{points, cells}``).

The BFM licence forbids redistribution: users point ``--model`` at their own copy.
BFM 2017 coordinates are millimetres.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["load_bfm_h5"]


def _scaled_basis(group, V: int) -> tuple[np.ndarray, np.ndarray]:
    mean = np.asarray(group["model/mean"], dtype=np.float32).reshape(V, 3)
    basis = np.asarray(group["model/pcaBasis"], dtype=np.float32)  # (3V, K), orthonormal columns
    var = np.asarray(group["model/pcaVariance"], dtype=np.float32).ravel()
    if basis.shape != (3 * V, var.size) or (var < 0).any():
        raise ValueError(f"pcaBasis {basis.shape} and pcaVariance {var.shape} do not match {V} vertices")
    return mean, (basis * np.sqrt(var)).T.reshape(var.size, V, 3)


def load_bfm_h5(path, name: str | None = None):
    """Load a BFM 2017 ``.h5`` -> MorphableModel (identity = shape PCA, expression = PCA)."""
    from ..model import MorphableModel

    import h5py

    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            for key in ("shape/representer/points", "shape/representer/cells", "shape/model/mean",
                        "shape/model/pcaBasis", "shape/model/pcaVariance"):
                # h5py's KeyError text is its C library's, not the missing name
                if key not in f:
                    raise InputError(f"{path}: not a BFM 2017 file (no {key})")
            points = np.asarray(f["shape/representer/points"], dtype=np.float64)
            cells = np.asarray(f["shape/representer/cells"], dtype=np.int64)
            V = points.shape[1]
            mean, identity = _scaled_basis(f["shape"], V)
            expression = None
            if "expression" in f:
                emean, expression = _scaled_basis(f["expression"], V)
                mean = mean + emean  # statismo stores the expression model around its own mean
    except InputError:
        raise
    except KeyError as e:
        raise InputError(f"{path}: not a BFM 2017 file (missing {e})") from None
    except (OSError, ValueError, TypeError) as e:
        raise InputError(f"{path}: cannot read BFM h5 ({e})") from None
    n_exp = 0 if expression is None else len(expression)
    return MorphableModel.from_arrays(
        mean=mean, triangles=cells.T, identity_basis=identity, expression_basis=expression,
        expression_names=[f"pc{i}" for i in range(n_exp)],
        expression_kind="pca" if n_exp else "none", name=name or path.stem, source=str(path))
