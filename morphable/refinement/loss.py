"""The refinement's loss: its weights, the perceptual features and the loss closure."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from .geometry import project_points

__all__ = ["DEFAULT_WEIGHTS", "NO_PHOTOMETRIC", "LANDMARK_UNIT_PX", "landmark_trust", "loss_weights", "parse_loss_weights",
           "perceptual_features", "loss_function"]

DEFAULT_WEIGHTS = {"photo": 1.0, "feat": 0.05, "eps": 1e-3, "lmk": 1.0, "alpha": 1e-3,
                   "beta": 1e-4}
"""Loss weights of :func:`morphable.refinement.refine`; landmark residuals are in pixels of
the renderer resolution, photometric ones in [0, 1] intensity; ``eps`` weighs the gar
renderer's appearance prior (its noise maps). ``lmk`` is the weight of annotated
landmarks; a frame the landmark fit gave a larger model error (detected landmarks,
``DETECTED_MODEL_STD_MM``) has it scaled down by its landmark variance
(:func:`landmark_trust`). ``lmk`` and ``alpha`` were chosen on 4 validation faces
(``evaluation.gar_ablation.held_out_faces(4, seed=777)``, not the ablation's): mean vertex
error after 100 steps, landmark fit alone 3.38 mm; gar / classical with lmk 0.01 and
alpha 1e-4 (before) 5.27 / 3.08 mm, lmk 0.1: 4.40 / 2.68, lmk 1: 3.10 / 2.96, lmk 1 and alpha
1e-3: 2.99 / 2.88 mm (chosen). Moving only the appearance for the first 50 steps changed
little (3.01 / 2.93 mm) and was not kept. For detected landmarks and the real-photo GAR a
sweep on the photo-dressed validation sets chose ``lmk`` 10 (``--loss-weight lmk=10`` on the
command lines, :func:`parse_loss_weights`); it is an option, not the default, because on james,
AFLW2000-3D and the London set it did worse than 1 (docs/neural.md, "Loss weights for detected
landmarks")."""

LANDMARK_UNIT_PX = 64
"""Landmark residuals count in pixels of a crop this wide (the resolution the weights were
chosen at), so that ``lmk`` means the same at every crop resolution."""

NO_PHOTOMETRIC = {"photo": 0.0, "feat": 0.0}
"""Weight overrides that turn the photometric terms off: a refinement by the landmark and prior
terms alone, in the crop camera (the ablations' baseline for what the photometric terms add)."""


def landmark_trust(fit, frame: int = 0) -> float:
    """How much the landmark fit trusted frame ``frame``'s landmarks relative to annotated ones:
    ``(s^2 + (k m_0)^2) / (s^2 + (k m)^2)`` with ``s`` its landmark noise (px), ``m`` its model
    error (mm; ``m_0`` = ``MODEL_STD_MM``, annotations) and ``k`` the image scale at the face
    (px/mm). 1 for annotated landmarks, about 0.02 for detected ones (10 mm) at 3 px/mm; 1 when
    the fit does not record them. A detector's errors are face-shaped and shared by a video's
    frames: the refinement must not pull the face onto them harder than the fit did."""
    from ..fitting.noise import MODEL_STD_MM

    m = np.asarray(fit.model_std_mm, dtype=np.float64)
    if not len(m):
        return 1.0
    s2 = float(fit.landmark_std_px[frame]) ** 2 if len(fit.landmark_std_px) else 1.0
    ids = np.asarray(fit.landmark_vertices[frame])
    pts = fit.model.vertices_at(ids[ids >= 0], fit.frame_identity[frame], fit.expression[frame])
    k = float(fit.cameras[frame].px_per_mm(pts.mean(0)))
    return float((s2 + (k * MODEL_STD_MM) ** 2) / (s2 + (k * m[frame]) ** 2))


def loss_weights(fit, frame: int, weights: dict | None = None, renderer=None) -> dict:
    """:data:`DEFAULT_WEIGHTS` with the renderer's ``default_weights``, then the overrides
    ``weights``, ``lmk`` scaled by :func:`landmark_trust`."""
    lam = {**DEFAULT_WEIGHTS, **getattr(renderer, "default_weights", {}), **(weights or {})}
    return {**lam, "lmk": lam["lmk"] * landmark_trust(fit, frame)}


def parse_loss_weights(items, option: str = "--loss-weight") -> dict:
    """Overrides of :data:`DEFAULT_WEIGHTS` from ``KEY=VALUE`` strings (a command line's
    ``option``) -> {key: float}; a one-line InputError naming ``option`` for an unknown key, a
    value that is not a finite number >= 0, or a key given twice.

    >>> parse_loss_weights(["photo=4", "feat=0.2"])
    {'photo': 4.0, 'feat': 0.2}
    """
    out = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        if not sep or key not in DEFAULT_WEIGHTS:
            raise InputError(f"{option} {item!r}: expected KEY=VALUE with KEY one of "
                             f"{', '.join(DEFAULT_WEIGHTS)}")
        if key in out:
            raise InputError(f"{option} {item!r}: {key} given twice")
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = float("nan")
        if not np.isfinite(out[key]) or out[key] < 0:
            raise InputError(f"{option} {item!r}: the weight must be a finite number >= 0")
    return out


def perceptual_features(features, renderer):
    """-> (callable image (B, 3, H, W) in [0, 1] -> list of feature maps, or None; its name).

    ``features``: None (the renderer's ``feature_network``, else the first an installed
    renderer plugin offers, else none), a callable, or the path of a TorchScript network."""
    if features is None:
        from ..renderer_plugins import plugin_feature_network

        return renderer.feature_network() or plugin_feature_network() or (None, "none")
    if callable(features):
        return features, "user feature network"
    import torch

    path = Path(features)
    if not path.is_file():
        raise InputError(f"{path}: feature network not found")
    try:
        net = torch.jit.load(str(path), map_location="cpu").eval()
    except (RuntimeError, ValueError) as e:
        raise InputError(f"{path}: not a TorchScript feature network ({e})") from None
    return (lambda img: list(net(img))), f"TorchScript {path.name}"


def loss_function(problem, unknowns, frame: int, renderer, weights: dict, features=None):
    """The loss of frame ``frame`` of ``unknowns`` on its ``problem`` -> callable ``(mask,
    full=False) -> (total, terms, image, normals)``: the weighted total, each term (scalar
    tensors; names as in ``weights``; the identity prior ``alpha`` is the caller's, once for
    all frames), the render and the normals. ``mask`` (1, 1, R, R) weighs the photometric
    term's pixels; landmark residuals count in pixels of a :data:`LANDMARK_UNIT_PX` crop,
    whatever the resolution. ``features``: a feature network of :func:`perceptual_features`
    or None. ``problem`` is a callable giving the frame's current problem (it is re-cast).

    A ``pixelwise`` renderer without perceptual features, on a crop of one sample per pixel,
    is compared on the surface points the face pixels saw at the last cast, as a (1, 3, 1, N)
    strip with their (N, 3) normals (per-pixel appearance maps (1, C, R, R) gathered alike):
    each point is projected with the current shape and pose and the crop sampled there
    (bilinear), so that the photometric term pulls the points' positions by the image's
    gradients as well as their normals by the shading, at a third of a full render's cost.
    With ``full=True``, or otherwise, the whole crop: (1, 3, R, R) and (R, R, 3), each pixel
    against the surface point it saw at the last cast."""
    import torch
    import torch.nn.functional as F

    from ..raster import interpolate

    from ..raster import normal_map
    from ..raster.normal_maps import sample_normals

    model, u, i = problem().fit.model, unknowns, frame
    target_feats = [f.detach() for f in features(problem().image)] if features else []

    def strip(a, idx, R):
        if torch.is_tensor(a) and a.dim() == 4 and a.shape[2:] == (R, R):
            return a.reshape(*a.shape[:2], 1, R * R)[..., idx]
        return a

    def losses(mask, full: bool = False):
        p = problem()
        R = p.resolution
        verts = model.vertices(u.alpha, u.betas[i])
        Rt = u.rotation(i)
        pixelwise = (getattr(renderer, "pixelwise", False) and not features and not full
                     and p.vis.supersample == 1)
        region = mask * renderer.photometric_mask(p.coverage)
        if pixelwise:
            idx = torch.as_tensor(p.vis.pixels)
            n = sample_normals(verts, model.triangles, p.vis, rotation=Rt, foreground=True)
            app = {k: strip(v, idx, R) for k, v in u.appearances[i].items()}
            img = renderer.render(n.T[None, :, None, :], app)
            xy = project_points(p.camera, interpolate(p.vis, verts, foreground=True), Rt,
                                u.translation(i))
            grid = ((xy + 0.5) * (2.0 / R) - 1.0).to(p.image.dtype)[None, None]
            target = F.grid_sample(p.image, grid, mode="bilinear", padding_mode="border",
                                   align_corners=False)
            m = strip(region, idx, R)
        else:
            n = normal_map(verts, model.triangles, vis=p.vis, rotation=Rt)      # (R, R, 3)
            img = renderer.render(n.permute(2, 0, 1)[None], u.appearances[i])
            target, m = p.image, region
        photo = ((img - target).pow(2) * m).sum() / (3 * m.sum()).clamp_min(1e-6)
        terms = {"photo": photo}
        if features:
            terms["feat"] = sum((a - b).pow(2).mean() for a, b in zip(features(img), target_feats))
        terms.update(renderer.appearance_prior(u.appearances[i]))
        uv = project_points(p.camera, verts[p.landmark_ids], Rt, u.translation(i))
        unit = LANDMARK_UNIT_PX / p.resolution
        terms["lmk"] = ((uv - p.landmarks) * unit).pow(2).sum(1).mean()
        terms["beta"] = u.betas[i].pow(2).sum()
        total = sum(weights[k] * v for k, v in terms.items())
        return total, terms, img, n

    return losses
