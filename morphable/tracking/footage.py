"""Footage: every face of a video, shot by shot, joined into people, one identity per person.

:func:`track_footage` runs these steps (frames streamed, never all held):

1. the shots (:func:`morphable.shots.find_shots`: hard cuts and fades), one decoding pass;
2. every frame, in a second pass: each running track's face read by the landmark detector
   in the box its previous frame's points give (:func:`morphable.detection.detect_in_boxes`);
   the face detector (:func:`morphable.detection.detect_all`, the faces not tracked already)
   at a shot's start and every :data:`REDETECT_S` seconds, and a quicker one
   (:data:`morphable.detection.QUICK_FACE_DETECTORS`) every :data:`QUICK_S` seconds and
   wherever a track has lost
   its face, the quickest (:data:`morphable.detection.QUICKEST_FACE_DETECTORS`) on the other
   frames where no face is tracked. A face found is associated with the tracks that lost
   theirs on that frame by box overlap (:func:`associate`: the landmark detector lost the face
   in its carried box, the face detector found it there); one left over starts a track. A
   track ends at a cut, or where its box holds no face (the face detector finds none there
   either, or the landmark network scores the crop below
   :data:`~morphable.detection.result.FACE_PROBABILITY`: a back of a head, a profile beyond
   what it reads); two tracks on one face end in one;
3. each track's face descriptor (:mod:`morphable.descriptors`) on its first frame and then
   every :data:`DESCRIPTOR_EVERY_S` seconds;
4. the tracks joined into people (:func:`join_tracks`): tracks whose mean descriptors lie
   within :data:`~morphable.descriptors.SAME_PERSON_DISTANCE` (average linkage), never two that
   share a frame;
5. each person's identity from their own frames (:data:`IDENTITY_FRAMES` spread over them,
   each fitted alone and their identities averaged, as ``morphable track`` did for its one
   face); each frame's pose and expression with it held (:func:`~morphable.tracking.fit_frames`),
   then the temporal prior along each track (:func:`~morphable.tracking.smooth_trajectories`).

What is held in memory: never the frames; a face's detected points (float32, about 6 KB a
frame) only for a running track's last :data:`CHUNK_ROWS` frames, the older ones in a
temporary folder until the fits; the result, per person, arrays over all the video's frames
(about 5 KB a frame: :class:`~morphable.tracking.TrackResult`'s points).

Units: angles in degrees, translations in mm, image points in pixels (0-based, x right, y down).
"""
from __future__ import annotations

import dataclasses
import pickle
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["FootageResult", "TrackInfo", "track_footage", "associate", "join_tracks", "REDETECT_S",
           "QUICK_S", "TRACKING_DETECTORS", "CHUNK_ROWS",
           "DESCRIPTOR_EVERY_S", "MAX_DESCRIPTORS", "IDENTITY_FRAMES", "MATCH_IOU", "STATUSES"]

REDETECT_S = 2.0
"""The face detector as chosen runs at a shot's start and then this often (seconds of video)."""
QUICK_S = 0.25
"""Between those, a quicker face detector (:data:`morphable.detection.QUICK_FACE_DETECTORS`)
runs this often and
on every frame where a track has lost its face, so that a face entering the picture is found
within a few frames; on frames where no face is tracked, the quickest
(:data:`morphable.detection.QUICKEST_FACE_DETECTORS`, with ``face_detector="auto"``) runs in
between: it finds a face of 100 px or more in a 640 x 480 frame at once, the quick searches
the smaller ones. All read only the faces not tracked already."""
TRACKING_DETECTORS = {"fused": "network"}
"""``landmark_detector="auto"`` resolved (:func:`morphable.detection.resolve_detectors`) -> what
the tracker reads faces with: the landmark network alone where "auto" would fuse it with the
face mesh. On the benchmark's clips (``python -m evaluation.bench_footage --clips 3``,
docs/video.md) the fused reading costs 3 x the network's per face (24 against 8 ms in a
cProfile of three faces) for an eye-centre error no lower (3.17 against 3.20 % of the
interocular distance, the mean of three clips)."""
DESCRIPTOR_EVERY_S = 1.0
"""A track's face descriptor is computed on its first frame and then this often (seconds)."""
MAX_DESCRIPTORS = 5
"""Descriptors kept per track (about 75 ms each on one core)."""
IDENTITY_FRAMES = 9
"""Frames per person, spread over their tracked frames, fitted for their identity."""
MATCH_IOU = 0.3
"""A face the face detector finds continues a running track whose box it overlaps by this
IoU or more (:func:`associate`)."""
STATUSES = ("fitted", "no fit")
"""A track's frame: its face fitted, or its points read but not fitted by the person's face
(the fit misses them by more than :data:`~morphable.tracking.LOST_RMSE_FRACTION`: no mesh)."""


@dataclasses.dataclass
class TrackInfo:
    """One track: a face followed through consecutive frames of one shot.

    Attributes
    ----------
    id : int, the track's number (in order of start)
    person : int, the person it belongs to (:attr:`FootageResult.people`)
    shot : int, the shot it lies in
    frames : (n,) int64, the video frames it has a face in (consecutive)
    status : list of n str, per frame, :data:`STATUSES`
    score : (n,) float64, the landmark detector's face probability (NaN where it gives none)
    box : (n, 4) float64 px, the face box per frame
    descriptors : (M, 128) float32, its face descriptors (M <= :data:`MAX_DESCRIPTORS`)
    lost : (frame, face score or None) or None: where the track ended because its box held no
        face (the landmark detector's face score there, below
        :data:`~morphable.detection.result.FACE_PROBABILITY`, or None where it read nothing);
        None where it ended at a cut or the video's end
    """

    id: int
    person: int
    shot: int
    frames: np.ndarray
    status: list
    score: np.ndarray
    box: np.ndarray
    descriptors: np.ndarray
    lost: tuple | None = None

    @property
    def first_frame(self) -> int:
        return int(self.frames[0])

    @property
    def last_frame(self) -> int:
        return int(self.frames[-1])


@dataclasses.dataclass
class FootageResult:
    """What :func:`track_footage` found in a video.

    Attributes
    ----------
    shots : list of (start, end) frame indices, end exclusive
    tracks : list of :class:`TrackInfo`
    people : list of :class:`~morphable.tracking.TrackResult`, one per person (P of them):
        their identity, and per video frame (all F of them; NaN where the person is not fitted)
        pose, expression, points, ``tracked``; ``detected`` is the video's (the face detector
        ran on the frame)
    detected : (F,) bool, the face detector ran on the frame
    fps : float
    image_size : (W, H) px
    descriptor_threshold : float, the descriptor distance that joined tracks
    """

    shots: list
    tracks: list
    people: list
    detected: np.ndarray
    fps: float
    image_size: tuple
    descriptor_threshold: float

    @property
    def n_frames(self) -> int:
        return len(self.detected)

    def person_tracks(self, person: int) -> list:
        """The :class:`TrackInfo` of one person, in order."""
        return [t for t in self.tracks if t.person == person]

    def largest_person(self) -> int:
        """The person whose face covers the most pixels, summed over the frames (a person who
        fills the picture, or who is there the longest)."""
        area = np.zeros(len(self.people))
        for t in self.tracks:
            area[t.person] += float(((t.box[:, 2] - t.box[:, 0]) * (t.box[:, 3] - t.box[:, 1])).sum())
        return int(np.argmax(area))

    def frame_status(self) -> list:
        """Per video frame ``{"frame", "shot", "detector", "faces": [{"person", "track",
        "status", "score"}]}``: what ``track.json`` lists. A track's face is ``"fitted"`` or
        ``"no fit"`` (:data:`STATUSES`) in its frames, and ``"lost"`` in the frame after its
        last where its box held no face (its score there: a back of a head, a face turned
        beyond what the detector reads, no face)."""
        shot_of = np.zeros(self.n_frames, np.int64)
        for k, (a, b) in enumerate(self.shots):
            shot_of[a:b] = k
        faces = [[] for _ in range(self.n_frames)]
        for t in self.tracks:
            for f, s, p in zip(t.frames, t.status, t.score):
                faces[int(f)].append({"person": t.person, "track": t.id, "status": s,
                                      "score": None if not np.isfinite(p) else round(float(p), 3)})
            if t.lost is not None:
                f, p = t.lost
                faces[int(f)].append({"person": t.person, "track": t.id, "status": "lost",
                                      "score": None if p is None else round(float(p), 3)})
        return [{"frame": i, "shot": int(shot_of[i]), "detector": bool(self.detected[i]), "faces": faces[i]}
                for i in range(self.n_frames)]


CHUNK_ROWS = 256
"""A track's detections held in memory at most (about 6 KB each); older ones wait on disk in
chunks of this many, so that memory does not grow with the video's length."""


class _Running:
    """A track being followed: its frames, face scores and boxes, and its detections as
    compact float32 copies, all but the last :data:`CHUNK_ROWS` in ``folder`` on disk."""

    def __init__(self, id: int, shot: int, folder: Path):
        self.id, self.shot, self.folder = id, shot, Path(folder)
        self.frames, self.scores, self.boxes, self.descriptors = [], [], [], []
        self.last_descriptor = -10 ** 9
        self.recent, self.n_chunks, self.loaded = [], 0, (None, None)
        self.end = None         # (frame, face score or None) where its box held no face

    def add(self, frame: int, det) -> None:
        from ..detection import face_box

        if len(self.recent) == CHUNK_ROWS:
            with open(self.folder / f"{self.id}_{self.n_chunks}.pkl", "wb") as f:
                pickle.dump(self.recent, f, protocol=pickle.HIGHEST_PROTOCOL)
            self.recent, self.n_chunks = [], self.n_chunks + 1
        f32 = (lambda a: None if a is None else np.asarray(a, np.float32))     # noqa: E731
        self.frames.append(frame)
        self.scores.append(np.nan if det.score is None else float(det.score))
        self.boxes.append(face_box(det))
        self.recent.append((f32(det.points), f32(det.sigma_px), f32(det.ibug68), f32(det.ibug68_sigma_px),
                            det.scheme, det.convention, det.detector))

    def drop_last(self) -> None:
        """Forget the row just added (its face is another track's)."""
        for rows in (self.frames, self.scores, self.boxes, self.recent):
            rows.pop()

    @property
    def box(self) -> np.ndarray:
        return self.boxes[-1]

    @property
    def ibug68(self) -> np.ndarray:
        return self.recent[-1][2]

    def detection(self, k: int):
        from ..detection.result import Detection

        chunk, j = divmod(k, CHUNK_ROWS)
        if chunk == self.n_chunks:
            rows = self.recent
        else:
            if self.loaded[0] != chunk:
                with open(self.folder / f"{self.id}_{chunk}.pkl", "rb") as f:
                    self.loaded = chunk, pickle.load(f)
            rows = self.loaded[1]
        p, s, i, si, scheme, convention, name = rows[j]
        score = self.scores[k]
        return Detection(p, s, i, si, scheme, convention, name, None if np.isnan(score) else score, self.boxes[k])


def associate(track_boxes, found_boxes, min_iou: float = MATCH_IOU) -> list:
    """Running tracks' boxes (T, 4) and newly found faces' boxes (N, 4) px -> the pairs
    ``[(track, face), ...]`` of the assignment of largest total overlap (Hungarian, scipy)
    whose IoU is at least ``min_iou``.

    >>> associate([[0, 0, 10, 10], [20, 0, 30, 10]], [[21, 0, 31, 10], [50, 0, 60, 10]])
    [(1, 0)]
    """
    from scipy.optimize import linear_sum_assignment

    from ..detection.boxes import iou

    a = np.asarray(track_boxes, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(found_boxes, dtype=np.float64).reshape(-1, 4)
    if not len(a) or not len(b):
        return []
    overlap = np.stack([iou(b, box) for box in a])          # (T, N)
    rows, cols = linear_sum_assignment(-overlap)
    return [(int(r), int(c)) for r, c in zip(rows, cols) if overlap[r, c] >= min_iou]


def join_tracks(descriptors, frames, threshold: float | None = None) -> np.ndarray:
    """Tracks -> people: average-linkage clustering of the tracks' descriptors, two groups
    joined while their mean distance is below ``threshold`` and no track of one shares a frame
    with a track of the other (one person is in one place at a time).

    Parameters
    ----------
    descriptors : list of T (M_t, 128) arrays (M_t >= 0; a track without one stays alone)
    frames : list of T arrays of frame indices
    threshold : descriptor distance; None: :data:`~morphable.descriptors.SAME_PERSON_DISTANCE`

    Returns
    -------
    (T,) int64 person per track, numbered by first appearance from 0.

    >>> d = np.eye(128)[[0, 0, 1]] * 1.0
    >>> join_tracks([d[:1], d[1:2], d[2:]], [np.arange(5), np.arange(10, 15), np.arange(20, 25)]).tolist()
    [0, 0, 1]
    """
    from ..descriptors import SAME_PERSON_DISTANCE, descriptor_distance

    threshold = SAME_PERSON_DISTANCE if threshold is None else float(threshold)
    T = len(descriptors)
    groups = [[t] for t in range(T)]
    spans = [set(int(f) for f in fr) for fr in frames]
    while True:
        best, pair = threshold, None
        for i in range(len(groups)):
            for j in range(i + 1, len(groups)):
                di = [descriptors[t] for t in groups[i] if len(descriptors[t])]
                dj = [descriptors[t] for t in groups[j] if len(descriptors[t])]
                if not di or not dj:
                    continue
                d = float(descriptor_distance(np.concatenate(di), np.concatenate(dj)).mean())
                if d < best and not any(spans[a] & spans[b] for a in groups[i] for b in groups[j]):
                    best, pair = d, (i, j)
        if pair is None:
            break
        i, j = pair
        groups[i] += groups.pop(j)
    first = [min(min(frames[t]) if len(frames[t]) else 0 for t in g) for g in groups]
    person = np.zeros(T, np.int64)
    for k, g in enumerate(np.argsort(first, kind="stable")):
        person[groups[g]] = k
    return person


def track_footage(path, *, model="sfm", landmark_detector: str = "auto", face_detector: str = "auto",
                  smoothing_hz: float | None = None, identity_frames: int = IDENTITY_FRAMES,
                  descriptor_threshold: float | None = None, shots=None,
                  progress: bool = False) -> FootageResult:
    """Track every face of a video through its shots, joined into people (see the module).

    Parameters
    ----------
    path : a video file (:mod:`morphable.video`)
    model : MorphableModel or name/path
    landmark_detector, face_detector : see :func:`morphable.detection.detect` ("auto": as
        resolved there, except :data:`TRACKING_DETECTORS`)
    smoothing_hz : cut-off of the temporal prior along each track, Hz (0: off; None:
        :data:`~morphable.tracking.DEFAULT_SMOOTHING_HZ`)
    identity_frames : int >= 1, frames per person fitted for their identity
    descriptor_threshold : distance joining tracks into a person (None:
        :data:`~morphable.descriptors.SAME_PERSON_DISTANCE`)
    shots : list of (start, end), optional: the shots when known (else
        :func:`morphable.shots.find_shots`)
    progress : a progress bar on stderr

    Returns
    -------
    :class:`FootageResult`

    Raises
    ------
    InputError for a bad file or setting, or a video in which no frame shows a face (nothing
    to write).
    """
    from ..descriptors import SAME_PERSON_DISTANCE, face_descriptors
    from ..detection import (QUICK_FACE_DETECTORS, QUICKEST_FACE_DETECTORS, describe, detect_all,
                             detect_in_boxes, face_box, resolve_detectors)
    from ..detection.boxes import iou
    from ..detection.result import FACE_PROBABILITY
    from ..shots import find_shots
    from ..video import iter_frames, probe
    from .single import DEFAULT_SMOOTHING_HZ

    smoothing_hz = DEFAULT_SMOOTHING_HZ if smoothing_hz is None else smoothing_hz
    if int(identity_frames) < 1:
        raise InputError(f"identity frames must be >= 1, got {identity_frames}")
    if not smoothing_hz >= 0:
        raise InputError(f"smoothing must be >= 0 Hz, got {smoothing_hz}")
    describe(landmark_detector, face_detector)          # a bad choice fails before any work
    if landmark_detector == "auto":
        landmark_detector = TRACKING_DETECTORS.get(resolve_detectors()[0], "auto")
    info = probe(path)
    if isinstance(model, (str, Path)):
        from ..io.registry import load_model

        model = load_model(str(model))
    shots = find_shots(path) if shots is None else [(int(a), int(b)) for a, b in shots]
    fps = info.fps or 30.0
    redetect, every = max(1, round(REDETECT_S * fps)), max(1, round(DESCRIPTOR_EVERY_S * fps))
    quick_every = max(1, round(QUICK_S * fps))
    starts = {a: k for k, (a, _) in enumerate(shots)}
    detectors = {"landmark_detector": landmark_detector, "face_detector": face_detector}
    quick, empty = dict(detectors), dict(detectors)
    if face_detector == "auto":
        resolved = resolve_detectors(landmark_detector)[0]
        quick["face_detector"] = QUICK_FACE_DETECTORS.get(resolved, "auto")
        empty["face_detector"] = QUICKEST_FACE_DETECTORS.get(resolved, "auto")
    # the detections wait on disk, a track's last CHUNK_ROWS in memory (_Running)
    spill_dir = tempfile.TemporaryDirectory(prefix="morphable-track-")
    spill = Path(spill_dir.name)
    try:
        running, ended, detected, times = [], [], [], []
        shot, last_detect, last_quick, next_id = -1, -10 ** 9, -10 ** 9, 0
        frames = iter_frames(path)
        if progress:
            from tqdm import tqdm

            # disable=None: a bar on a terminal only, so that a failure stays one line in a log
            frames = tqdm(frames, total=info.n_frames, unit="frame", desc=str(path), leave=False, disable=None)
        for frame in frames:
            i, image = frame.index, frame.image
            full = i in starts or shot < 0
            if full:
                shot = starts.get(i, max(shot, 0))
                ended += running
                running = []
            # each running track's face in its carried box (the face score judged here, to report it)
            found = detect_in_boxes(image, [t.box for t in running], min_score=None, **detectors) if running else []
            kept, lost = [], []
            for t, det in zip(running, found):
                if det is None or (det.score is not None and det.score < FACE_PROBABILITY):
                    t.end = (i, None if det is None else det.score)
                    lost.append(t)
                    continue
                t.add(i, det)
                kept.append(t)
            running = []
            for t in kept:           # two tracks that have drifted onto one face: the older one stays
                if running and float(iou(np.array([r.box for r in running]), t.box).max()) >= MATCH_IOU:
                    t.drop_last()
                    ended.append(t)
                else:
                    running.append(t)
            full = full or i - last_detect >= redetect
            searched = full or bool(lost) or i - last_quick >= quick_every
            ran = searched or not running
            detected.append(ran)
            times.append(frame.time_s)
            if ran:
                last_detect = i if full else last_detect
                last_quick = i if searched else last_quick
                chosen = detectors if full else quick if searched else empty
                faces = detect_all(image, **chosen, skip=[t.box for t in running])
                pairs = dict((f, t) for t, f in associate([t.box for t in lost], [face_box(d) for d in faces]))
                for k, det in enumerate(faces):
                    if k in pairs:              # the face its track lost in the carried box, found
                        t = lost[pairs[k]]
                        t.end = None
                    else:
                        t = _Running(next_id, shot, spill)
                        next_id += 1
                    t.add(i, det)
                    running.append(t)
                lost = [t for k, t in enumerate(lost) if k not in pairs.values()]
            ended += lost
            due = [t for t in running if i - t.last_descriptor >= every and len(t.descriptors) < MAX_DESCRIPTORS]
            if due:
                for t, d in zip(due, face_descriptors(image, [t.ibug68 for t in due])):
                    t.descriptors.append(d)
                    t.last_descriptor = i
        ended += running
        ended = [t for t in ended if t.frames]
        if not ended:
            raise InputError(f"{path}: no face found in any of its {len(detected)} frames")
        ended.sort(key=lambda t: t.id)
        person = join_tracks([np.array(t.descriptors).reshape(-1, 128) for t in ended],
                             [np.array(t.frames) for t in ended], descriptor_threshold)
        threshold = SAME_PERSON_DISTANCE if descriptor_threshold is None else float(descriptor_threshold)
        people, tracks = [], []
        times = np.array(times, dtype=np.float64)
        for p in range(int(person.max()) + 1):
            mine = [t for t, q in zip(ended, person) if q == p]
            result, status = _fit_person(model, mine, len(detected), times, fps, (info.width, info.height),
                                         int(identity_frames), smoothing_hz)
            result.detected = np.array(detected, dtype=bool)
            people.append(result)
            for t in mine:
                tracks.append(TrackInfo(id=t.id, person=p, shot=t.shot, frames=np.array(t.frames, np.int64),
                                        status=status[t.id], score=np.array(t.scores),
                                        box=np.array(t.boxes, dtype=np.float64).reshape(-1, 4),
                                        descriptors=np.array(t.descriptors, np.float32).reshape(-1, 128),
                                        lost=t.end))
        tracks.sort(key=lambda t: t.id)
        return FootageResult(shots=shots, tracks=tracks, people=people, detected=np.array(detected, dtype=bool),
                             fps=float(fps), image_size=(info.width, info.height), descriptor_threshold=threshold)
    finally:
        spill_dir.cleanup()


def _fit_person(model, tracks, n_frames: int, times, fps: float, size, identity_frames: int,
                smoothing_hz: float):
    """One person's :class:`~morphable.tracking.TrackResult` over all ``n_frames`` frames and
    ``{track id: per-frame status}``: their identity from ``identity_frames`` of their rows
    (each fitted alone, identities averaged), then every row's pose and expression with it held,
    smoothed along each track."""
    from ..camera import Camera, euler_to_matrix
    from ..fitting import fit_landmarks
    from ..fitting.noise import effective_std
    from ..fitting.options import detection_settings
    from ..fitting.result import FitResult
    from ..pipeline.fit import one_landmark_set
    from .single import TrackResult, fit_frames, fixed_identity_model, smooth_trajectories

    rows = [(t, k) for t in tracks for k in range(len(t.frames))]
    pick = np.unique(np.round(np.linspace(0, len(rows) - 1, min(identity_frames, len(rows)))).astype(int))
    dets = [rows[j][0].detection(rows[j][1]) for j in pick]
    pts = one_landmark_set([d.points for d in dets])
    res = fit_landmarks(model, pts, np.tile(np.asarray(size, np.float64), (len(dets), 1)),
                        shared_identity=False, **detection_settings(dets, pts.shape[1]))
    alpha = res.identity
    fixed = fixed_identity_model(model, alpha)
    F, E = n_frames, model.n_expression
    euler, trans = np.full((F, 3), np.nan), np.full((F, 3), np.nan)
    scale, expr, rmse = np.full(F, np.nan), np.full((F, E), np.nan), np.full(F, np.nan)
    sigma, tracked = np.full(F, np.nan), np.zeros(F, bool)
    L = max(len(t.detection(0).points) for t in tracks)
    detector = np.full((F, L, 2), np.nan, np.float32)
    status = {}
    for t in tracks:
        status[t.id] = []
        for a in range(0, len(t.frames), 64):           # batches of rows fitted at once
            dets = [t.detection(k) for k in range(a, min(a + 64, len(t.frames)))]
            for k, (det, fit) in enumerate(zip(dets, fit_frames(fixed, dets, size))):
                f = t.frames[a + k]
                status[t.id].append(STATUSES[0] if fit is not None else STATUSES[1])
                if fit is None:
                    continue
                cam, e, r = fit
                tracked[f] = True
                euler[f], trans[f], scale[f], expr[f], rmse[f] = cam.euler_deg, cam.translation, cam.scale, e, r
                if len(det.points) == L:
                    detector[f] = det.points
                if det.sigma_px is not None:
                    sigma[f] = float(effective_std(det.sigma_px[None] ** 2, np.ones((1, len(det.sigma_px)), bool))[0])
    raw_euler, raw_expr = euler.copy(), expr.copy()
    # the prior along each track: a cut or a change of track breaks the runs
    smooth = np.c_[euler, trans, np.log(scale), expr]
    for t in tracks:
        f = np.asarray(t.frames)
        smooth[f] = smooth_trajectories(smooth[f], tracked[f], fps, smoothing_hz)
    euler, trans, scale, expr = smooth[:, :3], smooth[:, 3:6], np.exp(smooth[:, 6]), smooth[:, 7:]
    cams = [Camera(kind="affine", rotation=euler_to_matrix(*euler[i]), translation=trans[i], scale=scale[i],
                   image_size=tuple(size)) for i in np.flatnonzero(tracked)]
    lm68 = np.full((F, 68, 2), np.nan)
    projected = None
    if cams:
        k = len(cams)
        projected = FitResult(model=fixed, identity=np.zeros(0), frame_identity=np.zeros((k, 0)),
                              expression=expr[tracked], cameras=cams, landmark_rmse_px=np.zeros(k),
                              landmarks=np.zeros((k, 0, 2)), fitted_landmarks=np.zeros((k, 0, 2)),
                              landmark_vertices=np.zeros((k, 0), dtype=np.int64))
        lm68[tracked] = projected.landmarks_68_px()
    result = TrackResult(identity=alpha, time_s=times, tracked=tracked, detected=np.zeros(F, bool),
                         euler_deg=euler, translation=trans, scale=scale, expression=expr,
                         landmarks_68_px=lm68, detector_px=detector, detector_std_px=sigma,
                         raw_euler_deg=raw_euler, raw_expression=raw_expr, landmark_rmse_px=rmse,
                         fps=float(fps), image_size=tuple(size), fit=projected)
    return result, status
