"""One frame's inversion problem: what is compared (the crop, its landmarks, the fitted
face's visibility) and what moves (geometry and appearance tensors), with their start."""
from __future__ import annotations

import dataclasses

import numpy as np

from ..camera import Camera
from ..errors import FitError
from .crop import crop_camera, crop_image, face_crop
from .geometry import face_visibility, rodrigues

__all__ = ["Problem", "Unknowns", "set_up", "start"]


@dataclasses.dataclass
class Problem:
    """Frame ``frame`` of ``fit`` seen in the renderer's ``resolution`` x ``resolution`` crop.

    crop : (left, top, side) px of the image; camera : the fit's camera in the crop;
    target : (R, R, 3) float [0, 1] the image crop and ``image`` the same (1, 3, R, R) torch;
    vis : visibility of the fitted face in the crop and ``coverage`` (1, 1, R, R) torch;
    used : (68,) bool, the landmarks compared (a model vertex and a finite position);
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
    vis = face_visibility(fit.model, verts, cam)
    cover = torch.as_tensor(vis.coverage(), dtype=torch.float32)[None, None]
    if float(cover.sum()) < 4:
        raise FitError("refine: the fitted face covers no pixels of the crop")
    ids = np.asarray(fit.landmark_vertices[frame])
    used = (ids >= 0) & np.isfinite(lm_in).all(1)
    scale = resolution / crop[2]
    in_crop = (lm_in[used] + 0.5 - np.array(crop[:2])) * scale - 0.5
    return Problem(fit, frame, crop, cam, target, torch.as_tensor(target).permute(2, 0, 1)[None],
                   vis, cover, used, torch.as_tensor(ids[used]),
                   torch.as_tensor(in_crop, dtype=torch.float32), lm_in[used])


@dataclasses.dataclass
class Unknowns:
    """What the refinement moves, as torch leaves: ``alpha`` (K,), ``beta`` (E,), a rotation
    increment ``rot`` (3,) axis-angle (rad) before the crop camera's ``rotation0`` and a
    translation offset ``trans`` (3,) mm after its ``translation0``; ``appearance`` the
    renderer's dict and ``appearance_init`` how the renderer chose its start."""

    alpha: object
    beta: object
    rot: object
    trans: object
    rotation0: object
    translation0: object
    appearance: dict
    appearance_init: str | None

    def rotation(self):
        """(3, 3) torch, the refined camera rotation."""
        return rodrigues(self.rot) @ self.rotation0

    def translation(self):
        """(3,) torch mm, the refined camera translation."""
        return self.translation0 + self.trans


def start(problem: Problem, renderer, seed: int = 0) -> Unknowns:
    """The fit's geometry and the renderer's ``initial_appearance`` for the crop."""
    import torch

    fit, frame = problem.fit, problem.frame
    appearance, init = renderer.initial_appearance(problem.image, problem.coverage, seed=seed)
    return Unknowns(
        alpha=torch.tensor(np.asarray(fit.frame_identity[frame], dtype=np.float64),
                           dtype=torch.float32, requires_grad=True),
        beta=torch.tensor(np.asarray(fit.expression[frame], dtype=np.float64),
                          dtype=torch.float32, requires_grad=True),
        rot=torch.zeros(3, requires_grad=True), trans=torch.zeros(3, requires_grad=True),
        rotation0=torch.as_tensor(problem.camera.rotation, dtype=torch.float32),
        translation0=torch.as_tensor(problem.camera.translation, dtype=torch.float32),
        appearance=appearance, appearance_init=init)
