"""The nonlinear stage of a landmark fit: a joint Levenberg-Marquardt over all parameters.

Per frame: rotation (axis-angle increments, no gimbal lock), translation, scale (affine) or
depth (perspective) and expressions; per group of frames: the shared coefficients (identity
and landmark offsets). Analytic Jacobians, an optional Huber loss on the normalised residuals,
and Marquardt's damping (``mu`` times the diagonal of the whole system). A group of one frame
is solved whole; a larger one by the Schur complement of its per-frame blocks, which keeps a
shared identity cheap for many frames (with landmark offsets, the whole system is solved by
its structure: :mod:`~morphable.fitting.offsets`). A step is tried with growing damping until
it lowers the group's cost. Blendshape weights stay >= 0: those a step would take below 0 are
set to 0 and the rest of the step is solved again given them (clamping alone leaves a step the
model did not predict, which the trial then often rejects); a whole solve does that from the
same factorisation. A group has converged when its step gains, or is predicted to gain, less
than :data:`CONVERGED_GAIN`; after a small step that prediction is first estimated with the
step's own Jacobian, and a clear pass ends the group without new normal equations.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..camera import cross
from .linear import gram_hessian, project_rows, weighted_rows
from .noise import weights
from .offsets import damped_step, offset_normal
from .pose import rotate
from .problem import Problem, State, group_index, group_sum
from .rows import offsets, residuals, shared_rows
from .sliding import slide

__all__ = ["lm_stage", "normal_equations", "NormalEquations", "CONVERGED_GAIN"]

CONVERGED_GAIN = 1e-2
"""A step that lowers a group's cost by less than this, or whose predicted decrease is less
than this, ends its iterations. The cost is in chi-square units (residuals divided by their
standard deviation), so 0.01 is a step of about a tenth of a standard deviation in the
best-determined direction: below anything the landmarks can tell apart (docs/fitting.md, the
partial-landmark benchmark: same 3D error, fewer iterations)."""

ESTIMATE_BELOW_GAIN = 2.0
"""After a step that gained less than this (chi-square units), the next convergence test is
first estimated from the step's own Jacobian (``_predicted_decrease``), which costs about
half of new normal equations; after larger steps (a fit's first: 8-260 on 40 benchmark faces)
it passed in 2 of 40, so it is not tried."""


def lm_stage(pb: Problem, st: State, n_iterations: int, slide_every: int = 2):
    """Up to ``n_iterations`` Levenberg-Marquardt iterations from ``st``, re-picking the outline
    correspondences every ``slide_every``-th -> (state, iterations run)."""
    N, K, E = pb.N, pb.K, pb.E
    G = 1 if pb.shared else N
    n_t, n_rho, Pf = _frame_params(pb)
    mu = np.full(G, 1e-3)
    gidx = group_index(pb)
    iters = 0
    # a group that has converged stops moving, so that fitting frames together or alone
    # gives the same result
    active = np.ones(G, bool)
    for it in range(n_iterations):
        if it % slide_every == 0 and it:
            slide(pb, st)
        ne = normal_equations(pb, st)
        Hff, gf, Hfa, Haa, ga, W, cost0, off = (ne.Hff, ne.gf, ne.Hfa, ne.Haa, ne.ga, ne.W,
                                                ne.cost, ne.off)
        # a group of one frame is solved whole (each attempt damps a copy of its system)
        whole = ne.H if off is None and K and G == N else None
        accepted = ~active
        stepped = np.zeros(G, bool)
        gain = np.zeros(G)
        for attempt in range(4):          # retry rejected groups with more damping
            # independent frames: solve only the active ones still rejected (all of them: a
            # slice, not a copy of every frame's rows)
            sel = slice(None) if pb.shared or not accepted.any() else np.flatnonzero(~accepted)
            gs = slice(None) if pb.shared else sel
            Hfs, gfs = Hfa[sel], gf[sel]
            if whole is not None:
                Hd = whole[sel].copy()
                _damp(Hd, mu[gs])
                df, da, unit = _whole_step(pb, Hd, gfs, ga[gs], sel, pb.nonneg)
            else:
                Hd = Hff[sel].copy()
                _damp(Hd, mu[gidx[sel]])
                df, da = _damped_step(pb, Hd, Hfs, gfs, Haa[gs], ga[gs], off, mu[gs], sel)
                unit = None
            if attempt == 0:
                # -g.step / 2 is at most the decrease the damped Gauss-Newton model predicts:
                # a group whose step cannot gain CONVERGED_GAIN has converged, without a trial
                g_shared = ga if off is None else np.concatenate([ga, off.gd.reshape(1, -1)], -1)
                pred = np.full(G, np.inf)
                pred[gs] = -0.5 * (group_sum(pb, (gfs * df[sel]).sum(-1))
                                   + (g_shared[gs] * da[gs]).sum(-1))
                done = ~accepted & (pred < CONVERGED_GAIN)
                active &= ~done
                accepted |= done
                if accepted.all():
                    break
            crossing = pb.nonneg and E and (st.beta[sel] + df[sel, Pf - E:] < 0).any()
            if crossing:
                # blendshape weights the step takes below 0 go to 0 and the others are solved
                # again given that (clamping them alone would leave a step the model did not
                # predict, and a third of the second iterations rejected it)
                if unit is not None:
                    df, da = _fix_at_bound(pb, st.beta[sel], df, da, unit, sel)
                else:
                    Hd, Hfs, gfs, ga_s, off_s = _to_bound(pb, st.beta[sel], df[sel], Hd, Hfs,
                                                          gfs, ga[gs], off)
                    df, da = _damped_step(pb, Hd, Hfs, gfs, Haa[gs], ga_s, off_s, mu[gs], sel)
            new = _apply(pb, st, df, da, n_t, n_rho)
            cost1 = np.full(G, np.inf)
            cost1[gs] = _subset_cost(pb, new, W, sel)
            ok = np.isfinite(cost1) & (cost1 <= cost0) & ~accepted
            gain = np.where(ok, cost0 - cost1, gain)
            if ok.any():
                near = ok & (cost0 - cost1 < ESTIMATE_BELOW_GAIN)
                if off is None and near.any() and (pb.sliding is None or (it + 1) % slide_every):
                    # the next iteration's convergence test, estimated with this Jacobian:
                    # a group it passes by a wide margin is done without new normal equations
                    est = _predicted_decrease(pb, new, ne.rows, Hd, Hfs, Haa[gs], mu[gs], sel,
                                              whole is not None)
                    active &= ~(near & (est < CONVERGED_GAIN / 10))
                st = _merge(pb, st, new, ok[gidx], ok)
                accepted |= ok
                stepped |= ok
                mu = np.where(ok, np.maximum(mu / 3, 1e-9), mu)
            mu = np.where(~accepted, mu * 8, mu)
            if accepted.all():
                break
        if not stepped.any() and not active.any():
            break
        iters += 1
        # a group stops when no damping gave it a better step, or when it has converged
        active &= stepped & (gain > np.maximum(1e-6 * cost0, CONVERGED_GAIN)) & (mu <= 1e8)
        if not active.any():
            break
    return st, iters


def _predicted_decrease(pb, st, rows, Hd, Hfs, Haa, mu, sel, whole: bool):
    """The decrease (G,) the damped Gauss-Newton model predicts for a step from ``st`` (G,
    inf outside ``sel``), from the weighted Jacobian rows ``rows`` of the state the step left
    and that step's blocks (Hd, Hfs, Haa, mu: :func:`_damped_step`, or with ``whole`` Hd the
    damped whole system of :func:`_whole_step`): the residuals' change is the new state's, the
    Jacobian's is not. At a Gauss-Newton step's end the gradient of the linearisation is 0, so
    what remains is the residuals' nonlinearity. On 40 benchmark faces (inner 51) it was
    0.07-10x the decrease new normal equations then predicted, and wherever it was below
    ``CONVERGED_GAIN / 10`` so was theirs below ``CONVERGED_GAIN``: fits end with the same
    results and iterations as with the full test (docs/fitting.md)."""
    _, _, _, _, _, r = residuals(pb, st, False)
    gf, ga, _ = _gradient(pb, st, rows, r)
    gs = slice(None) if pb.shared else sel
    if whole:
        df, da, _ = _whole_step(pb, Hd, gf[sel], ga[gs], sel)
    else:
        df, da = _damped_step(pb, Hd, Hfs, gf[sel], Haa, ga[gs], None, mu, sel)
    out = np.full(len(ga), np.inf)
    out[gs] = -0.5 * (group_sum(pb, (gf[sel] * df[sel]).sum(-1)) + (ga[gs] * da[gs]).sum(-1))
    return out


def _whole_step(pb, H, gfs, ga, sel, unit: bool = False):
    """The damped Gauss-Newton step of the frames ``sel``, each a group of one frame, solved
    whole -> df (N, Pf), da (G, K), unit: H (n, P, P) their damped systems
    (:attr:`NormalEquations.H`, Marquardt's damping on the whole diagonal), gfs (n, Pf) and
    ga (n, K) their gradients. With ``unit`` and blendshapes, ``unit`` (n, P, E) is the
    systems' inverse times the blendshape weights' unit vectors (its columns of the inverse,
    from the same factorisation: :func:`_fix_at_bound`); None otherwise."""
    N, G, E = pb.N, 1 if pb.shared else pb.N, pb.E
    n, Pf = gfs.shape
    P = H.shape[-1]
    bounded = bool(unit and E)
    rhs = np.zeros((n, P, 1 + E * bounded))
    rhs[:, :Pf, 0], rhs[:, Pf:, 0] = gfs, ga
    if bounded:
        rhs[:, Pf - E:Pf, 1:] = np.eye(E)
    x = np.linalg.solve(H, rhs)
    df, da = np.zeros((N, Pf)), np.zeros((G, P - Pf))
    df[sel], da[slice(None) if pb.shared else sel] = -x[:, :Pf, 0], -x[:, Pf:, 0]
    return df, da, x[..., 1:] if bounded else None


def _damped_step(pb, Hd, Hfs, gfs, Haa, ga, off, mu, sel):
    """The damped Gauss-Newton step of the frames ``sel`` where they are not solved whole
    (:func:`_whole_step`) -> df (N, Pf), da (G, K): Hd (n, Pf, Pf) their damped blocks, Hfs
    (n, Pf, K), gfs (n, Pf), and Haa (g, K, K) and ga (g, K) those of their groups, mu (g,)
    the groups' damping, which the shared coefficients get times their diagonal (+1e-9, as the
    frames' blocks in Hd: Marquardt's damping of the whole system); ``off`` the offsets' blocks
    or None. A shared identity of several frames is solved by the Schur complement of its
    frames' blocks, one without shared coefficients frame by frame."""
    if off is not None:
        return damped_step(Hd, Hfs, gfs, Haa, ga, off, mu[0])
    N, G, K = pb.N, 1 if pb.shared else pb.N, pb.K
    Pf = Hd.shape[-1]
    df, da = np.zeros((N, Pf)), np.zeros((G, K))
    gs = slice(None) if pb.shared else sel
    if not K:
        df[sel] = -np.linalg.solve(Hd, gfs[..., None])[..., 0]
        return df, da
    Had = Haa.copy()
    _damp(Had, mu)
    sol = np.linalg.solve(Hd, np.concatenate([Hfs, gfs[..., None]], -1))
    X1, x2 = sol[..., :K], sol[..., K]
    Sa = Had - group_sum(pb, Hfs.transpose(0, 2, 1) @ X1)
    ba = ga - group_sum(pb, (x2[:, None, :] @ Hfs)[:, 0])
    da[gs] = -np.linalg.solve(Sa, ba[..., None])[..., 0]
    df[sel] = -(x2 + (X1 @ da[group_index(pb)[sel]][..., None])[..., 0])
    return df, da


def _damp(H, mu):
    """Marquardt's damping in place: H (n, P, P) (a view is fine) gets ``mu`` (n,) times its
    diagonal, +1e-9, added to its diagonal."""
    d = np.einsum("nii->ni", H)
    d += mu[:, None] * (d + 1e-9)


def _fix_at_bound(pb, beta, df, da, unit, sel):
    """The whole-solve step (df (N, Pf), da (G, K) of the frames ``sel``) with each blendshape
    weight it takes below 0 fixed at 0: the minimum of the same damped model under those
    equalities, a correction along the inverse's columns ``unit`` (n, Pf + K, E) of the fixed
    weights (the Lagrange multipliers solve their E x E block; the free weights' rows and
    columns of it are the identity's) -> df, da. The same step as :func:`_to_bound` and a new
    solve, without the new factorisation."""
    Pf = df.shape[1]
    E = beta.shape[1]
    gs = slice(None) if pb.shared else sel
    x = np.concatenate([df[sel], da[gs]], -1)                              # (n, P)
    fix = beta + x[:, Pf - E:Pf] < 0                                       # (n, E)
    M = np.where(fix[:, :, None] & fix[:, None, :], unit[:, Pf - E:Pf], 0.0) + np.eye(E) * ~fix[:, None]
    lam = np.linalg.solve(M, np.where(fix, -beta - x[:, Pf - E:Pf], 0.0)[..., None])
    x = x + (unit @ lam)[..., 0]
    x[:, Pf - E:Pf] = np.where(fix, -beta, x[:, Pf - E:Pf])                # exactly at the bound
    df[sel], da[gs] = x[:, :Pf], x[:, Pf:]
    return df, da


def _to_bound(pb, beta, df, Hd, Hfs, gfs, ga, off):
    """The blocks of the same step with each blendshape weight that ``df`` (n, Pf) takes below
    0 fixed at 0 (its step ``-beta``): the fixed steps move to the right-hand sides and their
    rows and columns become the identity's, so that the solve returns them unchanged ->
    the Hd, Hfs, gfs, ga and off of :func:`_damped_step`."""
    n, Pf = df.shape
    E = beta.shape[1]
    fix = np.zeros((n, Pf), bool)
    fix[:, Pf - E:] = beta + df[:, Pf - E:] < 0
    c = np.where(fix, np.pad(-beta, ((0, 0), (Pf - E, 0))), 0.0)        # (n, Pf) fixed steps
    keep = ~fix
    gfs = np.where(keep, gfs + (Hd @ c[..., None])[..., 0], -c)
    ga = ga + group_sum(pb, (c[:, None, :] @ Hfs)[:, 0])
    Hd = np.where(keep[:, :, None] & keep[:, None, :], Hd, 0.0) + fix[:, :, None] * np.eye(Pf)
    Hfs = np.where(keep[:, :, None], Hfs, 0.0)
    if off is not None:
        frames = off.C[..., :n * Pf]
        gd = off.gd + (frames * c.reshape(-1)).sum(-1)
        off = off._replace(C=np.concatenate([np.where(keep.reshape(-1), frames, 0.0),
                                             off.C[..., n * Pf:]], -1), gd=gd)
    return Hd, Hfs, gfs, ga, off


class NormalEquations(NamedTuple):
    """The Gauss-Newton blocks at a state, priors included (:func:`normal_equations`).

    ``H`` (N, P, P) holds each frame's system over its parameters (rotation, translation,
    scale (affine) and expressions: Pf) and the shared coefficients (K), whose block is that
    frame's only; where each frame is its own group (one frame, or independent identities) it
    is the whole system, priors included. ``Hff`` (N, Pf, Pf) and ``Hfa`` (N, Pf, K) are
    views of it, ``Haa`` (G, K, K) the groups' shared block (a view of H where it is the
    whole system); gf (N, Pf), ga (G, K) the gradient; W (N, L) the data weights; ``act``
    (N, Pf) the expression bound's active set; ``cost`` (G,); ``off`` the landmark offsets'
    blocks (:class:`~morphable.fitting.offsets.OffsetBlocks`; None without offsets, else the
    shared coefficients here are the identity's only); ``rows`` = (Q (N, 2 L, P), s (N, 2 L,
    1)) the Jacobian rows times the square roots ``s`` of their weights."""
    H: np.ndarray
    Hff: np.ndarray
    Hfa: np.ndarray
    Haa: np.ndarray
    gf: np.ndarray
    ga: np.ndarray
    W: np.ndarray
    act: np.ndarray
    cost: np.ndarray
    off: object
    rows: tuple


def _frame_params(pb):
    """(n_t, n_rho, Pf): translations, log-scales and all parameters of a frame."""
    n_t, n_rho = (3, 0) if pb.perspective else (2, 1)
    return n_t, n_rho, 3 + n_t + n_rho + pb.E


def normal_equations(pb: Problem, st: State) -> NormalEquations:
    """The Gauss-Newton blocks at the current state, priors included
    (:class:`NormalEquations`)."""
    N, E = pb.N, pb.E
    n_t, n_rho, Pf = _frame_params(pb)
    X, uv, Xc, Jp, depth, r = residuals(pb, st, True)
    W = _robust(pb, weights(pb, st, depth), r)
    cost0 = _group_cost(pb, st, _data_cost(pb, st, W, r, depth))
    # Jacobian rows coordinate-major: the L x residuals, then the L y residuals
    L = r.shape[1]
    RX = Xc - st.t[:, None]
    blocks = [cross(RX[:, :, None, :], Jp), Jp[..., :n_t]]
    if n_rho:
        blocks.append((uv - pb.principal[:, None])[..., None])     # d uv / d log(scale)
    blocks = [np.concatenate(blocks, -1).transpose(0, 2, 1, 3)]
    # the affine Jacobian is the same for every point: one GEMM per frame
    JpR = Jp[:, 0] @ st.R if not pb.perspective else Jp @ st.R[:, None]
    if E:
        blocks.append(project_rows(JpR, st.rows[2]))
    S = shared_rows(pb, st)                                         # (N, 3, L, K)
    blocks.append(project_rows(JpR, S))
    J4 = _across_rows(pb, np.concatenate(blocks, -1))               # (N, 2, L, P)
    P = J4.shape[-1]
    K = P - Pf
    off = offset_normal(pb, st, JpR, W, r, J4[..., :Pf], S[0]) if pb.D else None
    # the rows times the square roots of their weights: the Hessian is their Gram matrix, one
    # symmetric product (half the arithmetic of a general one)
    Q, sw = weighted_rows(W, J4)                                    # (N, 2 L, P)
    gf, ga, act = _gradient(pb, st, (Q, sw), r)
    Qt = Q.transpose(0, 2, 1)
    if pb.gram is None or JpR.ndim != 3:
        H = Qt @ Q
    else:
        # the shared block from the fixed landmarks' Gram blocks (linear.gram_hessian)
        H = np.empty((N, P, P))
        H[:, :Pf] = Qt[:, :Pf] @ Q
        H[:, Pf:, :Pf] = H[:, :Pf, Pf:].transpose(0, 2, 1)
        shift = (offsets(pb, st.alpha)[0], pb.size_direction) if pb.D else None
        H[:, Pf:, Pf:] = gram_hessian(JpR, W, Q[..., Pf:].reshape(N, 2, L, K), pb.gram, shift)
    diag = np.einsum("nii->ni", H)                  # a view
    diag[:, Pf - E:Pf] += pb.expression_weight
    if act.any():
        # the held weights' rows and columns become the identity's (in place)
        held = np.zeros((N, P), bool)
        held[:, :Pf] = act
        H[held] = 0.0
        H.transpose(0, 2, 1)[held] = 0.0
        diag[held] = 1.0
        if off is not None:
            frames = np.where(~act.reshape(-1), off.C[..., :N * Pf], 0.0)
            off = off._replace(C=np.concatenate([frames, off.C[..., N * Pf:]], -1))
    # each frame its own group: its shared block is the group's (a view: the prior goes
    # into H, which is then the whole system)
    Haa = H[:, Pf:, Pf:] if not pb.shared or N == 1 else H[:, Pf:, Pf:].sum(0, keepdims=True)
    np.einsum("nii->ni", Haa)[:] += pb.prior[:K]
    return NormalEquations(H, H[:, :Pf, :Pf], H[:, :Pf, Pf:], Haa, gf, ga, W, act, cost0, off,
                           (Q, sw))


def _gradient(pb, st, rows, r):
    """The cost's gradient (in the Gauss-Newton scale of the normal equations) at ``st``,
    priors included, from the weighted Jacobian rows ``rows`` = (Q (N, 2 L, P), s (N, 2 L, 1):
    :attr:`NormalEquations.rows`) and the residuals ``r`` (N, L, 2) px -> gf (N, Pf), ga (G,
    K), and the expression bound's active set act (N, Pf): the blendshape weights held at 0
    whose gradient would take them below (their gf is 0: they leave the step, projected
    Newton)."""
    Q, sw = rows
    E, Pf = pb.E, _frame_params(pb)[2]
    rr = r.transpose(0, 2, 1).reshape(len(r), -1, 1)
    g = (Q.transpose(0, 2, 1) @ (sw * rr))[..., 0]
    gf, ga = g[:, :Pf], group_sum(pb, g[:, Pf:])
    act = np.zeros(gf.shape, bool)
    if E:
        gf[:, -E:] += pb.expression_weight * st.beta
        if pb.nonneg:
            act[:, -E:] = (st.beta <= 0) & (gf[:, -E:] > 0)
            gf[act] = 0.0
    K = ga.shape[-1]
    return gf, ga + pb.prior[:K] * (st.alpha[:, :K] - pb.prior_mean[:K]), act


def _across_rows(pb: Problem, J):
    """The same projection for coordinate-major Jacobian rows (N, 2, L, P), in place, on the
    sliding columns only."""
    if pb.sliding is None:
        return J
    t = pb.tangent[:, pb.sliding].transpose(0, 2, 1)[..., None]      # (N, 2, J, 1)
    Js = J[:, :, pb.sliding]
    J[:, :, pb.sliding] = Js - t * (t * Js).sum(1, keepdims=True)
    return J


def _robust(pb, W, r):
    if pb.robust is None:
        return W
    e = np.sqrt(W * (r * r).sum(-1))
    return W * np.where(e > pb.huber_k, pb.huber_k / np.maximum(e, 1e-300), 1.0)


def _data_cost(pb, st, W, r, depth, sel=slice(None)):
    """(n,) per-frame costs of the frames ``sel`` (W, r, depth: theirs)."""
    c = (W * (r * r).sum(-1)).sum(1)
    if pb.perspective:
        bad = ((W > 0) & (depth <= 1e-3)).any(1)
        c = np.where(bad, np.inf, c)
    if pb.E:
        c = c + pb.expression_weight * (st.beta[sel] ** 2).sum(1)
    return c


def _group_cost(pb, st, frame_cost, sel=slice(None)):
    """Group costs from the per-frame costs of the frames ``sel`` (all frames for a shared
    identity)."""
    g = frame_cost.sum(0, keepdims=True) if pb.shared else frame_cost
    if pb.K:
        alpha = st.alpha if pb.shared else st.alpha[sel]
        g = g + (pb.prior * (alpha - pb.prior_mean) ** 2).sum(1)
    return g


def _subset_cost(pb, st, W, sel):
    """Group costs of the frames ``sel`` (all frames for a shared identity)."""
    _, _, _, _, depth, r = residuals(pb, st, False, sel)
    return _group_cost(pb, st, _data_cost(pb, st, W[sel], r, depth, sel), sel)


def _apply(pb, st, df, da, n_t, n_rho):
    t = st.t.copy()
    t[:, :n_t] += df[:, 3:3 + n_t]
    k = st.k * np.exp(np.minimum(np.maximum(df[:, 3 + n_t], -2.0), 2.0)) if n_rho else st.k
    o = 3 + n_t + n_rho
    beta = st.beta
    if pb.E:
        beta = st.beta + df[:, o:]
        if pb.nonneg:
            beta = np.maximum(beta, 0.0)
    alpha = st.alpha + da if pb.K else st.alpha
    return State(rotate(st.R, df[:, :3]), t, k, alpha, beta, st.corr, st.rows)


def _merge(pb, old, new, frames_ok, groups_ok):
    if frames_ok.all() and groups_ok.all():
        return new
    f = frames_ok
    return State(np.where(f[:, None, None], new.R, old.R), np.where(f[:, None], new.t, old.t),
                  np.where(f, new.k, old.k), np.where(groups_ok[:, None], new.alpha, old.alpha),
                  np.where(f[:, None], new.beta, old.beta), old.corr, old.rows)
