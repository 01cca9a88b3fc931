"""Videos in and out: frames decoded one at a time, upright, with their timestamps.

Reading goes through PyAV (the ``video`` extra, ``pip install -e '.[video]'``; its wheel
bundles FFmpeg), imported only when a video is opened, so ``import morphable`` stays light.
Why PyAV and not the FFmpeg inside the OpenCV wheel: PyAV gives every frame's presentation
time (variable frame rates), the display rotation phones write into the container, and
decoding errors as exceptions; ``cv2.VideoCapture`` answers a cut-off file by returning no
more frames, indistinguishable from the end. docs/video.md says what it costs to install.

- :func:`probe` — size (upright), frame count, frame rate, duration and rotation, from the
  container's header (counting packets, without decoding, where the header has no count);
- :func:`iter_frames` — :class:`VideoFrame` objects, one at a time: memory does not grow with
  the video's length (only the frames asked for are converted to arrays);
- :func:`sample_indices`, :func:`sample_frames` — N frames spread uniformly (the Florence
  protocol's 5);
- :func:`write_video` — frames to an H.264 ``.mp4`` (tests, overlays).

Every problem with a file is an :class:`~morphable.errors.InputError` whose message starts
with the file's path: not a video, cut off, no video stream, no frames.

>>> import tempfile
>>> from morphable.video import sample_frames, write_video
>>> frames = [np.full((48, 64, 3), 8 * i, np.uint8) for i in range(30)]    # 1 s at 30 frames/s
>>> clip = write_video(f"{tempfile.mkdtemp()}/clip.mp4", frames, fps=30)
>>> [(f.index, round(f.time_s, 3)) for f in sample_frames(clip, 5)]
[(0, 0.0), (7, 0.233), (14, 0.467), (22, 0.733), (29, 0.967)]
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = ["VIDEO_SUFFIXES", "VideoFrame", "VideoInfo", "is_video", "probe", "iter_frames",
           "sample_indices", "sample_frames", "write_video", "import_av"]

VIDEO_SUFFIXES = frozenset({".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg",
                            ".wmv", ".flv", ".3gp", ".ts"})
"""File suffixes taken for videos (lower case); anything else is read as an image."""


@dataclass(frozen=True, eq=False)
class VideoFrame:
    """One decoded frame of a video.

    Attributes
    ----------
    source : str, the video's path
    index : int, 0-based position in presentation order
    time_s : float, presentation time in seconds from the video's first frame
    image : (H, W, 3) uint8 RGB, upright (the container's rotation applied)
    """

    source: str
    index: int
    time_s: float
    image: np.ndarray

    @property
    def label(self) -> str:
        """``"clip.mp4#14"``: how reports name the frame."""
        return f"{self.source}#{self.index}"

    @property
    def size(self) -> tuple[int, int]:
        """(W, H) pixels."""
        return int(self.image.shape[1]), int(self.image.shape[0])


@dataclass(frozen=True)
class VideoInfo:
    """What a video's header says.

    Attributes
    ----------
    path : str
    width, height : int, pixels of the upright frames (rotation applied)
    n_frames : int, frames in the video stream
    fps : float, average frame rate, frames per second (variable-rate videos: their mean)
    duration_s : float, seconds
    rotation_deg : int, counter-clockwise rotation applied to the decoded frames (0, 90, 180, 270)
    codec : str
    """

    path: str
    width: int
    height: int
    n_frames: int
    fps: float
    duration_s: float
    rotation_deg: int
    codec: str


def import_av():
    """``import av`` (PyAV), or an InputError saying how to install it."""
    try:
        import av
    except ImportError as e:
        raise InputError(f"reading videos needs the video extra: pip install -e '.[video]' ({e})") from None
    return av


def is_video(path) -> bool:
    """Whether ``path`` is taken for a video (by its suffix, :data:`VIDEO_SUFFIXES`).

    >>> is_video("clip.MP4"), is_video("photo.png")
    (True, False)
    """
    return isinstance(path, (str, Path)) and Path(path).suffix.lower() in VIDEO_SUFFIXES


def _open(path: Path):
    """(container, video stream) of ``path``; InputError naming the file when it cannot be."""
    av = import_av()
    if not path.is_file():
        raise InputError(f"{path}: no such video")
    try:
        container = av.open(str(path))
    except av.error.EOFError:
        # what FFmpeg says of a Matroska file whose header is all there is
        raise InputError(f"{path}: no frames") from None
    except (av.error.FFmpegError, OSError, UnicodeDecodeError):
        # FFmpeg says "Invalid data" both for a file that is no video and for an mp4 cut
        # before its index: one message for both
        raise InputError(f"{path}: cannot read video (not a video, or cut off)") from None
    if not container.streams.video:
        container.close()
        # an mp4 written without a single frame keeps no video stream either
        raise InputError(f"{path}: no video stream (no frames)")
    stream = container.streams.video[0]
    stream.thread_type = "AUTO"   # frame threads: a few frames in flight, not the whole video
    return container, stream


def _rotation(display_matrix_deg) -> int:
    """A display rotation in degrees (any sign, ~multiples of 90) -> 0, 90, 180 or 270."""
    return int(round((display_matrix_deg or 0) / 90.0)) % 4 * 90


def _count_packets(container, stream) -> int:
    """Frames of a stream whose header has no count: its packets, demuxed without decoding."""
    n = sum(1 for p in container.demux(stream) if p.size)
    container.seek(0)
    return n


def probe(path) -> VideoInfo:
    """A video's :class:`VideoInfo`, from its header and its first frame (the display rotation
    is the frame's); where the header has no frame count, its packets are counted without
    decoding them."""
    path = Path(path)
    container, stream = _open(path)
    av = import_av()
    try:
        n = int(stream.frames or 0) or _count_packets(container, stream)
        rate = stream.average_rate or stream.guessed_rate or stream.base_rate
        duration = (float(stream.duration * stream.time_base) if stream.duration and stream.time_base
                     else float(container.duration or 0) / 1e6)
        fps = float(rate) if rate else (n / duration if duration > 0 else 0.0)
        first = next(iter(container.decode(stream)), None)
        if first is None:
            raise InputError(f"{path}: no frames")
        rotation = _rotation(first.rotation)
        w, h = (first.height, first.width) if rotation % 180 else (first.width, first.height)
        codec = stream.codec_context.name
    except av.error.FFmpegError as e:
        raise InputError(f"{path}: cannot decode its first frame (cut off or corrupt: "
                         f"{type(e).__name__})") from None
    finally:
        container.close()
    return VideoInfo(str(path), int(w), int(h), n, fps, duration, rotation, codec)


def _upright(frame, rotation: int) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a decoded frame, turned ``rotation`` degrees counter-clockwise."""
    image = frame.to_ndarray(format="rgb24")
    if rotation:
        image = np.ascontiguousarray(np.rot90(image, k=rotation // 90))
    return image


def iter_frames(path, indices=None):
    """Decode a video frame by frame.

    Parameters
    ----------
    path : str or Path
    indices : iterable of int, optional; only these frames (0-based, presentation order) are
        yielded, the others decoded and dropped without conversion. None: every frame.

    Yields
    ------
    :class:`VideoFrame` — one at a time: memory stays that of a few frames however long the
    video is.

    Raises
    ------
    InputError naming the file: not a video, no video stream, a frame that cannot be decoded,
    a file cut off before the frames its header counts (or before a requested index), no
    frames.
    """
    av = import_av()
    path = Path(path)
    wanted = None if indices is None else sorted({int(i) for i in indices})
    if wanted is not None and wanted and wanted[0] < 0:
        raise InputError(f"{path}: frame index {wanted[0]} < 0")
    container, stream = _open(path)
    declared = int(stream.frames or 0)
    n = 0
    try:
        start = None
        fps = float(stream.average_rate or stream.guessed_rate or 0) or None
        frames = container.decode(stream)
        k = 0
        while True:
            if wanted is not None and k == len(wanted):
                return
            try:
                frame = next(frames)
            except StopIteration:
                break
            except (av.error.FFmpegError, OSError) as e:
                raise InputError(f"{path}: cannot decode frame {n} (cut off or corrupt: "
                                 f"{type(e).__name__})") from None
            if wanted is None or wanted[k] == n:
                t = frame.time
                if t is None:
                    t = n / fps if fps else float("nan")
                start = t if start is None else start
                yield VideoFrame(str(path), n, float(t - start), _upright(frame, _rotation(frame.rotation)))
                k += 1
            elif start is None and frame.time is not None:
                start = frame.time
            n += 1
    finally:
        container.close()
    if n == 0:
        raise InputError(f"{path}: no frames")
    if declared and n < declared:
        raise InputError(f"{path}: cut off: {n} of the {declared} frames its header counts decoded")
    if wanted is not None and k < len(wanted):
        raise InputError(f"{path}: frame {wanted[k]} asked for, the video has {n}")


def sample_indices(n_frames: int, k: int) -> np.ndarray:
    """``k`` frame indices spread uniformly over ``n_frames`` (first and last included) ->
    (k,) int64.

    >>> sample_indices(30, 5)
    array([ 0,  7, 14, 22, 29])
    """
    if not 1 <= k <= n_frames:
        raise InputError(f"cannot sample {k} frames from a {n_frames}-frame video")
    return np.round(np.linspace(0, n_frames - 1, k)).astype(np.int64)


def sample_frames(path, k: int = 5) -> list:
    """``k`` frames spread uniformly over a video (all of them when it has fewer) -> list of
    :class:`VideoFrame`, in order. The video is decoded once, streamed."""
    if int(k) < 1:
        raise InputError(f"{path}: cannot sample {k} frames")
    n = probe(path).n_frames
    return list(iter_frames(path, sample_indices(n, min(int(k), n))))


def write_video(path, frames, *, fps: float = 30.0, times_s=None, rotation_deg: int = 0,
                crf: int = 18) -> Path:
    """Write frames to a video (H.264 in ``.mp4``/``.mkv``/``.mov``), atomically.

    Parameters
    ----------
    path : output path
    frames : iterable of (H, W, 3) uint8 RGB arrays, all the same size; H and W are cut to even
        numbers (H.264's 4:2:0 needs them)
    fps : frames per second (when ``times_s`` is None)
    times_s : (F,) seconds, optional: each frame's presentation time (a variable frame rate)
    rotation_deg : display rotation written into the container, degrees counter-clockwise
        (a reader turns the frames by it; :func:`iter_frames` does)
    crf : H.264 quality (0 lossless ... 51 worst)

    Returns the path written. Nothing is left behind when a frame is bad.
    """
    import fractions

    from .io.atomic import atomic_path

    av = import_av()
    path = Path(path)
    times = None if times_s is None else np.asarray(times_s, dtype=np.float64)
    with atomic_path(path) as tmp:
        out = av.open(str(tmp), "w")
        try:
            stream = None
            for i, image in enumerate(frames):
                image = np.asarray(image)
                if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
                    raise InputError(f"{path}: frame {i}: expected (H, W, 3) uint8, got "
                                     f"{image.shape} {image.dtype}")
                h, w = image.shape[0] // 2 * 2, image.shape[1] // 2 * 2
                if stream is None:
                    stream = out.add_stream("libx264", rate=fractions.Fraction(fps).limit_denominator(1001),
                                            options={"crf": str(int(crf)), "preset": "veryfast"})
                    stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
                    if times is not None:
                        stream.time_base = fractions.Fraction(1, 90000)
                    if rotation_deg % 360:
                        stream.set_display_rotation(int(rotation_deg))
                elif (w, h) != (stream.width, stream.height):
                    raise InputError(f"{path}: frame {i} is {image.shape[1]}x{image.shape[0]}, the "
                                     f"first was {stream.width}x{stream.height}")
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image[:h, :w]), format="rgb24")
                if times is not None:
                    frame.pts = int(round(times[i] * 90000))
                    frame.time_base = stream.time_base
                for packet in stream.encode(frame):
                    out.mux(packet)
            if stream is None:
                raise InputError(f"{path}: no frames to write")
            for packet in stream.encode():
                out.mux(packet)
        finally:
            out.close()
    return path

