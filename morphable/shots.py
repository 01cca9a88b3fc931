"""Shot boundaries of a video: hard cuts and fades through black, so that each shot is tracked
on its own (:mod:`morphable.tracking`).

PySceneDetect's detectors (the ``scenedetect`` package, the ``video`` extra; installed without
its declared ``opencv-python``, which would replace the headless cv2 the face mesh uses:
Makefile ``install``) run on the frames as they are decoded, reduced to about
:data:`ANALYSIS_WIDTH` px wide:

- ``ContentDetector``: a cut where the frame-to-frame change of hue, saturation and
  brightness (mean absolute difference, 0-255) exceeds :data:`CUT_THRESHOLD`;
- ``ThresholdDetector``: a fade out to black and back in (mean brightness below
  :data:`FADE_THRESHOLD`), cut at the middle of the dark stretch. The content detector's cuts
  into and out of such a stretch are the same boundary and are dropped for it.

Frame indices are 0-based; a shot is ``[start, end)``.

>>> import tempfile
>>> from morphable.video import write_video
>>> a, b = np.full((48, 64, 3), 40, np.uint8), np.zeros((48, 64, 3), np.uint8)
>>> b[:, :32] = 250
>>> clip = write_video(f"{tempfile.mkdtemp()}/cut.mp4", [a] * 10 + [b] * 10)
>>> find_shots(clip)
[(0, 10), (10, 20)]
"""
from __future__ import annotations

import numpy as np

from .errors import InputError

__all__ = ["CUT_THRESHOLD", "FADE_THRESHOLD", "MIN_SHOT_FRAMES", "ANALYSIS_WIDTH", "ShotDetector",
           "find_shots", "shots_from_cuts"]

CUT_THRESHOLD = 27.0
"""ContentDetector's threshold (its default): mean change of the HSV channels, 0-255 scale."""
FADE_THRESHOLD = 12.0
"""ThresholdDetector's: a frame darker than this mean brightness (0-255) is faded out."""
MIN_SHOT_FRAMES = 3
"""No shot shorter than this many frames: a flash or a fast pan is not a cut."""
ANALYSIS_WIDTH = 320
"""Frames are reduced by an integer factor to about this width for the detectors (a 4K frame
costs what a 320-px one does; cuts are large changes)."""


def _scenedetect():
    try:
        import scenedetect
        from scenedetect.detectors import ContentDetector, ThresholdDetector
    except ImportError as e:
        raise InputError("shot detection needs PySceneDetect: pip install --no-deps scenedetect "
                         f"click platformdirs (the video extra; docs/video.md) ({e})") from None
    return scenedetect.FrameTimecode, ContentDetector, ThresholdDetector


class ShotDetector:
    """Cuts found frame by frame (the frames streamed, none held).

    Parameters
    ----------
    fps : frames per second of the video (the detectors' timecodes)
    cut_threshold, fade_threshold : see :data:`CUT_THRESHOLD`, :data:`FADE_THRESHOLD`
    min_shot_frames : see :data:`MIN_SHOT_FRAMES`

    Call :meth:`push` with each frame in order, then :meth:`cuts`.
    """

    def __init__(self, fps: float = 30.0, *, cut_threshold: float = CUT_THRESHOLD,
                 fade_threshold: float = FADE_THRESHOLD, min_shot_frames: int = MIN_SHOT_FRAMES):
        self._timecode, content, threshold = _scenedetect()
        self.fps = float(fps) if fps and fps > 0 else 30.0
        self.fade_threshold = float(fade_threshold)
        self._content = content(threshold=float(cut_threshold), min_scene_len=int(min_shot_frames))
        self._fades = threshold(threshold=float(fade_threshold), min_scene_len=int(min_shot_frames))
        self._cuts, self._fade_cuts, self._dark = [], [], []
        self.n_frames = 0

    def push(self, image: np.ndarray) -> None:
        """The next frame, (H, W, 3) uint8 RGB."""
        k = max(1, image.shape[1] // ANALYSIS_WIDTH)
        small = np.ascontiguousarray(image[::k, ::k, ::-1])        # the detectors take BGR
        tc = self._timecode(self.n_frames, fps=self.fps)
        self._cuts += [int(c.frame_num) for c in self._content.process_frame(tc, small)]
        self._fade_cuts += [int(c.frame_num) for c in self._fades.process_frame(tc, small)]
        self._dark.append(float(small.mean()) < self.fade_threshold)
        self.n_frames += 1

    def cuts(self) -> list:
        """Sorted frame indices at which a new shot starts (0 not among them)."""
        dark = np.asarray(self._dark, dtype=bool)
        # a content cut beside a dark frame is a fade's edge: the fade's own cut stands for it
        away_from_dark = [c for c in self._cuts if not (dark[c] or (c > 0 and dark[c - 1]))]
        return sorted({c for c in away_from_dark + self._fade_cuts if 0 < c < self.n_frames})


def shots_from_cuts(cuts, n_frames: int) -> list:
    """Cut indices -> the shots ``[(start, end), ...]`` covering ``n_frames`` frames.

    >>> shots_from_cuts([10, 25], 30)
    [(0, 10), (10, 25), (25, 30)]
    """
    edges = [0, *sorted(int(c) for c in cuts if 0 < c < n_frames), int(n_frames)]
    return [(a, b) for a, b in zip(edges, edges[1:]) if b > a]


def find_shots(path, **options) -> list:
    """The shots of a video file -> ``[(start, end), ...]`` frame indices, ``end`` exclusive;
    ``options``: :class:`ShotDetector`'s keywords. The frames are decoded and dropped one at a
    time (:func:`morphable.video.iter_frames`)."""
    from .video import iter_frames, probe

    detector = ShotDetector(probe(path).fps, **options)
    for frame in iter_frames(path):
        detector.push(frame.image)
    return shots_from_cuts(detector.cuts(), detector.n_frames)
