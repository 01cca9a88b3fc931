"""Landmark detectors from plugins: the entry-point group ``morphable.landmark_detectors``.

A plugin registers ``name = package.module:Class`` in that group (the neural plugin:
``network = neural.landmarks.detector:NetworkDetector``). Nothing is imported until a
detector is asked for by name (or ``"auto"`` asks whether it can run), so ``morphable`` never
imports torch itself.

A detector class provides::

    FACE_DETECTORS : tuple of str            # the face detectors it takes, "auto" first
    unavailable() -> str | None              # classmethod: why it cannot run here (None: it can)
    Class()                                  # constructed once per process, without arguments
    detect(image, *, box=None, face_detector="auto", name="image") -> Detection
        image : (H, W, 3) uint8 RGB, upright (morphable.detection.images.as_image)
        box   : (4,) float64 (left, top, right, bottom) px, checked, or None
        name  : the photo's name for messages (FitError when no face is found)
    detect_faces(image, face_detector="auto") -> (F, 4) float64 px, largest first

:class:`~morphable.detection.result.Detection` holds the points (the face mesh's 478 rows in
mediapipe's order, or 68 iBUG rows), a σ each in px where the detector predicts one, and the
68 iBUG points.
"""
from __future__ import annotations

import functools
from importlib import metadata

from ..errors import InputError

__all__ = ["GROUP", "entry_points", "installed", "detector_class", "detector"]

GROUP = "morphable.landmark_detectors"


_found = {}


def entry_points() -> dict:
    """{name: importlib.metadata.EntryPoint} of the installed landmark-detector plugins
    (nothing imported), read once per process: importlib.metadata reads every installed
    distribution's metadata for it (60 ms here, and a fit asks up to five times). A replaced
    ``metadata.entry_points`` (a test's) is read anew."""
    reader = metadata.entry_points
    if reader not in _found:
        _found.clear()
        _found[reader] = {ep.name: ep for ep in reader(group=GROUP)}
    return dict(_found[reader])


def installed() -> list[str]:
    """Names of the installed landmark-detector plugins, e.g. ``["network"]``."""
    return sorted(entry_points())


def detector_class(name: str):
    """The plugin class registered as ``name`` (imports its module); InputError when it is not
    installed or cannot be imported."""
    eps = entry_points()
    if name not in eps:
        hint = (" (the neural plugin's: pip install -e '.[neural]', which registers it)"
                if name == "network" else "")
        raise InputError(f"landmark detector {name!r} is not installed{hint}; installed plugins: "
                         f"{', '.join(sorted(eps)) or 'none'}")
    try:
        return eps[name].load()
    except (ImportError, AttributeError) as e:
        raise InputError(f"landmark detector {name!r} ({eps[name].value}) cannot be loaded ({e})") from None


@functools.lru_cache(maxsize=None)
def detector(name: str):
    """The one instance of plugin ``name`` in this process (its weights load once)."""
    return detector_class(name)()
