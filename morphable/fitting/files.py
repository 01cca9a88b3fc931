"""Fitting from files: images and landmark files in, a mesh and a JSON report out.

The steps of ``morphable fit`` and of each item of ``morphable fit-batch``, usable alone:

- :func:`morphable.detection.image_size` reads only an image's header (no decoding, so a huge
  image costs nothing);
- :func:`read_landmark_file` reads iBUG ``.pts`` or menpo ``.ljson`` 68-point files, or 478
  face-mesh points (``.npy``, ``.json``), and checks them against the image;
- :func:`fit_files` fits (detecting landmarks where no file is given, with the landmark and
  face detectors of :mod:`morphable.detection`);
- :func:`write_fit` writes the mesh and the report atomically, only after the fit succeeded;
- :func:`fit_item` is the work function of :func:`morphable.batch.run_batch`.

Every problem with an input is an :class:`~morphable.errors.InputError` naming the file.

>>> from morphable.fitting.files import fit_files, write_fit          # doctest: +SKIP
>>> res, report = fit_files(["image_0010.png"], ["image_0010.pts"])   # doctest: +SKIP
>>> write_fit(res, report, mesh="fit.obj", report_path="fit.json")    # doctest: +SKIP
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..detection.images import image_size
from ..errors import InputError

__all__ = ["read_landmark_file", "one_landmark_set", "expand_videos", "fit_files", "write_fit", "fit_item",
           "MAX_DETECT_MEGAPIXELS", "OUTSIDE_MARGIN"]

MAX_DETECT_MEGAPIXELS = 40.0
"""Largest image (in millions of pixels) handed to the face detector: dlib's HOG pyramid on a
larger image takes minutes and gigabytes; such images need ``--landmarks`` or downscaling."""

OUTSIDE_MARGIN = 0.1
"""Landmarks may lie outside the image by this fraction of its width/height (faces cut by the
border are annotated that way); further out, the file does not belong to the image."""


def read_landmark_file(path, size=None) -> np.ndarray:
    """Landmarks from a file, checked against an image size.

    Parameters
    ----------
    path : one of
        ``.pts`` — 68 iBUG points, 1-based pixels;
        ``.ljson`` — menpo, 68 points in iBUG order or labelled;
        ``.npy`` — a (478, 2) array of face-mesh points (mediapipe's order), 0-based pixels;
        ``.json`` — 478 face-mesh points as a list of ``[x, y]`` or ``{"landmarks": [...]}``,
        0-based pixels.
    size : (W, H) pixels, optional; landmarks further than ``OUTSIDE_MARGIN`` outside are refused

    Returns
    -------
    (68, 2) or (478, 2) float64 pixels, 0-based, x right, y down; NaN rows for missing
    points (.ljson only).
    """
    from ..detection.facemesh import N_POINTS
    from ..io.landmark_files import read_ljson, read_pts
    from ..ibug68 import MENPO_LABELS, from_menpo_labels

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such landmark file")
    suffix = path.suffix.lower()
    if suffix in (".npy", ".json"):
        pts = _read_facemesh_points(path)
        if pts.shape != (N_POINTS, 2):
            raise InputError(f"{path}: expected {N_POINTS} x 2 face-mesh landmarks, got shape {pts.shape}")
        if not np.isfinite(pts).all():
            raise InputError(f"{path}: coordinates contain NaN or inf")
    elif suffix == ".ljson":
        pts, labels = read_ljson(path)
        if pts.shape[1] != 2:
            raise InputError(f"{path}: expected 2D landmarks, got {pts.shape[1]}D points")
        if len(pts) == 68 and labels and set(labels) <= set(MENPO_LABELS):
            pts = from_menpo_labels(pts, labels, str(path))
    else:
        pts = read_pts(path)
    if suffix not in (".npy", ".json") and pts.shape != (68, 2):
        raise InputError(f"{path}: expected 68 iBUG landmarks, got {len(pts)}")
    if size is not None:
        W, H = size
        lo = -0.5 - OUTSIDE_MARGIN * np.array([W, H])
        hi = np.array([W, H]) - 0.5 + OUTSIDE_MARGIN * np.array([W, H])
        with np.errstate(invalid="ignore"):
            out = np.flatnonzero(((pts < lo) | (pts > hi)).any(1))
        if out.size:
            i = int(out[0])
            raise InputError(f"{path}: landmark {i + 1} at ({pts[i, 0]:.1f}, {pts[i, 1]:.1f}) px "
                             f"is outside the {W}x{H} image")
    return pts


def _read_facemesh_points(path: Path) -> np.ndarray:
    """A ``.npy`` array or a ``.json`` list (bare or under ``"landmarks"``) -> float64 array
    of whatever shape it holds; InputError naming the file when it is not numbers."""
    try:
        if path.suffix.lower() == ".npy":
            data = np.load(path, allow_pickle=False)
        else:
            data = json.loads(path.read_text())
            if isinstance(data, dict):
                if "landmarks" not in data:
                    raise InputError(f"{path}: expected a list of [x, y] or {{\"landmarks\": [...]}}")
                data = data["landmarks"]
        return np.asarray(data, dtype=np.float64)
    except (OSError, ValueError, TypeError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read landmarks ({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None


def _detect(image, name, size, landmark_detector: str, face_detector: str):
    """The :class:`~morphable.detection.result.Detection` of a photo's path or a video frame's
    pixels (its points, and its σ where the detector gives one); ``name`` for messages."""
    from ..detection import detect

    mp = size[0] * size[1] / 1e6
    if mp > MAX_DETECT_MEGAPIXELS:
        raise InputError(f"{name}: {size[0]}x{size[1]} is {mp:.1f} megapixels, more than the "
                         f"{MAX_DETECT_MEGAPIXELS:.0f} megapixels face detection takes; downscale it or give landmarks")
    return detect(image, landmark_detector=landmark_detector, face_detector=face_detector)


def expand_videos(images, n_frames: int = 5) -> list:
    """Photos and videos -> photos and video frames: each video (:func:`morphable.video.is_video`)
    replaced by ``n_frames`` of its frames spread uniformly (:func:`morphable.video.sample_frames`,
    the Florence protocol's 5 by default), as :class:`~morphable.video.VideoFrame` objects;
    photos (paths) and frames already decoded stay as they are."""
    from ..video import is_video, sample_frames

    out = []
    for item in images:
        if is_video(item):
            out.extend(sample_frames(item, n_frames))
        else:
            out.append(item if _is_frame(item) else Path(item))
    return out


def _is_frame(item) -> bool:
    # by attribute rather than isinstance: morphable.video stays unimported for photos
    return hasattr(item, "image") and hasattr(item, "label")


def one_landmark_set(points: list) -> np.ndarray:
    """(N, L, 2): the frames' landmarks as one set. A fit takes one landmark scheme, so when
    68-point and 478-point frames are mixed the face mesh's go through
    :data:`morphable.detection.facemesh.FACEMESH_TO_IBUG68`."""
    if len({len(p) for p in points}) == 1:
        return np.stack(points)
    from ..detection.facemesh import to_ibug68

    return np.stack([p if len(p) == 68 else to_ibug68(p) for p in points])


def fit_files(images, landmarks=None, *, model="sfm", camera: str = "affine", focal_px=None,
              n_iterations: int = 4, robust=None, shared_identity: bool = True,
              landmark_detector: str = "auto", face_detector: str = "auto", landmark_std_px=1.0,
              video_frames: int = 5):
    """Fit a model to one or more images or videos of a person, from landmark files or detection.

    Parameters
    ----------
    images : list of photo paths, video paths and :class:`~morphable.video.VideoFrame` objects;
        each video gives ``video_frames`` frames spread uniformly (:func:`expand_videos`)
    landmarks : list of paths or None (one per photo; a None entry is detected); see
        :func:`read_landmark_file`. Video frames are always detected (their entry must be None).
    model : MorphableModel or name/path for ``load_model``
    camera, focal_px, n_iterations, landmark_std_px : see :func:`morphable.fitting.fit_landmarks`
    robust : None or "huber" (see :func:`morphable.fitting.fit_landmarks`)
    shared_identity : bool, one identity for all images (False: independent fits)
    landmark_detector, face_detector : see :func:`morphable.detection.detect_landmarks`
    video_frames : int >= 1, frames sampled from each video (all of a shorter one)

    A detector that gives each point a σ (the landmark network) has its frames fitted with
    those σ (:func:`morphable.detection.result.landmark_noise`; ``landmark_std_px`` for the
    other frames). Frames whose landmarks are detected are fitted with ``model_std_mm``
    :data:`~morphable.fitting.noise.DETECTED_MODEL_STD_MM` (a detector's errors are
    face-shaped), the others with the fitter's default. A video frame without a face is
    skipped (listed in the report's ``frames_skipped``); a photo without one, or a video
    without a face in any sampled frame, is an error.

    Returns
    -------
    (FitResult, report dict) — the report is ``FitResult.to_dict`` (frames named by path, video
    frames as ``clip.mp4#INDEX``) plus the landmark sources; with videos also
    ``video_frames`` (each fitted frame's video, index and time in seconds) and
    ``frames_skipped``.
    """
    from ..detection import describe
    from ..errors import FitError
    from . import fit_landmarks
    from .options import detection_settings

    images = list(images)
    if not images:
        raise InputError("no images given")
    landmarks = list(landmarks) if landmarks else [None] * len(images)
    if len(landmarks) != len(images):
        raise InputError(f"landmarks: {len(landmarks)} files for {len(images)} images")
    if int(n_iterations) < 0:
        raise InputError(f"n_iterations must be >= 0, got {n_iterations}")
    if int(video_frames) < 1:
        raise InputError(f"video frames must be >= 1, got {video_frames}")
    describe(landmark_detector, face_detector)  # a bad choice fails before any work
    items, files = [], []
    for item, lm in zip(images, landmarks):
        expanded = expand_videos([item], video_frames)
        if lm and (len(expanded) != 1 or _is_frame(expanded[0])):
            raise InputError(f"{item}: landmark files are for photos; a video's frames are detected")
        items += expanded
        files += [lm] * len(expanded)
    sizes = [item.size if _is_frame(item) else image_size(item) for item in items]
    points, kept, skipped, found = [], [], [], []
    for item, lm, size in zip(items, files, sizes):
        if lm:
            points.append(read_landmark_file(lm, size))
            found.append(None)
        elif _is_frame(item):
            try:
                found.append(_detect(item.image, item.label, size, landmark_detector, face_detector))
                points.append(found[-1].points)
            except FitError:
                # a video's frame without a face (turned away, occluded) is skipped, not fatal
                skipped.append({"image": item.label, "time_s": round(item.time_s, 4),
                                "reason": "no face found"})
                continue
        else:
            found.append(_detect(item, item, size, landmark_detector, face_detector))
            points.append(found[-1].points)
        kept.append((item, lm, size))
    _check_every_video_kept(items, kept)
    lms = one_landmark_set(points)
    if isinstance(model, (str, Path)):
        from ..io.registry import load_model

        model = load_model(str(model))
    res = fit_landmarks(model, lms, np.array([s for _, _, s in kept], dtype=np.float64), camera=camera,
                        focal_px=focal_px, n_iterations=int(n_iterations),
                        robust=robust, shared_identity=shared_identity,
                        **detection_settings(found, np.shape(lms)[1], landmark_std_px))
    report = res.to_dict(images=[item.label if _is_frame(item) else str(item) for item, _, _ in kept])
    # "auto" may have found a photo's face with the network where the face mesh found none
    report["landmarks"] = [str(lm) if lm else d.detector for (_, lm, _), d in zip(kept, found)]
    if any(_is_frame(item) for item in items):
        report["video_frames"] = [{"image": item.label, "video": item.source, "frame": item.index,
                                   "time_s": round(item.time_s, 4)}
                                  for item, _, _ in kept if _is_frame(item)]
        report["frames_skipped"] = skipped
    return res, report


def _check_every_video_kept(items, kept) -> None:
    """InputError naming a video none of whose sampled frames showed a face."""
    sources = {item.source for item, _, _ in kept if _is_frame(item)}
    for video in dict.fromkeys(item.source for item in items if _is_frame(item)):
        if video not in sources:
            n = sum(1 for item in items if _is_frame(item) and item.source == video)
            raise InputError(f"{video}: no face found in any of the {n} sampled frames")


def write_fit(result, report, mesh=None, report_path=None, texture=None,
              texture_path=None) -> list:
    """Write the fitted mesh (one image: that frame; several: the shared neutral identity) and
    the JSON report, each atomically. Returns the paths written.

    ``texture`` (a :class:`morphable.texture.PhotoTexture`) is written to ``texture_path``
    (PNG) first; an OBJ ``mesh`` then carries the texture's UV layout and names the image
    through a material library beside it (``NAME.mtl``)."""
    from ..io.atomic import atomic_path
    from ..io.mesh import write_mesh

    for out in (mesh, report_path, texture_path):
        # check every output's folder first: either every output is written or none
        if out and not Path(out).resolve().parent.is_dir():
            raise InputError(f"{out}: folder {Path(out).parent} does not exist")
    written = []
    m = result.model
    uv, tuv = m.uv, m.triangle_uv
    if texture is not None and texture_path:
        from ..texture import save_texture

        save_texture(texture, texture_path)
        written.append(Path(texture_path))
        uv, tuv = texture.uv, texture.triangle_uv
    if mesh:
        verts = result.vertices(0) if result.n_frames == 1 else result.neutral_vertices()
        material = texture_path if texture is not None and Path(mesh).suffix.lower() == ".obj" else None
        write_mesh(mesh, verts, m.triangles, uv, tuv, texture=material)
        written.append(Path(mesh))
    if report_path:
        with atomic_path(report_path) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=2))
        written.append(Path(report_path))
    return written


def fit_item(item, folder, options: dict) -> dict:
    """Work function of ``morphable fit-batch``: fit one :class:`~morphable.batch.BatchItem`
    (all its images together) and write ``fit.obj`` and ``fit.json`` into ``folder``.

    ``options``: ``model``, ``camera``, ``focal_px``, ``n_iterations``, ``robust``, ``independent``,
    ``landmark_detector``, ``face_detector``, ``landmark_std_px``, ``mesh_format`` (suffix,
    default ``obj``).

    Returns a summary for the results log: n_frames, landmark RMSE (px, per frame and mean),
    yaw/pitch/roll of each frame (degrees) and the fit's runtime.
    """
    folder = Path(folder)
    res, report = fit_files(item.images, item.landmarks or None,
                            model=options.get("model", "sfm"), camera=options.get("camera", "affine"),
                            focal_px=options.get("focal_px"), n_iterations=options.get("n_iterations", 4),
                            robust=options.get("robust"),
                            shared_identity=not options.get("independent", False),
                            landmark_detector=options.get("landmark_detector", "auto"),
                            face_detector=options.get("face_detector", "auto"),
                            landmark_std_px=options.get("landmark_std_px", 1.0))
    suffix = options.get("mesh_format", "obj").lstrip(".")
    write_fit(res, report, mesh=folder / f"fit.{suffix}", report_path=folder / "fit.json")
    rmse = [round(float(x), 4) for x in res.landmark_rmse_px]
    return {"n_frames": res.n_frames, "landmark_rmse_px": round(float(np.mean(rmse)), 4),
            "frame_rmse_px": rmse,
            "pose_deg": [[round(float(a), 3) for a in e] for e in res.euler_deg],
            "fit_ms": round(float(res.runtime_ms), 2)}
