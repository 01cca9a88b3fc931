"""What a video's track writes (:func:`morphable.tracking.track_video`): ``track.npz``,
``track.json`` and, on request, ``overlay.mp4`` and ``track.glb``, all or nothing."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["write_track", "check_track_folder", "NPZ_KEYS"]

NPZ_KEYS = ("time_s", "tracked", "detected", "euler_deg", "translation", "scale", "expression",
            "landmarks_68_px", "detector_px", "detector_std_px", "raw_euler_deg", "raw_expression",
            "landmark_rmse_px", "identity")
"""The arrays of ``track.npz`` (units: :class:`morphable.tracking.TrackResult`)."""


def check_track_folder(folder) -> Path:
    """``folder`` as a Path, or an InputError when it cannot hold a track's files: a file, or
    in a folder that does not exist (call it before tracking)."""
    out = Path(folder)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if not out.exists() and not out.resolve().parent.is_dir():
        raise InputError(f"{out}: folder {out.resolve().parent} does not exist")
    return out


def write_track(track, folder, *, video, settings: dict | None = None, seconds: float | None = None,
                overlay_video: bool = False, animated_mesh: bool = False) -> list:
    """Write a track's files into ``folder`` (made if missing; its parent must exist), all or
    nothing: nothing is written unless the face was tracked in some frame, and when one file
    fails those already written are removed.

    Parameters
    ----------
    track : :class:`~morphable.tracking.TrackResult`
    folder : path
    video : path, the tracked video (named in ``track.json``; decoded again for the overlay)
    settings : dict, JSON-ready, optional
        How the track was made, for ``track.json`` (e.g. ``smoothing_hz``,
        ``identity_frames``, ``identity_mode``).
    seconds : float, optional; the tracking's run time, for ``track.json``'s ``tracking_fps``
    overlay_video : bool, also ``overlay.mp4``: the fitted mesh (wireframe) over every frame
    animated_mesh : bool, also ``track.glb`` (:func:`morphable.tracking.write_track_glb`)

    Returns
    -------
    list of Path, the files written; ``track.json`` holds the video, model, frame counts,
    the frames lost, the frame rate, image size, identity, ``settings``, mean landmark RMSE
    (px) and tracking speed (frames/s).
    """
    from ..io.atomic import atomic_path
    from ..tracking import write_track_glb

    out = check_track_folder(folder)
    if not track.tracked.any():
        raise InputError(f"{video}: the face was lost in every frame")
    summary = {"video": str(video), "model": track.fit.model.name, "frames": track.n_frames,
               "frames_tracked": int(track.tracked.sum()),
               "frames_lost": [int(i) for i in np.flatnonzero(~track.tracked)],
               "frames_detected": int(track.detected.sum()), "fps": track.fps,
               "image_size": list(track.image_size), "identity": [float(x) for x in track.identity],
               **(settings or {}), "landmark_rmse_px": _mean(track.landmark_rmse_px)}
    if seconds is not None:
        summary["tracking_fps"] = track.n_frames / seconds
    out.mkdir(exist_ok=True)
    written = []
    try:
        # the glTF first: cheap, so that its problems come before the overlay's long write
        if animated_mesh:
            written.append(write_track_glb(track, out / "track.glb"))
        if overlay_video:
            written.append(_overlay_video(video, track, out / "overlay.mp4"))
        with atomic_path(out / "track.npz") as tmp:
            np.savez_compressed(tmp, **{k: np.asarray(getattr(track, k)) for k in NPZ_KEYS},
                                fps=track.fps, image_size=np.array(track.image_size))
        written.append(out / "track.npz")
        with atomic_path(out / "track.json") as tmp:
            Path(tmp).write_text(json.dumps(summary, indent=2))
        written.append(out / "track.json")
    except BaseException:
        # all or nothing: a track without its arrays (or arrays without the asked-for files)
        # would pass for a finished one
        for p in written:
            Path(p).unlink(missing_ok=True)
        raise
    return written


def _mean(values) -> float | None:
    v = np.asarray(values, dtype=np.float64)
    return float(np.nanmean(v)) if np.isfinite(v).any() else None


def _overlay_video(video, track, path) -> Path:
    """The fitted mesh (wireframe) over every frame, lost frames as they are, streamed."""
    from ..overlay import draw_overlay
    from ..video import iter_frames, write_video

    index = {int(f): i for i, f in enumerate(np.flatnonzero(track.tracked))}

    def frames():
        for frame in iter_frames(video):
            i = index.get(frame.index)
            if i is None:
                yield frame.image
            else:
                yield draw_overlay(frame.image, track.fit, i, mesh="wireframe", landmarks=False)

    return write_video(path, frames(), fps=track.fps or 30.0)
