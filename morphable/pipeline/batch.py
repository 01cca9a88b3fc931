"""The work function of ``morphable fit-batch`` (:func:`morphable.batch.run_batch`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["fit_item"]


def fit_item(item, folder, options: dict) -> dict:
    """Fit one :class:`~morphable.batch.BatchItem` (all its images together,
    :func:`~morphable.pipeline.fit.fit_images`) and write ``fit.obj`` and ``fit.json`` into
    ``folder``.

    ``options``: ``model``, ``camera``, ``focal_px``, ``n_iterations``, ``robust``, ``independent``,
    ``landmark_detector``, ``face_detector``, ``landmark_std_px``, ``mesh_format`` (suffix,
    default ``obj``).

    Returns a summary for the results log: n_frames, landmark RMSE (px, per frame and mean),
    yaw/pitch/roll of each frame (degrees) and the fit's runtime.
    """
    from .fit import fit_images

    folder = Path(folder)
    result = fit_images(item.images, item.landmarks or None,
                        model=options.get("model", "sfm"), camera=options.get("camera", "affine"),
                        focal_px=options.get("focal_px"), n_iterations=options.get("n_iterations", 4),
                        robust=options.get("robust"),
                        shared_identity=not options.get("independent", False),
                        landmark_detector=options.get("landmark_detector", "auto"),
                        face_detector=options.get("face_detector", "auto"),
                        landmark_std_px=options.get("landmark_std_px", 1.0))
    suffix = options.get("mesh_format", "obj").lstrip(".")
    result.write(mesh=folder / f"fit.{suffix}", report=folder / "fit.json")
    res = result.fit
    rmse = [round(float(x), 4) for x in res.landmark_rmse_px]
    return {"n_frames": res.n_frames, "landmark_rmse_px": round(float(np.mean(rmse)), 4),
            "frame_rmse_px": rmse,
            "pose_deg": [[round(float(a), 3) for a in e] for e in res.euler_deg],
            "fit_ms": round(float(res.runtime_ms), 2)}
