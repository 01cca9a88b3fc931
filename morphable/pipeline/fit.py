"""One person's fit to photos, video frames and arrays: :func:`fit_images` and its
:class:`ImageFit`."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from .inputs import Picture, check_landmarks, detect_points, pictures, read_landmark_file
from .outputs import check_mesh_kind

__all__ = ["fit_images", "ImageFit", "one_landmark_set"]


@dataclass
class ImageFit:
    """The fit of one person's face in N pictures, what :func:`fit_images` returns.

    Attributes
    ----------
    fit : :class:`~morphable.fitting.FitResult`
        The fit of the N frames: identity, expression and camera per frame (mm, degrees).
    report : dict
        JSON-ready: :meth:`FitResult.to_dict <morphable.fitting.FitResult.to_dict>` (frames
        named by their pictures' labels) plus ``landmarks`` (each frame's landmark file, or the
        detector that found its points); with videos ``video_frames`` (each fitted frame's
        video, index and time in seconds) and ``frames_skipped``; when refined ``refine`` (each
        frame's refinement report).
    pictures : list of N :class:`~morphable.pipeline.inputs.Picture`
        The fitted frames in the fit's order (a video's frames without a face are not among
        them): their labels, sizes, and pixels or photo paths.
    refinements : list of N :class:`~morphable.refinement.Refinement`, or empty
        Each frame's refinement state when the fit was refined by a renderer's inversion (to
        re-render it: :func:`morphable.refinement.edit`).
    """

    fit: object
    report: dict
    pictures: list
    refinements: list = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return self.fit.n_frames

    def vertices(self, frame: int = 0) -> np.ndarray:
        """(V, 3) float32, mm: the fitted mesh of ``frame`` (its identity and expression)."""
        return self.fit.vertices(frame)

    def mesh_vertices(self, kind: str = "neutral"):
        """The mesh :meth:`write` writes, the same rule for one picture and for several:
        ``kind`` "neutral" (default): (V, 3) float32 mm, the shared (or average) identity
        without expression; "expressive": a list of N (V, 3), each frame's face with its
        expression (in the model frame, without pose)."""
        check_mesh_kind(kind)
        if kind == "expressive":
            return [self.vertices(i) for i in range(self.n_frames)]
        return self.fit.neutral_vertices()

    def images(self) -> list:
        """The N frames' pictures as the texture and overlays take them: photo paths (read
        when used), else (H, W, 3) uint8 pixels."""
        return [p.image for p in self.pictures]

    def write(self, mesh=None, report=None, texture=None, overlay=None, *, texture_size: int = 512,
              overlay_style: str | None = "shaded", overlay_crop: float | None = None,
              refine_render=None, mesh_kind: str = "neutral", overlay_mask: bool = False,
              albedo: bool = True) -> list:
        """Write the fit's files, all or nothing: every output's folder is checked first, each
        file is written atomically, and when one fails those already written are removed.

        Parameters
        ----------
        mesh : path, optional
            The mesh (:meth:`mesh_vertices` of ``mesh_kind``: "neutral", the identity without
            expression, or "expressive", each frame's face, ``NAME_0.obj``, ``NAME_1.obj``, ...
            for several frames; .obj with UVs, .ply, .stl, .off, .glb); with a texture an .obj
            names it through a material library ``NAME.mtl`` beside it.
        report : path, optional
            The JSON report: :attr:`report`, plus ``overlays`` (the paths written) and
            ``texture`` (its path, size, fractions observed and mirrored, runtime).
        texture : path, optional
            A .png UV texture (the model needs UVs), ``texture_size`` texels per side: for a
            fit refined photometrically (with ``albedo``) the recovered albedo texture, else
            the pictures' colours (:func:`morphable.texture.extract_texture`).
        overlay : path, optional
            .png/.jpg: each picture with the fitted mesh (``overlay_style``: "shaded",
            "wireframe" or None for landmarks only) and the landmarks
            (:func:`morphable.overlay.draw_overlay`; ``overlay_crop``: cut to the face widened
            by that fraction of its size); several frames: ``NAME_0.png``, ``NAME_1.png``, ...
        refine_render : path, optional
            .png: the first frame's face crop next to its refined render (a refined fit only).
        overlay_mask : bool
            Paint the photometric mask on the overlays (a refined fit only): the face pixels
            the mask leaves out tinted red.

        Returns
        -------
        list of Path, the files written.
        """
        from .outputs import write_outputs

        return write_outputs(self, mesh, report, texture, overlay, texture_size=texture_size,
                             overlay_style=overlay_style, overlay_crop=overlay_crop,
                             refine_render=refine_render, mesh_kind=mesh_kind,
                             overlay_mask=overlay_mask, albedo=albedo)


def fit_images(images, landmarks=None, *, model="sfm", refine: str | None = None,
               refine_options: dict | None = None, camera: str = "affine", focal_px=None,
               n_iterations: int = 4, robust=None, shared_identity: bool = True,
               landmark_detector: str = "auto", face_detector: str = "auto", landmark_std_px=1.0,
               video_frames: int = 5, face: int | None = None, all_faces: bool = False):
    """Fit a model to one person's face in photos, videos and image arrays, from landmarks
    given or detected.

    Parameters
    ----------
    images : a photo path, a video path, an (H, W, 3) array or a
        :class:`~morphable.video.VideoFrame`, or a list of them
        Photos are read from their files (only their header where landmarks are given); arrays
        are uint8, uint16 or float in [0, 1] (:func:`morphable.detection.images.as_image`);
        each video gives ``video_frames`` frames spread uniformly
        (:func:`morphable.video.sample_frames`).
    landmarks : None, or one entry per image (a single one for a single image)
        A landmark file (:func:`~morphable.pipeline.inputs.read_landmark_file`: iBUG ``.pts``
        or ``.ljson``, 68 points; face-mesh ``.npy``/``.json``, 478), an array of (68, 2) or
        (478, 2) pixels (0-based, x right, y down), or None: detected. A video's frames are
        always detected (their entry must be None).
    model : MorphableModel or name/path for :func:`morphable.load_model`
    refine : None, or the name of a refinement after the landmark fit
        (:func:`~morphable.pipeline.refine.refine_fit`, all frames together with one identity:
        "photometric" (= "classical"), the albedo texture and light in closed form, or "gar";
        needs torch, the neural extra)
    refine_options : dict, keywords of the refinement (e.g. ``{"steps": 100}``)
    camera, focal_px, n_iterations, robust : see :func:`morphable.fitting.fit_landmarks`
    shared_identity : bool, one identity for all pictures (False: each fitted on its own)
    landmark_detector, face_detector : see :func:`morphable.detection.detect`
    landmark_std_px : float > 0 or "auto", px, the noise of points without a σ of their own
    video_frames : int >= 1, frames sampled from each video (all of a shorter one); the
        person fitted is the largest face of the first of them with a face, found again in
        the others by their face descriptor (:mod:`morphable.descriptors`; a frame showing only
        other people is skipped)
    face : int >= 0, optional: fit face number ``face`` of a single photo or array, its faces
        numbered from 0 left to right (:func:`morphable.detection.detect_all`); default the
        largest
    all_faces : bool, fit every face of a single photo or array, each on its own

    A detector that gives each point a σ (the landmark network) has its frames fitted with
    those σ (:func:`morphable.detection.result.landmark_noise`). Frames whose landmarks are
    detected are fitted with ``model_std_mm``
    :data:`~morphable.fitting.noise.DETECTED_MODEL_STD_MM` (a detector's errors are
    face-shaped), the others with the fitter's default. A video frame without a face is
    skipped (listed in the report's ``frames_skipped``); a photo or array without one, or a
    video without a face in any sampled frame, is an error.

    Returns
    -------
    ImageFit: the fit, its report and the fitted pictures. The face fitted is each picture's
    largest (what :func:`morphable.detection.detect` finds), all as one person; a single photo's
    report then says how many faces its quickest face detector sees (``faces_seen``). With ``all_faces``: a list of
    ImageFit, one per face from left to right, each report's ``face`` its number, the faces
    found and its box (px); with ``face``: that face's ImageFit, its report's ``face`` alike.

    Raises
    ------
    InputError naming the input for a bad file, array or setting (``face`` beyond the faces
    found; ``face`` or ``all_faces`` with landmarks given, several inputs or a video);
    FitError when a photo shows no face.

    Examples
    --------
    >>> import tempfile, morphable
    >>> photo = "../shared/data/images/image_0010.png"
    >>> result = morphable.fit_images(photo, photo.replace(".png", ".pts"))
    >>> print(f"{result.fit.landmark_rmse_px[0]:.2f} px, yaw {result.fit.euler_deg[0, 0]:.1f} deg")
    5.84 px, yaw -26.7 deg
    >>> folder = tempfile.mkdtemp()
    >>> [p.name for p in result.write(mesh=f"{folder}/fit.obj", report=f"{folder}/fit.json")]
    ['fit.obj', 'fit.json']
    """
    from ..detection import describe
    from ..errors import FitError
    from ..fitting import fit_landmarks
    from ..fitting.options import detection_settings

    images = _as_list(images, 3)
    if not images:
        raise InputError("no images given")
    given = _as_list(landmarks, 2) if landmarks is not None else []
    if len(given) == 0:
        given = [None] * len(images)
    if len(given) != len(images):
        raise InputError(f"landmarks: {len(given)} given for {len(images)} images")
    if int(n_iterations) < 0:
        raise InputError(f"n_iterations must be >= 0, got {n_iterations}")
    if int(video_frames) < 1:
        raise InputError(f"video frames must be >= 1, got {video_frames}")
    describe(landmark_detector, face_detector)  # a bad choice fails before any work
    if isinstance(model, (str, Path)):
        from ..io.registry import load_model

        model = load_model(str(model))
    settings = dict(model=model, refine=refine, refine_options=refine_options, camera=camera,
                    focal_px=focal_px, n_iterations=n_iterations, robust=robust,
                    shared_identity=shared_identity, landmark_std_px=landmark_std_px)
    if face is not None or all_faces:
        return _fit_faces(images, given, face, all_faces, landmark_detector, face_detector, video_frames,
                          settings)
    items, sources = [], []
    for i, (item, lm) in enumerate(zip(images, given)):
        expanded = pictures(item, i, video_frames)
        if lm is not None and (len(expanded) != 1 or expanded[0].frame is not None):
            raise InputError(f"{item}: landmark files are for photos; a video's frames are detected")
        items += expanded
        sources += [lm] * len(expanded)
    points, kept, found, skipped, people = [], [], [], [], {}
    for picture, lm in zip(items, sources):
        if lm is None:
            try:
                det = detect_points(picture, landmark_detector, face_detector)
                if picture.frame is not None:
                    det = _same_person(picture, det, people, landmark_detector, face_detector)
            except FitError as e:
                if picture.frame is None:
                    raise
                # a video's frame without a face (turned away, occluded), or without the
                # video's person, is skipped, not fatal
                skipped.append({"image": picture.label, "time_s": round(picture.frame.time_s, 4),
                                "reason": "no face found" if str(e) != _OTHERS else _OTHERS})
                continue
            found.append(det)
            points.append(det.points)
        else:
            points.append(_given_points(lm, picture))
            found.append(None)
        kept.append((picture, lm))
    _check_every_video_kept(items, [p for p, _ in kept])
    result = _fit_found(kept, points, found, **settings)
    if any(p.frame is not None for p in items):
        result.report["video_frames"] = [{"image": p.label, "video": p.frame.source, "frame": p.frame.index,
                                          "time_s": round(p.frame.time_s, 4)}
                                         for p in result.pictures if p.frame is not None]
        result.report["frames_skipped"] = skipped
    elif len(items) == 1 and sources[0] is None:
        result.report["faces_seen"] = _faces_seen(items[0], landmark_detector, face_detector)
    return result


_OTHERS = "only other people's faces"


def _same_person(picture: Picture, det, people: dict, landmark_detector: str, face_detector: str):
    """A video frame's face of the video's person: the largest face of the first frame with a
    face fixes who (their face descriptor, :mod:`morphable.descriptors`, in ``people`` by
    video); on later frames the largest face if it is them, else the face of the frame that
    is, else FitError (the frame shows only other people)."""
    from ..descriptors import SAME_PERSON_DISTANCE, descriptor_distance, face_descriptors
    from ..detection import detect_all
    from ..errors import FitError

    image = picture.pixels()
    d = face_descriptors(image, [det.ibug68])
    ref = people.setdefault(picture.frame.source, d)
    if descriptor_distance(d, ref)[0, 0] < SAME_PERSON_DISTANCE:
        return det
    faces = detect_all(image, landmark_detector=landmark_detector, face_detector=face_detector)
    if faces:
        dist = descriptor_distance(face_descriptors(image, [f.ibug68 for f in faces]), ref)[:, 0]
        if dist.min() < SAME_PERSON_DISTANCE:
            return faces[int(np.argmin(dist))]
    raise FitError(_OTHERS)


def _faces_seen(picture: Picture, landmark_detector: str, face_detector: str) -> int:
    """How many faces a photo whose largest face was fitted shows: the boxes of the landmark
    detector's quickest face detector (:data:`morphable.detection.QUICKEST_FACE_DETECTORS`;
    3 ms, where reading every face costs 0.15 s and 30 MB more), the fitted face among them;
    the chosen face detector where one is chosen."""
    from ..detection import QUICKEST_FACE_DETECTORS, detect_faces, resolve_detectors

    if face_detector == "auto":
        face_detector = QUICKEST_FACE_DETECTORS.get(resolve_detectors(landmark_detector)[0], "auto")
    boxes = detect_faces(picture.pixels(), landmark_detector=landmark_detector, face_detector=face_detector)
    return max(1, len(boxes))


def _fit_found(kept, points, found, *, model, refine, refine_options, camera, focal_px, n_iterations,
               robust, shared_identity, landmark_std_px) -> ImageFit:
    """The fit of the pictures ``kept`` (``[(Picture, landmarks given or None)]``) from their
    points (each (L, 2) px) and detections (a Detection or None each)."""
    from ..fitting import fit_landmarks
    from ..fitting.options import detection_settings

    lms = one_landmark_set(points)
    res = fit_landmarks(model, lms, np.array([p.size for p, _ in kept], dtype=np.float64), camera=camera,
                        focal_px=focal_px, n_iterations=int(n_iterations),
                        robust=robust, shared_identity=shared_identity,
                        **detection_settings(found, np.shape(lms)[1], landmark_std_px))
    fitted = [p for p, _ in kept]
    # "auto" may have found a photo's face with the network where the face mesh found none
    extra = {"landmarks": [_source(lm) if lm is not None else d.detector for (_, lm), d in zip(kept, found)]}
    states = []
    if refine is not None:
        from .refine import refine_fit

        res, runs, states = refine_fit(res, fitted, refine, **(refine_options or {}))
        extra["refine"] = runs
    report = {**res.to_dict(images=[p.label for p in fitted]), **extra}
    return ImageFit(fit=res, report=report, pictures=fitted, refinements=states)


def _all_faces(picture: Picture, landmark_detector: str, face_detector: str) -> list:
    """Every face of one picture, left to right (:func:`morphable.detection.detect_all`, its
    tiles searched too), after :func:`~.inputs.detect_points`' size check."""
    from ..detection import detect_all
    from .inputs import check_detect_size

    check_detect_size(picture)
    return detect_all(picture.image, landmark_detector=landmark_detector, face_detector=face_detector,
                      tiles=True)


def _fit_faces(images, given, face, all_faces, landmark_detector, face_detector, video_frames, settings):
    """``fit_images`` with ``face`` or ``all_faces``: one photo's faces, each fitted alone."""
    from ..detection import face_box
    from ..errors import FitError

    what = "all_faces" if all_faces else "face"
    if face is not None and all_faces:
        raise InputError("give face or all_faces, not both")
    if len(images) != 1:
        raise InputError(f"{what}: for one photo, got {len(images)} inputs")
    if given[0] is not None:
        raise InputError(f"{what}: for detected faces; landmarks were given")
    if face is not None and (isinstance(face, bool) or int(face) != face or face < 0):
        raise InputError(f"face must be a face number >= 0, got {face}")
    (picture, *more) = pictures(images[0], 0, video_frames)
    if more or picture.frame is not None:
        raise InputError(f"{picture.label}: {what} is for photos; a video's faces are tracked "
                         "(morphable track, morphable.track_footage)")
    faces = _all_faces(picture, landmark_detector, face_detector)
    if not faces:
        raise FitError(f"{picture.label}: no face found")
    if face is not None and face >= len(faces):
        raise InputError(f"{picture.label}: face {face} asked for, {len(faces)} "
                         f"face{'s were' if len(faces) > 1 else ' was'} found (0 to {len(faces) - 1})")
    chosen = range(len(faces)) if all_faces else [int(face)]
    results = []
    for k in chosen:
        result = _fit_found([(picture, None)], [faces[k].points], [faces[k]], **settings)
        result.report["face"] = {"index": k, "faces_found": len(faces),
                                 "box_px": [round(float(v), 2) for v in face_box(faces[k])]}
        results.append(result)
    return results if all_faces else results[0]


def _as_list(value, item_ndim: int) -> list:
    """One input or a list of them -> a list: a list or tuple holds inputs, so does an array of
    more than ``item_ndim`` dimensions (an image has 3 or 2, landmarks 2); anything else is one."""
    if isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray) and value.ndim > item_ndim):
        return list(value)
    return [value]


def _given_points(lm, picture: Picture) -> np.ndarray:
    """A picture's landmarks given as a file or an array, checked against its size."""
    if isinstance(lm, (str, Path)):
        return read_landmark_file(lm, picture.size)
    return check_landmarks(lm, picture.size, f"landmarks of {picture.label}")


def _source(lm) -> str:
    """How the report names landmarks that were given: the file, or "array"."""
    return str(lm) if isinstance(lm, (str, Path)) else "array"


def _check_every_video_kept(items, kept) -> None:
    """InputError naming a video none of whose sampled frames showed a face."""
    sources = {p.frame.source for p in kept if p.frame is not None}
    for video in dict.fromkeys(p.frame.source for p in items if p.frame is not None):
        if video not in sources:
            n = sum(1 for p in items if p.frame is not None and p.frame.source == video)
            raise InputError(f"{video}: no face found in any of the {n} sampled frames")


def one_landmark_set(points: list) -> np.ndarray:
    """(N, L, 2): the frames' landmarks as one set. A fit takes one landmark scheme, so when
    68-point and 478-point frames are mixed the face mesh's go through
    :data:`morphable.detection.facemesh.FACEMESH_TO_IBUG68`."""
    if len({len(p) for p in points}) == 1:
        return np.stack(points)
    from ..detection.facemesh import to_ibug68

    return np.stack([p if len(p) == 68 else to_ibug68(p) for p in points])
