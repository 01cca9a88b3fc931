"""The sliding outline correspondences of a fit, re-picked on the face's current outline.

Every round of the linear stage and every second nonlinear iteration, each 2D outline point
(iBUG-68's jaw, the face mesh's oval) takes the nearest point of the face's projected outline
— the jaw line where it faces the camera, else the cheek's silhouette, at any height — and
only its distance across the outline counts (:mod:`~morphable.fitting.correspondences`).
"""
from __future__ import annotations

import numpy as np

from .correspondences import outline_points, slide_contours
from .pose import project
from .problem import Problem, State
from .rows import gather

__all__ = ["slide"]


def slide(pb: Problem, st: State):
    """Re-pick the outline correspondences on the current outline, move their targets along it
    (:func:`~morphable.fitting.correspondences.slide_contours`) and gather their rows anew;
    nothing where no frame gives an outline point."""
    bank = pb.bank
    if pb.sliding is None:
        return
    if pb.perspective:
        # a pinhole camera sees the outline where the surface turns away from its centre (the
        # direction taken to each line's start on the mean shape: a few mm do not change it)
        centre = -np.einsum("nji,nj->ni", st.R, st.t)
        v = centre[:, None] - bank.mean[bank.outline_rows[:, 0]][None]
        view = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9)
    else:
        view = st.R[:, 2]
    outline = a, b, w = outline_points(bank, view)                   # (N, T) each
    # both ends of every outline point in one gather of the basis rows
    rows = np.concatenate([a, b], axis=1)
    n = pb.n_identity
    X = bank.mean[rows]                                             # (N, 2T, 3), a copy
    if n:
        alpha = np.broadcast_to(st.alpha[:, :n], (pb.N, n))
        X += (pb.A[rows].reshape(pb.N, -1, n) @ alpha[..., None]).reshape(rows.shape + (3,))
    if pb.E:
        X += (pb.B[rows].reshape(pb.N, -1, pb.E) @ st.beta[..., None]).reshape(rows.shape + (3,))
    T = a.shape[1]
    X = (1 - w[..., None]) * X[:, :T] + w[..., None] * X[:, T:]
    uv = project(X, st.R, st.t, st.k, pb.principal, pb.perspective, False)[0]
    pb.y, pb.tangent = slide_contours(bank, st.corr, outline, uv, pb.y_obs, pb.mask)
    gather(pb, st)
