"""What a video's track writes, all or nothing: ``track.npz``, ``track.json`` and, on request,
``overlay.mp4`` and animated meshes (``.glb``): :func:`write_track` for one face's
(:func:`morphable.tracking.track_video`), :func:`write_footage` for every person's
(:func:`morphable.tracking.track_footage`, ``morphable track``)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["write_track", "write_footage", "keep_person", "check_track_folder", "NPZ_KEYS"]

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


def keep_person(footage, person: int):
    """The :class:`~morphable.tracking.FootageResult` with one person kept (``--person K``,
    ``--largest``): their tracks, their result; InputError when there is no person ``person``."""
    import dataclasses

    n = len(footage.people)
    if not 0 <= int(person) < n:
        raise InputError(f"person {person}: the video has {n} {'person' if n == 1 else 'people'} "
                         f"(0 to {n - 1})")
    tracks = [dataclasses.replace(t, person=0) for t in footage.tracks if t.person == int(person)]
    return dataclasses.replace(footage, people=[footage.people[int(person)]], tracks=tracks)


def write_footage(footage, folder, *, video, settings: dict | None = None, seconds: float | None = None,
                  overlay_video: bool = False, animated_mesh: bool = False, person_ids=None) -> list:
    """Write every person's track (:func:`morphable.tracking.track_footage`) into ``folder``
    (made if missing; its parent must exist), all or nothing.

    Parameters
    ----------
    footage : :class:`~morphable.tracking.FootageResult`
    folder : path
    video : path, the tracked video (named in ``track.json``; decoded again for the overlay)
    settings : dict, JSON-ready, optional: how the track was made, for ``track.json``
    seconds : float, optional; the run time, for ``track.json``'s ``tracking_fps``
    overlay_video : bool, also ``overlay.mp4``: every person's fitted mesh (wireframe) over
        every frame, their number beside it
    animated_mesh : bool, also one animated glTF per person fitted in some frame
        (:func:`morphable.tracking.write_track_glb`): ``person_K.glb``, or ``track.glb`` when
        there is one person
    person_ids : list of P int, optional: the numbers the people are written under (those of
        the whole video where :func:`keep_person` kept one); default 0 ... P-1

    Returns
    -------
    list of Path, the files written. ``track.json``: the video, shots and cuts, ``people``
    (number, identity, tracks, frames fitted), ``tracks`` (number, person, shot, first and last
    frame, frames fitted), per frame the faces with their status and face score
    (``frame_status``), the face detector's frames, settings and speed; with one person also
    ``identity``, ``frames_tracked``, ``frames_lost`` and ``landmark_rmse_px`` as
    :func:`write_track` writes them. ``track.npz``: per person K the arrays of
    :data:`NPZ_KEYS` as ``personK_KEY`` (F rows, NaN where not fitted; with one person also
    under their plain names), per track T ``trackT_frames``, ``trackT_fitted``,
    ``trackT_score``, ``trackT_box`` (px), and ``track_person``, ``track_shot``, ``shots``.
    """
    from ..io.atomic import atomic_path
    from ..tracking import write_track_glb

    out = check_track_folder(folder)
    ids = list(range(len(footage.people))) if person_ids is None else [int(i) for i in person_ids]
    one = footage.people[0] if len(footage.people) == 1 else None
    model = next((p.fit.model.name for p in footage.people if p.fit is not None), None)
    if model is None:
        raise InputError(f"{video}: no face was fitted in any frame")
    tracks = [{"id": t.id, "person": ids[t.person], "shot": t.shot, "first_frame": t.first_frame,
               "last_frame": t.last_frame, "frames_fitted": t.status.count("fitted"),
               "ended": "cut or end of video" if t.lost is None else
               f"no face in its box at frame {t.lost[0]}" + ("" if t.lost[1] is None else
                                                             f" (face score {t.lost[1]:.2f})")}
              for t in footage.tracks]
    people = [{"id": ids[k], "identity": [float(x) for x in p.identity],
               "tracks": [t.id for t in footage.person_tracks(k)], "frames_tracked": int(p.tracked.sum()),
               "landmark_rmse_px": _mean(p.landmark_rmse_px)} for k, p in enumerate(footage.people)]
    summary = {"video": str(video), "model": model, "frames": footage.n_frames, "fps": footage.fps,
               "image_size": list(footage.image_size), "shots": [list(s) for s in footage.shots],
               "cuts": [int(a) for a, _ in footage.shots[1:]], "people": people, "tracks": tracks,
               "frames_detected": int(footage.detected.sum()),
               "descriptor_threshold": footage.descriptor_threshold, **(settings or {})}
    if one is not None:
        summary.update({"identity": people[0]["identity"], "frames_tracked": int(one.tracked.sum()),
                        "frames_lost": [int(i) for i in np.flatnonzero(~one.tracked)],
                        "landmark_rmse_px": _mean(one.landmark_rmse_px)})
    if seconds is not None:
        summary["tracking_fps"] = footage.n_frames / seconds
    summary["frame_status"] = footage.frame_status()
    for f in summary["frame_status"]:
        for face in f["faces"]:
            face["person"] = ids[face["person"]]
    arrays = {}
    for k, p in enumerate(footage.people):
        for key in NPZ_KEYS:
            arrays[f"person{ids[k]}_{key}"] = np.asarray(getattr(p, key))
            if one is not None:
                arrays[key] = np.asarray(getattr(p, key))
    for t in footage.tracks:
        arrays.update({f"track{t.id}_frames": t.frames, f"track{t.id}_score": t.score, f"track{t.id}_box": t.box,
                       f"track{t.id}_fitted": np.array([s == "fitted" for s in t.status], dtype=bool)})
    arrays.update(track_person=np.array([ids[t.person] for t in footage.tracks], np.int64),
                  track_shot=np.array([t.shot for t in footage.tracks], np.int64),
                  shots=np.array(footage.shots, np.int64).reshape(-1, 2), detected=footage.detected)
    out.mkdir(exist_ok=True)
    written = []
    try:
        if animated_mesh:
            for k, p in enumerate(footage.people):
                if p.tracked.any():
                    name = "track.glb" if one is not None else f"person_{ids[k]}.glb"
                    written.append(write_track_glb(p, out / name))
        if overlay_video:
            written.append(_footage_overlay(video, footage, ids, out / "overlay.mp4"))
        with atomic_path(out / "track.npz") as tmp:
            np.savez_compressed(tmp, **arrays, fps=footage.fps, image_size=np.array(footage.image_size))
        written.append(out / "track.npz")
        with atomic_path(out / "track.json") as tmp:
            Path(tmp).write_text(json.dumps(summary, indent=1))
        written.append(out / "track.json")
    except BaseException:
        for p in written:
            Path(p).unlink(missing_ok=True)
        raise
    return written


def _footage_overlay(video, footage, ids, path) -> Path:
    """Every person's fitted mesh (wireframe) over every frame, their number at the top left of
    their face, streamed."""
    from ..overlay import draw_overlay, label_faces
    from ..video import iter_frames, write_video

    index = [{int(f): i for i, f in enumerate(np.flatnonzero(p.tracked))} for p in footage.people]
    colors = [(0.2, 1.0, 0.2), (1.0, 0.6, 0.1), (0.2, 0.7, 1.0), (1.0, 0.3, 0.8), (1.0, 1.0, 0.2)]

    def frames():
        for frame in iter_frames(video):
            image, boxes, labels = frame.image, [], []
            for k, p in enumerate(footage.people):
                i = index[k].get(frame.index)
                if i is None:
                    continue
                image = draw_overlay(image, p.fit, i, mesh="wireframe", landmarks=False,
                                     mesh_color=colors[ids[k] % len(colors)])
                pts = p.landmarks_68_px[frame.index]
                boxes.append(np.r_[np.nanmin(pts, 0), np.nanmax(pts, 0)])
                labels.append(str(ids[k]))
            yield label_faces(image, boxes, labels) if boxes else image

    return write_video(path, frames(), fps=footage.fps or 30.0)
