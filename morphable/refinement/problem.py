"""One frame's inversion problem: what is compared (the crop, its landmarks, the fitted
face's visibility, re-cast as the face moves) and what moves (the shared identity, each frame's
expression, pose and appearance), with their start."""
from __future__ import annotations

import dataclasses

import numpy as np

from ..camera import Camera
from ..errors import FitError
from .crop import crop_camera, crop_image, face_crop
from .geometry import face_visibility, rodrigues, surface_uv

__all__ = ["Problem", "Unknowns", "set_up", "recast", "start"]


@dataclasses.dataclass
class Problem:
    """Frame ``frame`` of ``fit`` seen in the renderer's ``resolution`` x ``resolution`` crop.

    crop : (left, top, side) px of the image; camera : the fit's camera in the crop;
    target : (R, R, 3) float [0, 1] the image crop and ``image`` the same (1, 3, R, R) torch;
    vis : visibility of the fitted face in the crop and ``coverage`` (1, 1, R, R) torch;
    uv : (R, R, 2) the UV each pixel sees (:func:`~.geometry.surface_uv`; None for a model
    without UVs); used : (68,) bool, the landmarks compared (a model vertex and a finite position);
    landmark_ids : (n,) torch int, their vertices; landmarks : (n, 2) torch, their positions
    in crop pixels and ``observed`` (n, 2) in image pixels.
    """

    fit: object
    frame: int
    crop: tuple
    camera: Camera
    target: np.ndarray
    image: object
    vis: object
    coverage: object
    uv: object
    used: np.ndarray
    landmark_ids: object
    landmarks: object
    observed: np.ndarray

    @property
    def resolution(self) -> int:
        return self.target.shape[0]

    def to_image(self, uv) -> np.ndarray:
        """(n, 2) crop pixels -> image pixels."""
        return (uv + 0.5) / (self.resolution / self.crop[2]) - 0.5 + np.array(self.crop[:2])


def set_up(image, fit, frame: int, resolution: int) -> Problem:
    """Crop ``image`` around frame ``frame``'s landmarks and cast the fitted face in it."""
    import torch

    lm_in = np.asarray(fit.landmarks[frame], dtype=np.float64)
    # the FFHQ framing needs iBUG-68's eyes and mouth: the given points where they are the 68
    # (the fitted ones where missing), else the fitted face's (a face mesh's 478 points have
    # other indices)
    if len(lm_in) == 68:
        crop = face_crop(np.where(np.isfinite(lm_in), lm_in, fit.fitted_landmarks[frame]))
    else:
        crop = face_crop(fit.landmarks_68_px()[frame])
    cam = crop_camera(fit.cameras[frame], crop, resolution)
    target = crop_image(image, crop, resolution)
    verts = fit.model.vertices(np.asarray(fit.frame_identity[frame], dtype=np.float64),
                               np.asarray(fit.expression[frame], dtype=np.float64))
    vis, cover, uv = _cast(fit.model, verts, cam)
    ids = np.asarray(fit.landmark_vertices[frame])
    used = (ids >= 0) & np.isfinite(lm_in).all(1)
    scale = resolution / crop[2]
    in_crop = (lm_in[used] + 0.5 - np.array(crop[:2])) * scale - 0.5
    return Problem(fit, frame, crop, cam, target, torch.as_tensor(target).permute(2, 0, 1)[None],
                   vis, cover, uv, used, torch.as_tensor(ids[used]),
                   torch.as_tensor(in_crop, dtype=torch.float32), lm_in[used])


def _cast(model, vertices, camera):
    """Visibility, (1, 1, R, R) torch coverage and UV map of the face ``vertices`` in
    ``camera``; a FitError when it covers no pixel."""
    import torch

    vis = face_visibility(model, vertices, camera)
    cover = torch.as_tensor(vis.coverage(), dtype=torch.float32)[None, None]
    if float(cover.sum()) < 4:
        raise FitError("refine: the fitted face covers no pixels of the crop")
    return vis, cover, surface_uv(model, vis)


def recast(problem: Problem, vertices, rotation, translation) -> Problem:
    """``problem`` with the visibility re-cast for the face ``vertices`` (V, 3) mm seen with
    camera ``rotation`` (3, 3) and ``translation`` (3,) mm (numpy): which pixels the face
    covers and which surface point each sees follow the moved shape and pose."""
    cam = dataclasses.replace(problem.camera, rotation=np.asarray(rotation, dtype=np.float64),
                              translation=np.asarray(translation, dtype=np.float64))
    vis, cover, uv = _cast(problem.fit.model, vertices, cam)
    return dataclasses.replace(problem, vis=vis, coverage=cover, uv=uv)


@dataclasses.dataclass
class Unknowns:
    """What the refinement moves, as torch leaves: the identity ``alpha`` (K,) shared by the
    frames; per frame the expression ``betas[i]`` (E,), a rotation increment ``rots[i]`` (3,)
    axis-angle (rad) before the crop camera's ``rotation0s[i]`` and a translation offset
    ``transes[i]`` (3,) mm after its ``translation0s[i]``; ``appearances[i]`` the renderer's
    dict and ``appearance_init`` how the renderer chose its start."""

    alpha: object
    betas: list
    rots: list
    transes: list
    rotation0s: list
    translation0s: list
    appearances: list
    appearance_init: str | None

    def rotation(self, i: int = 0):
        """(3, 3) torch, frame ``i``'s refined camera rotation."""
        return rodrigues(self.rots[i]) @ self.rotation0s[i]

    def translation(self, i: int = 0):
        """(3,) torch mm, frame ``i``'s refined camera translation."""
        return self.translation0s[i] + self.transes[i]


def start(problems: list, renderer, seed: int = 0) -> Unknowns:
    """The fit's geometry (the identity: the mean of the frames') and the renderer's
    ``initial_appearance`` for each crop."""
    import torch

    fit = problems[0].fit
    alpha = np.mean([fit.frame_identity[p.frame] for p in problems], 0)
    starts = [renderer.initial_appearance(p.image, p.coverage, seed=seed) for p in problems]

    def leaf(a):
        return torch.tensor(np.asarray(a, dtype=np.float64), dtype=torch.float32, requires_grad=True)
    return Unknowns(
        alpha=leaf(alpha),
        betas=[leaf(fit.expression[p.frame]) for p in problems],
        rots=[torch.zeros(3, requires_grad=True) for _ in problems],
        transes=[torch.zeros(3, requires_grad=True) for _ in problems],
        rotation0s=[torch.as_tensor(p.camera.rotation, dtype=torch.float32) for p in problems],
        translation0s=[torch.as_tensor(p.camera.translation, dtype=torch.float32) for p in problems],
        appearances=[a for a, _ in starts], appearance_init=starts[0][1])
