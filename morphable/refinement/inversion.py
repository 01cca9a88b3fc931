"""Refining a landmark fit by inverting a renderer: :func:`refine` (one frame) and
:func:`refine_frames` (each frame of a video), short orchestrators over the steps of
:mod:`~morphable.refinement.problem` and :mod:`.loss`, the optimisation (:func:`optimise`) and
the mapping back into the fit (:func:`map_back`)."""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..errors import FitError, InputError
from ..threads import single_blas_thread, single_torch_thread
from .editing import Refinement
from .geometry import project_points
from .loss import loss_function, loss_weights, perceptual_features
from .problem import Problem, Unknowns, set_up, start

__all__ = ["refine", "refine_frames", "optimise", "map_back", "Run", "LEARNING_RATES"]

LEARNING_RATES = {"alpha": 0.03, "beta": 0.02, "rot": 0.003, "trans": 0.3}
"""Adam learning rates of the geometry (the appearance's are the renderer's
``learning_rates``)."""


def _renderer(renderer, options):
    """A renderer object and its name for the report."""
    from ..renderer_plugins import RendererBase, get_renderer

    name = renderer if isinstance(renderer, str) else type(renderer).__name__
    if isinstance(renderer, str):
        renderer = get_renderer(renderer, **(options or {}))
    if not isinstance(renderer, RendererBase):
        raise InputError(f"renderer {name!r}: inverting it needs the hooks of "
                         "morphable.renderer_plugins.RendererBase (derive from it)")
    return renderer, name


@single_blas_thread()
@single_torch_thread()
def refine(image, fit, renderer="classical", *, steps: int = 100, frame: int = 0,
           weights: dict | None = None, features=None, resolution: int = 64,
           renderer_options: dict | None = None, seed: int = 0, return_state: bool = False,
           trace_every: int = 0):
    """Refine a landmark fit by photometric inversion of a renderer.

    Parameters
    ----------
    image : (H, W, 3) uint8 or float [0, 1], the image of ``fit``'s frame ``frame``
    fit : FitResult of :func:`morphable.fitting.fit_landmarks`
    renderer : a renderer name ("classical", "gar") or object (:mod:`morphable.renderer_plugins`;
        the gar renderer's options include its inverter V, ``inverter=``)
    steps : Adam iterations
    weights : overrides of :data:`~morphable.refinement.DEFAULT_WEIGHTS`
    features : None (a renderer plugin's features), a TorchScript path or a callable
        (perceptual term)
    resolution : crop size for renderers of any resolution (classical)
    renderer_options : keyword options of ``get_renderer``
    seed : of the renderer's random start (gar: the prior part of V's latent)
    return_state : also return a :class:`~morphable.refinement.Refinement`
    trace_every : when > 0, the report's ``trace`` lists
        ``{"step", "seconds", "alpha", "beta"}`` every ``trace_every`` steps and at the end
        (error against run time)

    Returns
    -------
    (FitResult, report) or (FitResult, report, Refinement)
        The report holds ``photometric_loss`` and ``loss`` per step, ``runtime_s``, the
        landmark RMSE (px) before/after, the feature network and how the renderer chose its
        starting appearance (``latent_init``; None for renderers that do not say).
    """
    t0 = time.perf_counter()
    renderer, name = _renderer(renderer, renderer_options)
    if int(steps) < 0:
        raise InputError(f"steps must be >= 0, got {steps}")
    problem = set_up(image, fit, frame, renderer.resolution or int(resolution))
    unknowns = start(problem, renderer, seed)
    w = loss_weights(fit, frame, weights)
    feat_fn, feat_name = perceptual_features(features, renderer) if w["feat"] > 0 else (None, "none")
    loss = loss_function(problem, unknowns, renderer, w, feat_fn)
    run = optimise(loss, unknowns, renderer, int(steps),
                   fit.model.expression_kind == "blendshapes", trace_every, t0)
    new_fit, state = map_back(problem, unknowns, renderer, run.rendered)
    report = {"renderer": name, "renderer_weights": getattr(renderer, "weights", None),
              "steps": int(steps), "resolution": problem.resolution,
              "crop_px": [round(c, 2) for c in problem.crop], "features": feat_name,
              "latent_init": unknowns.appearance_init, "loss_weights": w,
              "photometric_loss": run.photometric_loss, "loss": run.loss,
              "landmark_rmse_px_before": float(fit.landmark_rmse_px[frame]),
              "landmark_rmse_px_after": float(new_fit.landmark_rmse_px[frame]),
              "runtime_s": round(time.perf_counter() - t0, 3)}
    if trace_every > 0:
        report["trace"] = run.trace
    return (new_fit, report, state) if return_state else (new_fit, report)


@dataclasses.dataclass
class Run:
    """What :func:`optimise` did: ``loss`` and ``photometric_loss`` per step and of the final
    state, the ``trace`` points and the final render ``rendered`` (R, R, 3) numpy."""

    loss: list
    photometric_loss: list
    trace: list
    rendered: np.ndarray


def optimise(loss, unknowns: Unknowns, renderer, steps: int, blendshapes: bool,
             trace_every: int = 0, t0: float | None = None) -> Run:
    """Adam on ``loss`` over the geometry and the appearance entries the renderer's
    ``learning_rates`` name, ``steps`` times; blendshape weights stay >= 0 and the renderer
    keeps its appearance valid (``constrain_appearance``). With ``trace_every`` > 0 the
    coefficients every ``trace_every`` steps and at the end, with the seconds since ``t0``."""
    import torch

    u = unknowns
    t0 = time.perf_counter() if t0 is None else t0
    opt = torch.optim.Adam(_parameter_groups(u, renderer))
    history, photo, trace = [], [], []
    for step in range(steps):
        if trace_every > 0 and step % trace_every == 0:
            trace.append(_trace_point(step, u, t0))
        total, terms, _ = loss()
        if not torch.isfinite(total):
            raise FitError("refine: the loss became NaN or inf; try fewer steps or smaller weights")
        opt.zero_grad(set_to_none=True)
        total.backward()
        opt.step()
        with torch.no_grad():
            if blendshapes:
                u.beta.clamp_(min=0)
            renderer.constrain_appearance(u.appearance)
        history.append(float(total.detach()))
        photo.append(float(terms["photo"].detach()))
    with torch.no_grad():
        total, terms, img = loss()
    if trace_every > 0:
        trace.append(_trace_point(steps, u, t0))
    return Run(history + [float(total)], photo + [float(terms["photo"])], trace,
               img[0].permute(1, 2, 0).numpy())


def _parameter_groups(u: Unknowns, renderer) -> list:
    """Adam's groups: the appearance entries the renderer moves, then the geometry."""
    groups = []
    for k, v in u.appearance.items():
        ts = v if isinstance(v, list) else [v]
        for tsr in ts:
            tsr.requires_grad_(True)
        if k in renderer.learning_rates:
            groups.append({"params": ts, "lr": renderer.learning_rates[k]})
    return groups + [{"params": [getattr(u, k)], "lr": lr} for k, lr in LEARNING_RATES.items()]


def _trace_point(step: int, u: Unknowns, t0: float) -> dict:
    return {"step": step, "seconds": round(time.perf_counter() - t0, 4),
            "alpha": u.alpha.detach().double().tolist(), "beta": u.beta.detach().double().tolist()}


def map_back(problem: Problem, unknowns: Unknowns, renderer, rendered):
    """The refined frame back in the original image -> (FitResult, Refinement): the fit with
    the new coefficients, the same rotation and the translation offset in the image camera,
    and its landmark RMSE; ``rendered`` (R, R, 3) is the final render."""
    import torch

    fit, frame, u = problem.fit, problem.frame, unknowns
    with torch.no_grad():
        Rt = u.rotation().double().numpy()
        tt = u.translation().double().numpy()
    a, b = u.alpha.detach().double().numpy(), u.beta.detach().double().numpy()
    pts = fit.model.vertices_at(problem.landmark_ids.numpy(), a, b)
    uv = project_points(problem.camera, torch.as_tensor(pts), torch.as_tensor(Rt),
                        torch.as_tensor(tt)).numpy()
    lm_err = np.linalg.norm(problem.to_image(uv) - problem.observed, axis=1)
    frame_identity = np.array(fit.frame_identity, dtype=np.float64)
    frame_identity[frame] = a
    expression = np.array(fit.expression, dtype=np.float64)
    expression[frame] = b
    cams = list(fit.cameras)
    cams[frame] = dataclasses.replace(fit.cameras[frame], rotation=Rt, translation=tt)
    rmse = np.array(fit.landmark_rmse_px, dtype=np.float64)
    rmse[frame] = float(np.sqrt(np.mean(lm_err ** 2)))
    new_fit = dataclasses.replace(fit, identity=a if fit.n_frames == 1 else fit.identity,
                                  frame_identity=frame_identity, expression=expression,
                                  cameras=cams, landmark_rmse_px=rmse)
    app = {k: (v.detach() if torch.is_tensor(v) else [e.detach() for e in v])
           for k, v in u.appearance.items()}
    crop_cam = dataclasses.replace(problem.camera, rotation=Rt, translation=tt)
    return new_fit, Refinement(renderer, app, problem.crop, crop_cam, problem.target, rendered,
                               new_fit)


def refine_frames(model, images, landmarks, renderer="gar", *, steps: int = 100,
                  n_iterations: int = 4, fit_options: dict | None = None,
                  **options) -> tuple[np.ndarray, list]:
    """Reconstruct each frame of a video on its own: landmark fit, then :func:`refine`.

    Parameters
    ----------
    model : MorphableModel
    images : (N, H, W, 3) float [0, 1] or uint8, one image per frame
    landmarks : (N, L, 2) px, NaN where missing: iBUG-68 (L = 68) or the face mesh's
        (L = 478), as :func:`~morphable.fitting.fit_landmarks` takes them
    renderer, steps, options : as :func:`refine` (the renderer is loaded once, with its
        inverter for gar)
    n_iterations : of the landmark fit
    fit_options : further keyword arguments of the landmark fit
        (:func:`~morphable.fitting.fit_landmarks`, one independent fit per frame, all frames in
        one batch), e.g. ``camera="perspective"`` with ``focal_px`` when the video's camera is
        known, or per-frame values such as ``model_std_mm``

    Returns
    -------
    vertices (N, V, 3) mm in the model frame, and the N refinement reports.
    """
    from ..fitting import fit_landmarks

    renderer, _ = _renderer(renderer, options.pop("renderer_options", None))
    images = np.asarray(images)
    H, W = images.shape[1:3]
    fit = fit_landmarks(model, np.asarray(landmarks, dtype=np.float64), [W, H],
                        shared_identity=False, n_iterations=n_iterations, **(fit_options or {}))
    out, reports = [], []
    for i, image in enumerate(images):
        res, rep = refine(image, fit, renderer, steps=steps, frame=i, **options)
        out.append(res.vertices(i))
        reports.append(rep)
    return np.stack(out), reports
