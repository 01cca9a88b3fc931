"""A refined reconstruction re-rendered under another pose or expression."""
from __future__ import annotations

import dataclasses

import numpy as np

from ..camera import Camera
from ..errors import InputError
from .geometry import render_face

__all__ = ["Refinement", "edit"]


@dataclasses.dataclass
class Refinement:
    """Everything :func:`edit` needs to re-render the reconstruction.

    renderer : the renderer object; appearance : dict of its tensors (recovered);
    crop : (left, top, side) px; camera : crop camera (refined pose); target (R, R, 3) the
    image crop; rendered (R, R, 3) the final render; fit : refined FitResult; frame : the
    frame of ``fit`` it is; mask : (R, R) the photometric mask's weights in [0, 1];
    coverage : (R, R) the fitted face's coverage of the crop pixels in [0, 1].
    """

    renderer: object
    appearance: dict
    crop: tuple
    camera: Camera
    target: np.ndarray
    rendered: np.ndarray
    fit: object
    frame: int = 0
    mask: np.ndarray | None = None
    coverage: np.ndarray | None = None


def edit(state: Refinement, *, yaw=None, pitch=None, roll=None, expression: dict | None = None,
         identity_scale: float = 1.0, frame: int | None = None) -> np.ndarray:
    """Re-render a reconstruction under another pose and/or expression.

    Parameters
    ----------
    state : :class:`Refinement` from ``refine(..., return_state=True)``
    yaw, pitch, roll : degrees (absolute, in the crop camera); None keeps the recovered angle
    expression : {name: weight} replacing those expression coefficients (e.g.
        ``{"happiness": 0.8}`` for the SFM blendshapes); others keep their recovered value
    identity_scale : multiplies alpha (0: the mean face under the recovered appearance)
    frame : the frame of the fit whose expression is edited (default: the state's)

    Returns
    -------
    (R, R, 3) float image in [0, 1].
    """
    fit = state.fit
    model = fit.model
    frame = state.frame if frame is None else int(frame)
    beta = np.array(fit.expression[frame], dtype=np.float64)
    names = list(model.expression_names)
    for k, v in (expression or {}).items():
        if k not in names:
            raise InputError(f"unknown expression {k!r}; the model has: {', '.join(names)}")
        if not np.isfinite(v):
            raise InputError(f"expression {k}: weight must be finite, got {v}")
        beta[names.index(k)] = float(v)
    for a in (yaw, pitch, roll):
        if a is not None and not np.isfinite(a):
            raise InputError(f"pose angles must be finite, got {a}")
    cam = state.camera.with_pose(yaw=yaw, pitch=pitch, roll=roll)
    alpha = np.asarray(fit.frame_identity[frame], dtype=np.float64) * identity_scale
    return render_face(model, alpha, beta, cam, state.renderer, state.appearance)
