"""Peer methods run through their own libraries, for comparisons in the same process.

Currently eos (eos-py): landmark fitting of the Surrey Face Model with its jaw-contour
handling, one image at a time.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from morphable.errors import FitError, InputError

__all__ = ["EosFitter", "eos_projection"]


class EosFitter:
    """eos-py's ``fit_shape_and_pose`` with the SFM and its expression blendshapes.

    Parameters
    ----------
    folder : the SFM folder (``sfm_shape_3448.bin``, ``expression_blendshapes_3448.bin``,
        ``ibug_to_sfm.txt``, ``sfm_model_contours.json``, ``sfm_3448_edge_topology.json``);
        default: where ``morphable.load_model("sfm")`` finds it.
    num_iterations : eos's alternations of pose, contour, shape and expression
    lambda_identity : eos's shape regulariser

    Examples
    --------
    >>> from morphable import load_model
    >>> from morphable.camera import Camera
    >>> from morphable.fitting import simulate_landmarks
    >>> sfm = load_model("sfm")
    >>> landmarks = np.stack([simulate_landmarks(sfm, Camera.looking_at_face((512, 512), yaw=yaw))
    ...                       for yaw in (-20, 0, 20)])
    >>> EosFitter().fit(landmarks, (512, 512)).shape    # (N, 68, 2) px in -> (N, 3448, 3) mm
    (3, 3448, 3)
    """

    def __init__(self, folder=None, num_iterations: int = 5, lambda_identity: float = 30.0):
        try:
            import eos
        except ImportError as e:
            raise InputError(f"the eos method needs eos-py (pip install eos-py): {e}") from None
        if folder is None:
            from morphable.io.registry import find_model

            folder = find_model("sfm")
        folder = Path(folder)
        if folder.is_file():
            folder = folder.parent
        self.eos = eos
        self.num_iterations = int(num_iterations)
        self.lambda_identity = float(lambda_identity)
        self.model, self.mapper, self.edges, self.contour_lm, self.contour = _load(str(folder))

    def fit_one(self, landmarks, image_size) -> np.ndarray:
        """(68, 2) px (NaN = missing) -> (V, 3) mm vertices in the model frame."""
        return self.fit_with_pose(landmarks, image_size)[0]

    def fit_with_pose(self, landmarks, image_size):
        """(68, 2) px (NaN = missing) -> (V, 3) mm vertices in the model frame and eos'
        ``RenderingParameters`` (its camera: :func:`eos_projection`)."""
        v, pose, _ = self.fit_with_identity(landmarks, image_size)
        return v, pose

    def fit_with_identity(self, landmarks, image_size):
        """Like :meth:`fit_with_pose`, and the fitted identity without expression, (V, 3) mm."""
        eos = self.eos
        lm = np.asarray(landmarks, dtype=np.float64)
        pts = [eos.core.Landmark(str(i + 1), [float(x), float(y)])
               for i, (x, y) in enumerate(lm) if np.isfinite(x) and np.isfinite(y)]
        if len(pts) < 6:
            raise FitError(f"eos needs at least 6 landmarks, got {len(pts)}")
        W, H = (int(s) for s in image_size)
        mesh, pose, shape, _expr = eos.fitting.fit_shape_and_pose(
            self.model, pts, self.mapper, W, H, self.edges, self.contour_lm, self.contour,
            num_iterations=self.num_iterations, lambda_identity=self.lambda_identity)
        v = np.asarray(mesh.vertices, dtype=np.float64)
        neutral = np.asarray(self.model.get_shape_model().draw_sample(shape),
                             dtype=np.float64).reshape(-1, 3)
        if not (np.isfinite(v).all() and np.isfinite(neutral).all()):
            raise FitError("eos returned non-finite vertices")
        return v, pose, neutral

    def fit(self, landmarks, image_size) -> np.ndarray:
        """(N, 68, 2) px -> (N, V, 3) mm, one independent fit per image."""
        lm = np.asarray(landmarks, dtype=np.float64)
        if lm.ndim != 3 or lm.shape[1:] != (68, 2):
            raise InputError(f"eos: expected (N, 68, 2) landmarks, got {lm.shape}")
        return np.stack([self.fit_one(x, image_size) for x in lm])


@functools.lru_cache(maxsize=2)
def _load(folder: str):
    import eos

    f = Path(folder)
    need = ["sfm_shape_3448.bin", "expression_blendshapes_3448.bin", "ibug_to_sfm.txt",
            "sfm_model_contours.json", "sfm_3448_edge_topology.json"]
    missing = [n for n in need if not (f / n).is_file()]
    if missing:
        raise InputError(f"{f}: the eos method needs {', '.join(missing)}")
    shape_only = eos.morphablemodel.load_model(str(f / need[0]))
    blendshapes = eos.morphablemodel.load_blendshapes(str(f / need[1]))
    model = eos.morphablemodel.MorphableModel(
        shape_only.get_shape_model(), blendshapes, color_model=eos.morphablemodel.PcaModel(),
        vertex_definitions=None, texture_coordinates=shape_only.get_texture_coordinates())
    mapper = eos.core.LandmarkMapper(str(f / need[2]))
    edges = eos.morphablemodel.load_edge_topology(str(f / need[4]))
    contour_lm = eos.fitting.ContourLandmarks.load(str(f / need[2]))
    contour = eos.fitting.ModelContour.load(str(f / need[3]))
    return model, mapper, edges, contour_lm, contour


def eos_projection(pose, image_size):
    """eos' camera of a fit: its rotation (3, 3) and a function world points (n, 3) mm ->
    pixels (n, 2) through its modelview, orthographic projection and (flipped) viewport."""
    W, H = image_size
    MV = np.asarray(pose.get_modelview(), dtype=np.float64)
    P = np.asarray(pose.get_projection(), dtype=np.float64)

    def project(X):
        Xh = np.c_[X, np.ones(len(X))] @ (P @ MV).T
        return np.c_[(Xh[:, 0] + 1) / 2 * W, H - (Xh[:, 1] + 1) / 2 * H]
    return MV[:3, :3], project
