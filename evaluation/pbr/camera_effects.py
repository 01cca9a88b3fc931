"""What a real camera adds to a rendered face: a photo behind it, defocus, noise, JPEG.

Every function takes its randomness from a numpy Generator, so that one seed per frame
decides the frame (:func:`evaluation.pbr.renderer.render_frames` seeds one per frame).
"""
from __future__ import annotations

import io
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from morphable.errors import InputError

__all__ = ["Sensor", "SENSORS", "BACKGROUNDS", "background_photos", "background_crop",
           "defocus", "develop"]

BACKGROUNDS = Path(__file__).resolve().parents[3] / "shared" / "data" / "images" / "300w"
"""Default photos for backgrounds: 300-W (AFW, HELEN test set), research use only."""


@dataclass(frozen=True)
class Sensor:
    """How one condition's camera develops a frame.

    Attributes
    ----------
    defocus_px : radius of the lens blur (a disc) on the face, pixels
    background_defocus_px : radius of the lens blur on the background (farther away), pixels
    read_noise : standard deviation of the signal-independent noise (intensity in [0, 1])
    shot_noise : photon noise: standard deviation ``sqrt(shot_noise * intensity)``
    jpeg_quality : JPEG quality (PIL, 1-95)
    """

    defocus_px: float
    background_defocus_px: float
    read_noise: float
    shot_noise: float
    jpeg_quality: int


SENSORS = {
    "cooperative": Sensor(0.6, 3.0, 0.006, 0.0008, 92),
    "indoor": Sensor(1.3, 2.5, 0.012, 0.002, 80),
    "outdoor": Sensor(0.8, 1.5, 0.015, 0.003, 70),
}
"""The camera of each Florence condition (:data:`evaluation.videos.CONDITIONS`)."""


@lru_cache(maxsize=4)
def background_photos(folder=None) -> tuple:
    """Photos usable as backgrounds -> tuple of (path, (K, 4) face boxes x0 y0 x1 y1 px).

    Every ``.jpg``/``.png`` under ``folder`` (default :data:`BACKGROUNDS`) with an iBUG
    ``.pts`` beside it; the boxes are the annotated faces of that photo (an AFW photo with
    several faces, ``<id>_<k>.jpg``, gathers them all), which crops avoid. Sorted by path.
    """
    from morphable.io.landmark_files import read_pts

    folder = Path(folder) if folder is not None else BACKGROUNDS
    if not folder.is_dir():
        raise InputError(f"{folder}: no such folder of background photos")
    boxes = {}
    for pts in sorted(folder.rglob("*.pts")):
        photo = next((pts.with_suffix(s) for s in (".jpg", ".png") if pts.with_suffix(s).is_file()), None)
        if photo is None:
            continue
        p = read_pts(pts)
        group = pts.parent / pts.stem.rsplit("_", 1)[0] if "afw" in pts.parts else photo
        boxes.setdefault(group, []).append((photo, [*np.nanmin(p, 0), *np.nanmax(p, 0)]))
    out = [(faces[0][0], np.array([b for _, b in faces])) for faces in boxes.values()]
    if not out:
        raise InputError(f"{folder}: no photos with .pts landmarks for backgrounds")
    return tuple(out)


def background_crop(size, rng, photos=None, margin: float = 0.3) -> np.ndarray:
    """A square crop of a real photo, away from its faces, resized -> (H, W, 3) float in [0, 1].

    Parameters
    ----------
    size : (W, H) pixels of the output
    rng : numpy Generator: picks the photo and the crop
    photos : :func:`background_photos` (default: those of :data:`BACKGROUNDS`)
    margin : the face boxes are grown by this fraction of their size before they are avoided

    The crop is the largest square (at least a third of the photo's shorter side) found at a
    random place that overlaps no grown face box; a photo without such a place is skipped.
    """
    from PIL import Image

    photos = photos if photos is not None else background_photos()
    W, H = size
    for _ in range(50):
        path, boxes = photos[rng.integers(len(photos))]
        img = Image.open(path).convert("RGB")
        pw, ph = img.size
        grow = margin * np.c_[boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]]
        b = np.c_[boxes[:, :2] - grow, boxes[:, 2:] + grow]
        for side in (min(pw, ph) // 2, min(pw, ph) // 3):
            x = rng.integers(0, pw - side + 1, 20)
            y = rng.integers(0, ph - side + 1, 20)
            free = ~((x[:, None] < b[None, :, 2]) & (x[:, None] + side > b[None, :, 0])
                     & (y[:, None] < b[None, :, 3]) & (y[:, None] + side > b[None, :, 1])).any(1)
            if free.any():
                i = np.flatnonzero(free)[0]
                crop = img.crop((int(x[i]), int(y[i]), int(x[i]) + side, int(y[i]) + side))
                return np.asarray(crop.resize((W, H), Image.BICUBIC), dtype=np.float64) / 255.0
    raise InputError("no background photo has a face-free region large enough")


def defocus(image, radius_px: float) -> np.ndarray:
    """Lens blur: ``image`` (H, W, C) convolved with a uniform disc of ``radius_px`` pixels
    (anti-aliased edge); unchanged below a quarter pixel."""
    from scipy.ndimage import convolve

    if radius_px < 0.25:
        return np.asarray(image, dtype=np.float64)
    r = int(np.ceil(radius_px + 1))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    k = np.clip(radius_px + 0.5 - np.hypot(xx, yy), 0.0, 1.0)
    k /= k.sum()
    return convolve(np.asarray(image, dtype=np.float64), k[..., None], mode="nearest")


def develop(rgba, background, sensor: Sensor, rng) -> np.ndarray:
    """A rendered face over a background, through the condition's camera -> (H, W, 3) uint8.

    Parameters
    ----------
    rgba : (H, W, 4) float in [0, 1], the render with its coverage in alpha
    background : (H, W, 3) float in [0, 1]
    sensor : :class:`Sensor`
    rng : numpy Generator (the noise)

    The background is defocused more than the face, the composite once more (the face's
    depth of field), then photon and read noise are added and the frame is JPEG-encoded and
    decoded.
    """
    from PIL import Image

    rgba = np.asarray(rgba, dtype=np.float64)
    alpha = rgba[..., 3:]
    img = rgba[..., :3] * alpha + defocus(background, sensor.background_defocus_px) * (1 - alpha)
    img = np.clip(defocus(img, sensor.defocus_px), 0.0, 1.0)
    sigma = np.sqrt(sensor.shot_noise * img + sensor.read_noise ** 2)
    img = np.clip(img + sigma * rng.standard_normal(img.shape), 0.0, 1.0)
    buf = io.BytesIO()
    Image.fromarray(np.round(img * 255).astype(np.uint8)).save(buf, "JPEG", quality=sensor.jpeg_quality)
    return np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"))
