"""Reconstruction by inverting a renderer (paper Sec. 3.3) and face editing.

Starting from a landmark fit (:func:`morphable.fitting.fit_landmarks`: identity alpha,
expression beta, camera pose theta), the steps, each usable alone:

1. :func:`face_crop` / :func:`crop_camera` / :func:`crop_image`: the FFHQ-style square around
   the fitted landmarks (the framing of :mod:`neural.data`), resized to the renderer's
   resolution, and the fit's camera re-expressed in that crop;
2. the visibility of the fitted mesh in the crop is cast once (open3d); the camera-frame
   normal map ``n~(alpha, beta, theta)`` is then differentiable in the coefficients and a
   pose increment (axis-angle) through :func:`morphable.raster.normal_map`;
3. appearance initialisation: for ``gar``, ``z <- V(crop)`` when an inverter is available
   (:mod:`neural.inverter`), ``eps <- 0``; for ``classical``, albedo = mean colour of the face
   pixels and a uniform white SH environment;
4. :func:`refine`: Adam over alpha, beta, theta (+ a translation offset) and the appearance on

   ``L_f = lambda_photo ||render(n~) - I||^2 + lambda_feat sum_i ||F_i(render) - F_i(I)||^2
   + lambda_eps ||eps||^2 + lambda_lmk ||proj(landmarks) - l||^2 + lambda_alpha ||alpha||^2
   + lambda_beta ||beta||^2``

   with the photometric terms on the whole crop for ``gar`` (G renders a background) and on
   the fitted face pixels for ``classical``. ``F_i`` are the encoder stages of the aux normal
   network N (:mod:`neural.auxnets`) unless a TorchScript feature network (e.g. VGG, returning
   a list of feature maps) is given — no VGG weights can be downloaded here;
5. :func:`edit`: the recovered face under another pose / expression, re-rendered with the
   recovered appearance.

Units: mm and degrees in the results; images (H, W, 3) float in [0, 1] (or uint8).
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import torch

from morphable.camera import Camera
from morphable.errors import FitError, InputError

__all__ = ["face_crop", "crop_camera", "crop_image", "landmark_trust", "refine", "refine_frames",
           "edit", "Refinement", "DEFAULT_WEIGHTS", "default_inverter_path"]

DEFAULT_WEIGHTS = {"photo": 1.0, "feat": 0.05, "eps": 1e-3, "lmk": 1.0, "alpha": 1e-3,
                   "beta": 1e-4}
"""Loss weights of :func:`refine`; landmark residuals are in pixels of the renderer
resolution, photometric ones in [0, 1] intensity. ``lmk`` is the weight of annotated
landmarks; a frame the landmark fit gave a larger model error (detected landmarks,
``DETECTED_MODEL_STD_MM``) has it scaled down by its landmark variance
(:func:`landmark_trust`). ``lmk`` and ``alpha`` were chosen on 4 validation faces
(``neural.ablate.held_out_faces(4, seed=777)``, not the ablation's): mean vertex error after
100 steps, landmark fit alone 3.38 mm; gar / classical with lmk 0.01 and
alpha 1e-4 (before) 5.27 / 3.08 mm, lmk 0.1: 4.40 / 2.68, lmk 1: 3.10 / 2.96, lmk 1 and alpha
1e-3: 2.99 / 2.88 mm (chosen). Moving only the appearance for the first 50 steps changed
little (3.01 / 2.93 mm) and was not kept."""

_LR = {"alpha": 0.03, "beta": 0.02, "rot": 0.003, "trans": 0.3, "z": 0.03, "noise": 0.03,
       "sh": 0.02, "albedo": 0.01}


def default_inverter_path() -> Path | None:
    """``neural/weights/inverter_tiny.pt`` if committed, else None (pass ``inverter=`` to
    use another file, e.g. ``runs/inv/inverter.pt`` of :mod:`neural.train_inverter`)."""
    p = Path(__file__).resolve().parent / "weights" / "inverter_tiny.pt"
    return p if p.is_file() else None


def _inverter(inverter):
    """The Inverter that ``inverter`` names ("auto", None, a path or an Inverter), or None."""
    if inverter == "auto":
        inverter = default_inverter_path()
    if inverter is None:
        return None
    from .inverter import Inverter, load_inverter

    return inverter if isinstance(inverter, Inverter) else load_inverter(inverter)


def _is_gar(renderer) -> bool:
    """A generative adversarial renderer (latent z, noise, an inverter V), not a classical one."""
    return hasattr(renderer, "generator")


def landmark_trust(fit, frame: int = 0) -> float:
    """How much the landmark fit trusted frame ``frame``'s landmarks relative to annotated ones:
    ``(s^2 + (k m_0)^2) / (s^2 + (k m)^2)`` with ``s`` its landmark noise (px), ``m`` its model
    error (mm; ``m_0`` = ``MODEL_STD_MM``, annotations) and ``k`` the image scale at the face
    (px/mm). 1 for annotated landmarks, about 0.02 for detected ones (10 mm) at 3 px/mm; 1 when
    the fit does not record them. A detector's errors are face-shaped and shared by a video's
    frames: the refinement must not pull the face onto them harder than the fit did."""
    from morphable.fitting.noise import MODEL_STD_MM

    m = np.asarray(fit.model_std_mm, dtype=np.float64)
    if not len(m):
        return 1.0
    s2 = float(fit.landmark_std_px[frame]) ** 2 if len(fit.landmark_std_px) else 1.0
    ids = np.asarray(fit.landmark_vertices[frame])
    pts = fit.model.vertices_at(ids[ids >= 0], fit.frame_identity[frame], fit.expression[frame])
    k = float(fit.cameras[frame].px_per_mm(pts.mean(0)))
    return float((s2 + (k * MODEL_STD_MM) ** 2) / (s2 + (k * m[frame]) ** 2))


def face_crop(landmarks) -> tuple[float, float, float]:
    """(68, 2) pixels -> square crop ``(left, top, side)`` in pixel-edge coordinates (the
    image spans [0, W] x [0, H]): 4 x the inter-ocular distance wide (at least 3.6 x the
    eye-mouth distance), centred 0.1 of the way from the eye midpoint to the mouth.

    >>> from neural.data import template
    >>> left, top, side = face_crop(template(64))
    >>> round(side, 1), round(left + side / 2, 1)    # the template fills its own crop
    (64.0, 32.0)
    """
    lm = np.asarray(landmarks, dtype=np.float64)
    eyes = np.nanmean(lm[36:42], 0), np.nanmean(lm[42:48], 0)
    mouth = np.nanmean(lm[48:68], 0)
    if not (np.isfinite(eyes).all() and np.isfinite(mouth).all()):
        raise InputError("face crop: eye and mouth landmarks are missing")
    mid = (eyes[0] + eyes[1]) / 2
    centre = mid + 0.1 * (mouth - mid) + 0.5                      # to pixel-edge coordinates
    side = 2.0 * max(2.0 * np.linalg.norm(eyes[1] - eyes[0]), 1.8 * np.linalg.norm(mouth - mid))
    if side < 4:
        raise InputError(f"face crop: the face is only {side:.1f} px wide")
    return float(centre[0] - side / 2), float(centre[1] - side / 2), float(side)


def crop_camera(camera: Camera, crop, resolution: int) -> Camera:
    """The camera that sees ``crop`` = (left, top, side) of ``camera``'s image as a
    ``resolution`` x ``resolution`` image (pixel centre u' = (u + 0.5 - left) k - 0.5)."""
    left, top, side = crop
    k = resolution / side
    principal = (camera.principal + 0.5 - np.array([left, top])) * k - 0.5
    return dataclasses.replace(camera, scale=camera.scale * k, focal=camera.focal * k,
                               image_size=(resolution, resolution), principal=principal)


def crop_image(image, crop, resolution: int) -> np.ndarray:
    """(H, W, 3) uint8 or float [0, 1] -> (resolution, resolution, 3) float [0, 1] of the
    crop (area-averaged; outside the image is black)."""
    from PIL import Image

    a = np.asarray(image)
    if a.dtype != np.uint8:
        a = np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)
    left, top, side = crop
    H, W = a.shape[:2]
    # pad where the crop leaves the image (PIL's box must lie inside it)
    pl, pt = max(0, int(np.ceil(-left))), max(0, int(np.ceil(-top)))
    pr = max(0, int(np.ceil(left + side - W)))
    pb = max(0, int(np.ceil(top + side - H)))
    if pl or pt or pr or pb:
        a = np.pad(a[..., :3], ((pt, pb), (pl, pr), (0, 0)))
    im = Image.fromarray(a[..., :3]).resize((resolution, resolution), Image.BOX,
                                            box=(left + pl, top + pt, left + pl + side,
                                                 top + pt + side))
    return np.asarray(im, dtype=np.float32) / 255.0


def _rodrigues(w):
    """(3,) axis-angle (rad) torch -> (3, 3), smooth at 0."""
    theta2 = (w * w).sum()
    K = torch.zeros(3, 3, dtype=w.dtype)
    K[0, 1], K[0, 2], K[1, 2] = -w[2], w[1], -w[0]
    K = K - K.T
    # series forms near 0 keep the gradient finite at w = 0
    theta = torch.sqrt(theta2 + 1e-12)
    a = torch.where(theta2 > 1e-8, torch.sin(theta) / theta, 1 - theta2 / 6)
    b = torch.where(theta2 > 1e-8, (1 - torch.cos(theta)) / (theta2 + 1e-12), 0.5 - theta2 / 24)
    return torch.eye(3, dtype=w.dtype) + a * K + b * K @ K


def _project(cam: Camera, X, R, t):
    """torch (N, 3) world mm -> (N, 2) pixels of ``cam`` with rotation R and translation t."""
    Xc = X @ R.T + t
    if cam.kind == "affine":
        k = cam.scale
    else:
        k = cam.focal / (-Xc[:, 2]).clamp_min(1e-3)
    c = torch.as_tensor(cam.principal, dtype=X.dtype)
    return torch.stack([c[0] + k * Xc[:, 0], c[1] - k * Xc[:, 1]], -1)


def _feature_net(features):
    """-> callable image (B, 3, H, W) in [0, 1] -> list of feature maps, and its name."""
    if features is None:
        from .auxnets import load_aux

        N = load_aux("N")
        return (lambda img: N.net.encoder(img * 2 - 1)), "aux N encoder (no VGG weights given)"
    if callable(features):
        return features, "user feature network"
    path = Path(features)
    if not path.is_file():
        raise InputError(f"{path}: feature network not found")
    try:
        net = torch.jit.load(str(path), map_location="cpu").eval()
    except (RuntimeError, ValueError) as e:
        raise InputError(f"{path}: not a TorchScript feature network ({e})") from None
    return (lambda img: list(net(img))), f"TorchScript {path.name}"


@dataclasses.dataclass
class Refinement:
    """Everything :func:`edit` needs to re-render the reconstruction.

    renderer : the renderer object; appearance : dict of its tensors (recovered);
    crop : (left, top, side) px; camera : crop camera (refined pose); target (R, R, 3) the
    image crop; rendered (R, R, 3) the final render; fit : refined FitResult.
    """

    renderer: object
    appearance: dict
    crop: tuple
    camera: Camera
    target: np.ndarray
    rendered: np.ndarray
    fit: object


def _render_geometry(model, alpha, beta, camera, renderer, appearance, supersample=2):
    """Cast visibility of the face (numpy coefficients) in ``camera`` and render it."""
    from morphable.raster import normal_map, visibility

    verts = model.vertices(alpha, beta)
    vis = visibility(verts, model.triangles, camera, supersample=supersample)
    n = torch.as_tensor(normal_map(verts, model.triangles, vis=vis), dtype=torch.float32)
    with torch.no_grad():
        img = renderer.render(n.permute(2, 0, 1)[None], appearance)
    return img[0].permute(1, 2, 0).numpy(), vis


def refine(image, fit, renderer="classical", *, steps: int = 100, frame: int = 0,
           weights: dict | None = None, inverter="auto", features=None, resolution: int = 64,
           renderer_options: dict | None = None, seed: int = 0, return_state: bool = False,
           trace_every: int = 0):
    """Refine a landmark fit by photometric inversion of a renderer.

    Parameters
    ----------
    image : (H, W, 3) uint8 or float [0, 1], the image of ``fit``'s frame ``frame``
    fit : FitResult of :func:`morphable.fitting.fit_landmarks`
    renderer : "classical", "gar", or a renderer object (see :mod:`morphable.renderers`)
    steps : Adam iterations
    weights : overrides of :data:`DEFAULT_WEIGHTS`
    inverter : "auto" (:func:`default_inverter_path`), None (no V), a path or an Inverter;
        gar only
    features : None (aux N features), a TorchScript path or a callable (perceptual term)
    resolution : crop size for renderers of any resolution (classical)
    renderer_options : keyword options of ``get_renderer``
    return_state : also return a :class:`Refinement`
    trace_every : when > 0, the report's ``trace`` lists ``{"step", "seconds", "alpha",
        "beta"}`` every ``trace_every`` steps and at the end (error against run time)

    Returns
    -------
    (FitResult, report) or (FitResult, report, Refinement). The report holds
    ``photometric_loss`` and ``loss`` per step, ``runtime_s``, the landmark RMSE (px)
    before/after, the feature network and the latent initialisation used.
    """
    from morphable.raster import normal_map
    from morphable.renderers import get_renderer

    t0 = time.perf_counter()
    lam = {**DEFAULT_WEIGHTS, **(weights or {})}
    if isinstance(renderer, str):
        name = renderer
        renderer = get_renderer(renderer, **(renderer_options or {}))
    else:
        name = type(renderer).__name__
    if int(steps) < 0:
        raise InputError(f"steps must be >= 0, got {steps}")
    is_gar = _is_gar(renderer)
    R = renderer.resolution or int(resolution)
    model = fit.model
    lm_in = np.asarray(fit.landmarks[frame], dtype=np.float64)
    crop = face_crop(np.where(np.isfinite(lm_in), lm_in, fit.fitted_landmarks[frame]))
    cam = crop_camera(fit.cameras[frame], crop, R)
    target = crop_image(image, crop, R)
    I = torch.as_tensor(target).permute(2, 0, 1)[None]

    alpha0 = np.asarray(fit.frame_identity[frame], dtype=np.float64)
    beta0 = np.asarray(fit.expression[frame], dtype=np.float64)
    _, vis = _render_geometry(model, alpha0, beta0, cam, renderer,
                              renderer.default_appearance(1))
    cover = torch.as_tensor(vis.coverage(), dtype=torch.float32)[None, None]
    if float(cover.sum()) < 4:
        raise FitError("refine: the fitted face covers no pixels of the crop")
    photo_mask = torch.ones_like(cover) if is_gar else cover

    # geometry in torch: only the coefficients the fit used
    K, E = len(alpha0), len(beta0)
    mean = torch.tensor(np.asarray(model.mean), dtype=torch.float32).reshape(-1)
    B_id = torch.tensor(np.asarray(model.identity_basis[:K]), dtype=torch.float32).reshape(K, -1)
    B_ex = torch.tensor(np.asarray(model.expression_basis[:E]), dtype=torch.float32).reshape(E, -1)
    alpha = torch.tensor(alpha0, dtype=torch.float32, requires_grad=True)
    beta = torch.tensor(beta0, dtype=torch.float32, requires_grad=True)
    rot = torch.zeros(3, requires_grad=True)
    trans = torch.zeros(3, requires_grad=True)
    R0 = torch.as_tensor(cam.rotation, dtype=torch.float32)
    t_0 = torch.as_tensor(cam.translation, dtype=torch.float32)
    lm_ids = np.asarray(fit.landmark_vertices[frame])
    use = (lm_ids >= 0) & np.isfinite(lm_in).all(1)
    scale = R / crop[2]
    lm_target = torch.as_tensor((lm_in[use] + 0.5 - np.array(crop[:2])) * scale - 0.5,
                                dtype=torch.float32)
    lm_ids = torch.as_tensor(lm_ids[use])

    # appearance
    app = {k: (v.detach().clone() if torch.is_tensor(v) else [e.clone() for e in v])
           for k, v in renderer.default_appearance(1).items()}
    init = "default"
    if is_gar:
        V = _inverter(inverter)
        if V is not None:
            init = f"inverter {V.source}" if getattr(V, "source", None) else "inverter"
            with torch.no_grad():
                app["z"] = V.latent(I * 2 - 1, generator=torch.Generator().manual_seed(seed))
        app["noise"] = [torch.zeros_like(e) for e in app["noise"]]
    else:
        face = cover[0, 0] > 0.5
        if face.any():
            app["albedo"] = I[0][:, face].mean(1)[None].clamp(0.02, 1)
        app["sh"] = torch.zeros(1, 9, 3)
        app["sh"][:, 0] = 1.0
    groups = []
    for k, v in app.items():
        ts = v if isinstance(v, list) else [v]
        for tsr in ts:
            tsr.requires_grad_(True)
        if k in _LR:
            groups.append({"params": ts, "lr": _LR[k]})
    groups += [{"params": [alpha], "lr": _LR["alpha"]}, {"params": [beta], "lr": _LR["beta"]},
               {"params": [rot], "lr": _LR["rot"]}, {"params": [trans], "lr": _LR["trans"]}]
    opt = torch.optim.Adam(groups)
    feat_fn, feat_name = _feature_net(features) if lam["feat"] > 0 else (None, "none")
    target_feats = [f.detach() for f in feat_fn(I)] if feat_fn else []
    blendshapes = model.expression_kind == "blendshapes"

    def losses():
        verts = (mean + alpha @ B_id + beta @ B_ex).reshape(-1, 3)
        Rt = _rodrigues(rot) @ R0
        n = normal_map(verts, model.triangles, vis=vis, rotation=Rt)          # (R, R, 3)
        img = renderer.render(n.permute(2, 0, 1)[None], app)
        photo = ((img - I).pow(2) * photo_mask).sum() / (3 * photo_mask.sum())
        terms = {"photo": photo}
        if feat_fn:
            terms["feat"] = sum((a - b).pow(2).mean() for a, b in zip(feat_fn(img), target_feats))
        if is_gar:
            terms["eps"] = sum(e.pow(2).sum() for e in app["noise"])
        uv = _project(cam, verts[lm_ids], Rt, t_0 + trans)
        terms["lmk"] = (uv - lm_target).pow(2).sum(1).mean()
        terms["alpha"] = alpha.pow(2).sum()
        terms["beta"] = beta.pow(2).sum()
        total = sum(w[k] * v for k, v in terms.items())
        return total, terms, img

    w = {**lam, "lmk": lam["lmk"] * landmark_trust(fit, frame)}
    history, photo_hist, trace = [], [], []

    def record(step):
        trace.append({"step": step, "seconds": round(time.perf_counter() - t0, 4),
                      "alpha": alpha.detach().double().tolist(),
                      "beta": beta.detach().double().tolist()})

    for step in range(int(steps)):
        if trace_every > 0 and step % trace_every == 0:
            record(step)
        total, terms, _ = losses()
        if not torch.isfinite(total):
            raise FitError("refine: the loss became NaN or inf; try fewer steps or smaller weights")
        opt.zero_grad(set_to_none=True)
        total.backward()
        opt.step()
        with torch.no_grad():
            if blendshapes:
                beta.clamp_(min=0)
            if "albedo" in app:
                app["albedo"].clamp_(0, 1)
        history.append(float(total.detach()))
        photo_hist.append(float(terms["photo"].detach()))
    with torch.no_grad():
        total, terms, img = losses()
        Rt = (_rodrigues(rot) @ R0).double().numpy()
        tt = (t_0 + trans).double().numpy()
        uv = _project(cam, torch.as_tensor(model.vertices_at(lm_ids.numpy(), alpha.double().numpy(),
                                                             beta.double().numpy())),
                      torch.as_tensor(Rt), torch.as_tensor(tt)).numpy()
    photo_hist.append(float(terms["photo"]))
    history.append(float(total))
    if trace_every > 0:
        record(int(steps))
    # back to the original image: same rotation, translation offset in the image camera
    img_cam = dataclasses.replace(fit.cameras[frame], rotation=Rt, translation=tt)
    lm_err = np.linalg.norm((uv + 0.5) / scale - 0.5 + np.array(crop[:2]) - lm_in[use], axis=1)
    a, b = alpha.detach().double().numpy(), beta.detach().double().numpy()
    frame_identity = np.array(fit.frame_identity, dtype=np.float64)
    frame_identity[frame] = a
    expression = np.array(fit.expression, dtype=np.float64)
    expression[frame] = b
    cams = list(fit.cameras)
    cams[frame] = img_cam
    rmse = np.array(fit.landmark_rmse_px, dtype=np.float64)
    before = float(rmse[frame])
    rmse[frame] = float(np.sqrt(np.mean(lm_err ** 2)))
    new_fit = dataclasses.replace(fit, identity=a if fit.n_frames == 1 else fit.identity,
                                  frame_identity=frame_identity, expression=expression,
                                  cameras=cams, landmark_rmse_px=rmse)
    report = {"renderer": name, "renderer_weights": getattr(renderer, "weights", None),
              "steps": int(steps), "resolution": R, "crop_px": [round(c, 2) for c in crop],
              "features": feat_name, "latent_init": init if is_gar else None,
              "loss_weights": w, "photometric_loss": photo_hist, "loss": history,
              "landmark_rmse_px_before": before, "landmark_rmse_px_after": float(rmse[frame]),
              "runtime_s": round(time.perf_counter() - t0, 3)}
    if trace_every > 0:
        report["trace"] = trace
    if not return_state:
        return new_fit, report
    rendered = img[0].permute(1, 2, 0).numpy()
    crop_cam = dataclasses.replace(cam, rotation=Rt, translation=tt)
    app = {k: (v.detach() if torch.is_tensor(v) else [e.detach() for e in v]) for k, v in app.items()}
    return new_fit, report, Refinement(renderer, app, crop, crop_cam, target, rendered, new_fit)


def refine_frames(model, images, landmarks, renderer="gar", *, steps: int = 100,
                  n_iterations: int = 4, fit_options: dict | None = None,
                  **options) -> tuple[np.ndarray, list]:
    """Reconstruct each frame of a video on its own: landmark fit, then :func:`refine`.

    Parameters
    ----------
    model : MorphableModel
    images : (N, H, W, 3) float [0, 1] or uint8, one image per frame
    landmarks : (N, 68, 2) px, NaN where missing
    renderer, steps, options : as :func:`refine` (the renderer is loaded once)
    n_iterations : of the landmark fit
    fit_options : further keyword arguments of the landmark fit
        (:func:`~morphable.fitting.fit_landmarks`, one independent fit per frame, all frames in
        one batch), e.g. ``camera="perspective"`` with ``focal_px`` when the video's camera is
        known, or per-frame values such as ``model_std_mm``

    Returns
    -------
    vertices (N, V, 3) mm in the model frame, and the N refinement reports.
    """
    from morphable.fitting import fit_landmarks
    from morphable.renderers import get_renderer

    if isinstance(renderer, str):
        renderer = get_renderer(renderer, **(options.pop("renderer_options", None) or {}))
    images = np.asarray(images)
    H, W = images.shape[1:3]
    fit = fit_landmarks(model, np.asarray(landmarks, dtype=np.float64), [W, H],
                        shared_identity=False, n_iterations=n_iterations, **(fit_options or {}))
    if _is_gar(renderer):      # V read from its file once, not per frame
        options["inverter"] = _inverter(options.get("inverter", "auto"))
    out, reports = [], []
    for i, image in enumerate(images):
        res, rep = refine(image, fit, renderer, steps=steps, frame=i, **options)
        out.append(res.vertices(i))
        reports.append(rep)
    return np.stack(out), reports


def edit(state: Refinement, *, yaw=None, pitch=None, roll=None, expression: dict | None = None,
         identity_scale: float = 1.0, frame: int = 0) -> np.ndarray:
    """Re-render a reconstruction under another pose and/or expression.

    Parameters
    ----------
    state : :class:`Refinement` from ``refine(..., return_state=True)``
    yaw, pitch, roll : degrees (absolute, in the crop camera); None keeps the recovered angle
    expression : {name: weight} replacing those expression coefficients (e.g.
        ``{"happiness": 0.8}`` for the SFM blendshapes); others keep their recovered value
    identity_scale : multiplies alpha (0: the mean face under the recovered appearance)

    Returns
    -------
    (R, R, 3) float image in [0, 1].
    """
    fit = state.fit
    model = fit.model
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
    img, _ = _render_geometry(model, alpha, beta, cam, state.renderer, state.appearance)
    return img
