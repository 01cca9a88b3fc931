"""Refining a landmark fit by inverting a renderer: :func:`refine_shared` (one person's frames
together: one identity, each frame's expression, pose and appearance), :func:`refine` (one
frame) and :func:`refine_frames` (each frame of a video on its own), short orchestrators over
the steps of :mod:`~morphable.refinement.problem`, :mod:`.mask` and :mod:`.loss`, the
optimisation (:func:`optimise`) and the mapping back into the fit (:func:`map_back`)."""
from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from ..errors import FitError, InputError
from ..threads import single_blas_thread, single_torch_thread
from .editing import Refinement
from .geometry import pixel_view, project_points
from .loss import loss_function, loss_weights, perceptual_features
from .mask import MIN_COVERAGE, mask_coverage, pixel_weights
from .problem import Problem, Unknowns, recast, set_up, start

__all__ = ["refine", "refine_shared", "refine_frames", "optimise", "map_back", "Run",
           "LEARNING_RATES", "RECAST_EVERY", "SOLVE_EVERY", "DEFAULT_RESOLUTION"]

LEARNING_RATES = {"alpha": 0.03, "beta": 0.02, "rot": 0.003, "trans": 0.3}
"""Adam learning rates of the geometry (the appearance's are the renderer's
``learning_rates``)."""

RECAST_EVERY = 10
"""Steps between two re-casts of each frame's visibility at the moved shape and pose (a cast
of a 256-px crop costs about as much as one step; between casts the pixels keep the surface
points they saw)."""

SOLVE_EVERY = 10
"""Steps between two closed-form appearance solves and mask re-estimations (a closed form
and a mask cost about three steps' time; the geometry moves little in 10 steps). Each re-cast
is followed by one."""

DEFAULT_RESOLUTION = 256
"""Crop side (px) for renderers of any resolution (the classical one)."""

log = logging.getLogger(__name__)


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


def refine(image, fit, renderer="classical", *, steps: int = 100, frame: int = 0,
           weights: dict | None = None, features=None, resolution: int = DEFAULT_RESOLUTION,
           renderer_options: dict | None = None, seed: int = 0, return_state: bool = False,
           trace_every: int = 0, recast_every: int = RECAST_EVERY):
    """Refine frame ``frame`` of a landmark fit by photometric inversion of a renderer
    (:func:`refine_shared` on that frame alone: the refined identity becomes that frame's
    ``frame_identity``, and the fit's ``identity`` for a fit of one frame).

    Parameters
    ----------
    image : (H, W, 3) uint8 or float [0, 1], or a path: the image of ``fit``'s frame ``frame``
    fit : FitResult of :func:`morphable.fitting.fit_landmarks`
    renderer, steps, weights, features, resolution, renderer_options, seed, trace_every,
    recast_every : as :func:`refine_shared`
    return_state : also return a :class:`~morphable.refinement.Refinement`

    Returns
    -------
    (FitResult, report) or (FitResult, report, Refinement); the report as each of
    :func:`refine_shared`'s.
    """
    new_fit, reports, states = refine_shared(
        [image], fit, renderer, frames=[frame], steps=steps, weights=weights, features=features,
        resolution=resolution, renderer_options=renderer_options, seed=seed,
        trace_every=trace_every, recast_every=recast_every)
    return (new_fit, reports[0], states[0]) if return_state else (new_fit, reports[0])


def _images(images, fit, frames, labels):
    """The frames' images as (H, W, 3) uint8 with their names, each checked against the size
    of its frame's camera."""
    from ..detection.images import as_image

    out, names = [], []
    for k, (image, f) in enumerate(zip(images, frames)):
        a, name = as_image(image, labels[k] if labels else f"image {k}")
        W, H = (int(v) for v in fit.cameras[f].image_size)
        if a.shape[:2] != (H, W):
            raise InputError(f"{name}: image is {a.shape[1]}x{a.shape[0]}, frame {f} of the fit "
                             f"is {W}x{H}")
        out.append(a)
        names.append(name)
    return out, names


@single_blas_thread()
@single_torch_thread()
def refine_shared(images, fit, renderer="classical", *, frames=None, steps: int = 100,
                  weights: dict | None = None, features=None,
                  resolution: int = DEFAULT_RESOLUTION, renderer_options: dict | None = None,
                  seed: int = 0, trace_every: int = 0, recast_every: int = RECAST_EVERY,
                  labels=None):
    """Refine a landmark fit of one person by photometric inversion of a renderer, all frames
    at once: one identity shared by the frames, each frame's expression, pose and appearance.

    The loop (docs/photometric.md): each frame is cropped (:func:`set_up`, ``resolution`` px
    unless the renderer has its own); the appearance starts where the renderer puts it
    (``initial_appearance``, then ``solve_appearance`` for a renderer with a closed form: the
    classical one's albedo texture, shared, and SH light per frame); the robust mask
    (:func:`~.mask.pixel_weights`) is estimated from the residual. Then ``steps`` Adam steps
    move the identity, expressions and poses (and the appearance entries of the renderer's
    ``learning_rates`` when it has no closed form) on the masked photometric error, the
    landmark term and the priors (:mod:`.loss`); every :data:`SOLVE_EVERY` steps the
    appearance is solved again and the mask re-estimated, every ``recast_every`` steps the
    visibility is re-cast at the moved shape. A frame whose mask keeps under
    :data:`~.mask.MIN_COVERAGE` of its face keeps its landmark fit (its expression and pose;
    a warning is logged); an InputError when that is every frame.

    Parameters
    ----------
    images : the images of the frames refined, in the order of ``frames``: (H, W, 3) uint8 or
        float [0, 1] arrays or paths, each of its frame's camera size
    fit : FitResult of :func:`morphable.fitting.fit_landmarks`
    renderer : a renderer name ("classical", "gar") or object (:mod:`morphable.renderer_plugins`;
        the gar renderer's options include its inverter V, ``inverter=``)
    frames : the frame indices refined (default: all)
    steps : Adam iterations
    weights : overrides of :data:`~morphable.refinement.DEFAULT_WEIGHTS` (after the renderer's
        ``default_weights``)
    features : None (a renderer plugin's features), a TorchScript path or a callable
        (perceptual term; off by default for the classical renderer)
    resolution : crop size (px) for renderers of any resolution (classical)
    renderer_options : keyword options of ``get_renderer``
    seed : of the renderer's random start (gar: the prior part of V's latent)
    trace_every : when > 0, each report's ``trace`` lists
        ``{"step", "seconds", "alpha", "beta"}`` every ``trace_every`` steps and at the end
    recast_every : steps between visibility re-casts (0: never)
    labels : the images' names for messages (default: their paths, or "image k")

    Returns
    -------
    (FitResult, reports, states)
        The refined fit (the frames' ``frame_identity`` rows the shared identity; the fit's
        ``identity`` too when every frame was refined); per frame a report: ``photometric_loss``
        and ``loss`` per step and at the end, ``mask_coverage``, ``photometric_residual``
        (RMS colour error over the mask, in [0, 1] intensity), ``fallback`` (True: kept its
        landmark fit), ``landmark_rmse_px_before``/``_after``, ``runtime_s`` and ``stage_s``
        (the run's, all frames: set-up, appearance, mask, visibility, geometry), the feature
        network, the loss weights and how the renderer chose its starting appearance
        (``latent_init``); and per frame a :class:`~morphable.refinement.Refinement`.
    """
    import torch

    t0 = time.perf_counter()
    renderer, name = _renderer(renderer, renderer_options)
    frames = list(range(fit.n_frames)) if frames is None else [int(f) for f in frames]
    if len(images) != len(frames):
        raise InputError(f"{len(images)} images for {len(frames)} frames")
    if not frames or len(set(frames)) != len(frames) or not all(0 <= f < fit.n_frames for f in frames):
        raise InputError(f"frames must be distinct indices of the fit's {fit.n_frames} frames, "
                         f"got {frames}")
    if int(steps) < 0:
        raise InputError(f"steps must be >= 0, got {steps}")
    if int(recast_every) < 0:
        raise InputError(f"recast_every must be >= 0, got {recast_every}")
    pixels, names = _images(images, fit, frames, labels)
    stage = dict.fromkeys(("set_up", "appearance", "mask", "visibility", "geometry"), 0.0)
    problems = [set_up(a, fit, f, renderer.resolution or int(resolution)) for a, f in zip(pixels, frames)]
    u = start(problems, renderer, seed)
    stage["set_up"] = time.perf_counter() - t0
    w = [loss_weights(fit, f, weights, renderer) for f in frames]
    feat_fn, feat_name = perceptual_features(features, renderer) if w[0]["feat"] > 0 else (None, "none")
    state = _LoopState(problems, u, renderer, stage)
    losses = [loss_function(state.problem_getter(i), u, i, renderer, w[i], feat_fn)
              for i in range(len(frames))]
    state.start(losses)
    if not state.active.any():
        raise InputError(f"{', '.join(names)}: the photometric mask keeps under "
                         f"{100 * MIN_COVERAGE:.0f} % of the face (a black, saturated or "
                         "occluded face); nothing to fit photometrically")
    for i in np.flatnonzero(~state.active):
        log.warning("%s: the photometric mask keeps %.1f %% of the face (under %.0f %%); the "
                    "frame keeps its landmark fit", names[i], 100 * state.coverage[i],
                    100 * MIN_COVERAGE)
    run = optimise(state, losses, w, int(steps), fit.model.expression_kind == "blendshapes",
                   int(recast_every), trace_every, t0)
    new_fit, states = map_back(state.problems, u, renderer, run.rendered, state.active,
                               [m[0, 0].numpy() for m in state.masks])
    runtime = round(time.perf_counter() - t0, 3)
    reports = []
    for i, f in enumerate(frames):
        report = {"renderer": name, "renderer_weights": getattr(renderer, "weights", None),
                  "steps": int(steps), "resolution": problems[i].resolution,
                  "crop_px": [round(c, 2) for c in problems[i].crop], "features": feat_name,
                  "latent_init": u.appearance_init, "loss_weights": w[i],
                  "appearance": "closed form" if state.closed else "gradient steps",
                  "frames_together": len(frames), "recast_every": int(recast_every),
                  "solve_every": SOLVE_EVERY,
                  "photometric_loss": run.photometric_loss[i], "loss": run.loss,
                  "mask_coverage": round(state.coverage[i], 4),
                  "photometric_residual": run.residual[i], "fallback": not bool(state.active[i]),
                  "landmark_rmse_px_before": float(fit.landmark_rmse_px[f]),
                  "landmark_rmse_px_after": float(new_fit.landmark_rmse_px[f]),
                  "runtime_s": runtime, "stage_s": {k: round(v, 3) for k, v in stage.items()}}
        if trace_every > 0:
            report["trace"] = [{**t, "beta": t["beta"][i]} for t in run.trace]
        reports.append(report)
    return new_fit, reports, states


class _LoopState:
    """The loop's moving parts besides the Unknowns: the frames' problems (re-cast as the face
    moves), masks, coverage, which frames are fitted and whether the renderer solves its
    appearance in closed form."""

    def __init__(self, problems, u, renderer, stage):
        self.problems, self.u, self.renderer, self.stage = problems, u, renderer, stage
        self.masks = [None] * len(problems)
        self.coverage = [0.0] * len(problems)
        self.active = np.ones(len(problems), dtype=bool)
        self.closed = False

    def problem_getter(self, i):
        return lambda: self.problems[i]

    def _renders(self, losses):
        """Each frame's render (R, R, 3) and normal map (R, R, 3), numpy, without gradients."""
        import torch

        out = []
        with torch.no_grad():
            for i, loss in enumerate(losses):
                _, _, img, n = loss(self.problems[i].coverage, full=True)
                out.append((img[0].permute(1, 2, 0).double().numpy(), n.double().numpy()))
        return out

    def _views(self, normals):
        return [pixel_view(p.fit.model, p.vis, n, p.uv, p.target,
                           None if m is None else m[0, 0].double().numpy())
                for p, n, m in zip(self.problems, normals, self.masks)]

    def solve(self, losses, first: bool = False):
        """Closed-form appearance (if the renderer has one) and the masks from the residual."""
        import torch

        t = time.perf_counter()
        if first or self.closed:
            if first:   # before any mask: the face pixels, clipped ones out
                self.masks = [p.coverage * torch.as_tensor(pixel_weights(
                    p.target, p.target, p.coverage[0, 0].numpy()), dtype=torch.float32)[None, None]
                    for p in self.problems]
            views = self._views([n for _, n in self._renders(losses)])
            idx = np.flatnonzero(self.active)
            self.closed = bool(self.renderer.solve_appearance(
                [self.u.appearances[i] for i in idx], [views[i] for i in idx]))
        self.stage["appearance"] += time.perf_counter() - t
        t = time.perf_counter()
        for i, (img, _) in enumerate(self._renders(losses)):
            p = self.problems[i]
            region = self.renderer.photometric_mask(p.coverage)[0, 0].double().numpy()
            m = pixel_weights(p.target, img, p.coverage[0, 0].numpy(), region)
            self.masks[i] = torch.as_tensor(m, dtype=torch.float32)[None, None]
            self.coverage[i] = mask_coverage(m, p.coverage[0, 0].numpy())
        self.stage["mask"] += time.perf_counter() - t

    def start(self, losses):
        """The starting appearance and mask, twice (the mask sharpens the appearance); the
        frames whose mask keeps too little of the face drop out."""
        self.solve(losses, first=True)
        self.solve(losses)
        self.active &= np.array(self.coverage) >= MIN_COVERAGE

    def recast(self):
        """Each fitted frame's visibility at its current shape and pose; the appearance
        follows the new pixels."""
        import torch

        t = time.perf_counter()
        u = self.u
        with torch.no_grad():
            alpha = u.alpha.double().numpy()
            for i in np.flatnonzero(self.active):
                p = self.problems[i]
                verts = p.fit.model.vertices(alpha, u.betas[i].double().numpy())
                self.problems[i] = recast(p, verts, u.rotation(i).double().numpy(),
                                          u.translation(i).double().numpy())
        self.stage["visibility"] += time.perf_counter() - t
        return self

    def follow_views(self):
        """The appearance of each fitted frame on its re-cast pixels."""
        views = self._views([None] * len(self.problems))
        for i in np.flatnonzero(self.active):
            self.u.appearances[i] = self.renderer.view_appearance(self.u.appearances[i], views[i])


@dataclasses.dataclass
class Run:
    """What :func:`optimise` did: the total ``loss`` per step and of the final state; per
    frame ``photometric_loss`` per step and final, the final ``residual`` (RMS over the
    mask) and render ``rendered`` (R, R, 3) numpy; the ``trace`` points."""

    loss: list
    photometric_loss: list
    residual: list
    trace: list
    rendered: list


def optimise(state, losses, weights, steps: int, blendshapes: bool, recast_every: int = RECAST_EVERY,
             trace_every: int = 0, t0: float | None = None) -> Run:
    """Adam on the sum of the frames' ``losses`` (:func:`~.loss.loss_function`; the identity
    prior counts once, as in a posterior over all frames: the more frames, the less it weighs
    against their data) over the shared identity,
    the fitted frames' expressions and poses and the appearance entries the renderer's
    ``learning_rates`` name when it has no closed form, ``steps`` times; blendshape weights
    stay >= 0 and the renderer keeps its appearance valid (``constrain_appearance``). The
    appearance is solved and the mask re-estimated every :data:`SOLVE_EVERY` steps, the
    visibility re-cast every ``recast_every`` (0: never). With ``trace_every`` > 0 the
    coefficients every ``trace_every`` steps and at the end, with the seconds since ``t0``."""
    import torch

    u, renderer = state.u, state.renderer
    t0 = time.perf_counter() if t0 is None else t0
    active = np.flatnonzero(state.active)
    opt = torch.optim.Adam(_parameter_groups(u, renderer, active, state.closed))
    w_alpha = weights[0]["alpha"]
    history, photo, trace = [], [[] for _ in losses], []
    for step in range(steps):
        t = time.perf_counter()
        if trace_every > 0 and step % trace_every == 0:
            trace.append(_trace_point(step, u, t0))
        total = w_alpha * u.alpha.pow(2).sum()
        for i in active:
            frame_total, terms, _, _ = losses[i](state.masks[i])
            total = total + frame_total
            photo[i].append(float(terms["photo"].detach()))
        if not torch.isfinite(total):
            raise FitError("refine: the loss became NaN or inf; try fewer steps or smaller weights")
        opt.zero_grad(set_to_none=True)
        total.backward()
        opt.step()
        with torch.no_grad():
            for i in active:
                if blendshapes:
                    u.betas[i].clamp_(min=0)
                if not state.closed:
                    renderer.constrain_appearance(u.appearances[i])
        history.append(float(total.detach()))
        state.stage["geometry"] += time.perf_counter() - t
        if step + 1 == steps:
            continue
        if recast_every > 0 and (step + 1) % recast_every == 0:
            state.recast().follow_views()
        if (step + 1) % SOLVE_EVERY == 0:
            state.solve(losses)
    with torch.no_grad():
        total = w_alpha * u.alpha.pow(2).sum()
        rendered, residual = [], []
        for i, loss in enumerate(losses):
            frame_total, terms, img, _ = loss(state.masks[i], full=True)
            if state.active[i]:
                total = total + frame_total
            photo[i].append(float(terms["photo"]))
            m = state.masks[i]
            residual.append(float(((img - state.problems[i].image).pow(2) * m).sum()
                                  / (3 * m.sum()).clamp_min(1e-6)) ** 0.5)
            rendered.append(img[0].permute(1, 2, 0).numpy())
    if trace_every > 0:
        trace.append(_trace_point(steps, u, t0))
    return Run(history + [float(total)], photo, [round(r, 5) for r in residual], trace, rendered)


def _parameter_groups(u: Unknowns, renderer, active, closed: bool) -> list:
    """Adam's groups: the appearance entries the renderer moves (none when it solves them in
    closed form), then the geometry of the fitted frames."""
    groups = []
    for i in active:
        for k, v in u.appearances[i].items():
            ts = v if isinstance(v, list) else [v]
            if k in renderer.learning_rates and not closed:
                for tsr in ts:
                    tsr.requires_grad_(True)
                groups.append({"params": ts, "lr": renderer.learning_rates[k]})
    lr = LEARNING_RATES
    return groups + [{"params": [u.alpha], "lr": lr["alpha"]},
                     {"params": [u.betas[i] for i in active], "lr": lr["beta"]},
                     {"params": [u.rots[i] for i in active], "lr": lr["rot"]},
                     {"params": [u.transes[i] for i in active], "lr": lr["trans"]}]


def _trace_point(step: int, u: Unknowns, t0: float) -> dict:
    return {"step": step, "seconds": round(time.perf_counter() - t0, 4),
            "alpha": u.alpha.detach().double().tolist(),
            "beta": [b.detach().double().tolist() for b in u.betas]}


def map_back(problems: list, unknowns: Unknowns, renderer, rendered, active=None, masks=None):
    """The refined frames back in their original images -> (FitResult, list of Refinement):
    the fit with the shared identity in the refined frames' ``frame_identity`` (and as its
    ``identity`` when every frame was refined), each fitted frame's expression and pose (the
    translation offset in the image camera) and landmark RMSE; ``rendered`` the frames' final
    renders (R, R, 3); ``active`` (n,) bool, the frames fitted (others keep their landmark fit's
    expression and pose); ``masks`` the frames' (R, R) photometric masks (default: the face
    coverage)."""
    import torch

    fit, u = problems[0].fit, unknowns
    active = np.ones(len(problems), dtype=bool) if active is None else np.asarray(active)
    a = u.alpha.detach().double().numpy()
    frame_identity = np.array(fit.frame_identity, dtype=np.float64)
    expression = np.array(fit.expression, dtype=np.float64)
    cams = list(fit.cameras)
    rmse = np.array(fit.landmark_rmse_px, dtype=np.float64)
    crop_cams = []
    for i, p in enumerate(problems):
        f = p.frame
        frame_identity[f] = a
        with torch.no_grad():
            Rt = u.rotation(i).double().numpy() if active[i] else p.camera.rotation
            tt = u.translation(i).double().numpy() if active[i] else p.camera.translation
        if active[i]:
            expression[f] = u.betas[i].detach().double().numpy()
            cams[f] = dataclasses.replace(fit.cameras[f], rotation=Rt, translation=tt)
        pts = fit.model.vertices_at(p.landmark_ids.numpy(), a, expression[f])
        uv = project_points(p.camera, torch.as_tensor(pts), torch.as_tensor(Rt),
                            torch.as_tensor(tt)).numpy()
        rmse[f] = float(np.sqrt(np.mean(np.linalg.norm(p.to_image(uv) - p.observed, axis=1) ** 2)))
        crop_cams.append(dataclasses.replace(p.camera, rotation=Rt, translation=tt))
    every = len({p.frame for p in problems}) == fit.n_frames
    identity = a if every else fit.identity
    new_fit = dataclasses.replace(fit, identity=identity, frame_identity=frame_identity,
                                  expression=expression, cameras=cams, landmark_rmse_px=rmse)
    states = []
    for i, p in enumerate(problems):
        app = {k: (v.detach() if torch.is_tensor(v) else [e.detach() for e in v])
               for k, v in u.appearances[i].items()}
        states.append(Refinement(renderer, app, p.crop, crop_cams[i], p.target, rendered[i],
                                 new_fit, frame=p.frame,
                                 mask=p.coverage[0, 0].numpy() if masks is None else masks[i],
                                 coverage=p.coverage[0, 0].numpy()))
    return new_fit, states


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
