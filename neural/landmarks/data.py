"""Training batches of the landmark network: the packs in memory as one layout, and augmented
face crops drawn from them.

:class:`LandmarkSource` holds one pack's faces as images plus labels on the 546 rows of
:mod:`neural.faces.points` in image px: a synthetic pack (:mod:`neural.faces.build_synthetic`;
every defined row labelled, hidden points included: exact 3D-convention labels) or a
``landmarks-1`` pack (:mod:`neural.faces.packs`: annotated or profiled real photos; the
rows each annotation defines). 2D-convention faces (300-W) and test-split faces are never
drawn for training.

:func:`draw_batch` crops them as a detector's box would (jittered scale and centre, in-plane
rotation, mirror with the rows swapped, :data:`neural.landmarks.network` crop geometry), adds
crops away from the face (score 0), and jitters colour, seeded by (seed, step): a resumed run
draws the same batches. The per-face draws (boxes, angles, colour factors) and the label
geometry are small and made on the CPU; the crops are cut where the pack's images are
(:meth:`LandmarkSource.to`: on a GPU, decoded once and kept there), with the pixel noise
drawn there too, so that a batch moves only labels and a few numbers to the device, without
making the host wait.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from morphable.errors import InputError

from .cropping import crop_theta, image_to_crop
from .network import crop_images
from ..training import step_generator, to_device
from ..faces.points import box_side, face_box, mirror_index

__all__ = ["LandmarkSource", "load_source", "draw_batch", "validation_batch", "negative_crops",
           "NEGATIVE_KINDS", "SPLITS"]

SPLITS = {"train": 0, "validation": 1, "test": 2}
NEGATIVE_KINDS = ("away", "part", "texture")
"""The crops without a whole face that :func:`negative_crops` makes."""


class LandmarkSource:
    """One pack's faces in memory.

    Attributes: ``kind`` ("synthetic", "annotated", "profiled"), ``path``, ``images``
    (N, H, W, 3) uint8 tensor, ``points`` (N, 546, 2) float32 image px (NaN unlabelled),
    ``weight`` (N, 546) float32 (1 labelled, 0 not), ``boxes`` (N, 4) float32 face boxes px,
    ``yaw`` (N,) degrees (NaN unknown)."""

    def __init__(self, kind, path, images, points, weight, boxes, yaw):
        self.kind, self.path = kind, Path(path)
        self.images = torch.as_tensor(images)
        self.points = torch.as_tensor(points, dtype=torch.float32)
        self.weight = torch.as_tensor(weight, dtype=torch.float32)
        self.boxes = torch.as_tensor(boxes, dtype=torch.float32)
        self.yaw = np.asarray(yaw, dtype=np.float32)

    def __len__(self) -> int:
        return len(self.images)

    def to(self, device) -> "LandmarkSource":
        """This source with its images (uint8) on ``device``; the labels stay on the CPU,
        where the crops' geometry is worked out."""
        return LandmarkSource(self.kind, self.path, self.images.to(device), self.points,
                              self.weight, self.boxes, self.yaw)

    def subset(self, index) -> "LandmarkSource":
        index = np.asarray(index)
        return LandmarkSource(self.kind, self.path, self.images[index], self.points[index],
                              self.weight[index], self.boxes[index], self.yaw[index])


def load_source(path, kind: str, split: str = "train") -> LandmarkSource:
    """A pack -> its faces of ``split`` ("train" or "validation").

    ``kind`` "synthetic": a :mod:`neural.faces.build_synthetic` folder (no split: all of it,
    whichever is asked; hold out a separate pack); "annotated" or "profiled": a
    ``landmarks-1`` folder or its compact ``.npz``. InputError naming the path when it is not
    such a pack."""
    import json

    from ..faces.packs import load_pack

    path = Path(path)
    manifest = path / "pack.json"
    if kind == "synthetic":
        return _synthetic(path)
    if kind not in ("annotated", "profiled"):
        raise InputError(f"{path}: pack kind must be synthetic, annotated or profiled, got {kind!r}")
    if manifest.is_file():
        try:
            fmt = json.loads(manifest.read_text()).get("settings", {}).get("format")
        except (OSError, ValueError):
            raise InputError(f"{manifest}: unreadable pack manifest") from None
        if fmt != "landmarks-1":
            raise InputError(f"{path}: not a landmarks-1 pack (format {fmt!r}); a synthetic "
                             "pack goes to --synthetic")

    if split not in SPLITS:
        raise InputError(f"{path}: split must be one of {', '.join(SPLITS)}, got {split!r}")
    d = load_pack(path, splits=(SPLITS[split],))
    keep = d["convention"] == 0            # 2D-convention jaws are not our points
    labelled = d["labelled"][keep]
    return LandmarkSource(kind, path, d["image"][keep],
                          np.where(labelled[..., None], d["points"][keep], np.nan),
                          labelled.astype(np.float32), d["box"][keep], d["yaw_deg"][keep])


def _synthetic(path: Path) -> LandmarkSource:
    from ..faces.build_synthetic import load_pack

    d = load_pack(path)
    points = np.concatenate([d["points478"], d["points68"]], axis=1).astype(np.float32)
    weight = np.isfinite(points).all(-1).astype(np.float32)
    boxes = face_box(d["points68"]).astype(np.float32)
    return LandmarkSource("synthetic", path, d["image"], points, weight, boxes, d["pose"][:, 0])


def _uniform(gen, n, lo, hi):
    return lo + (hi - lo) * torch.rand(n, generator=gen)


def _colour_jitter(x: torch.Tensor, gen) -> torch.Tensor:
    """x (B, 3, R, R) in [-1, 1] -> brightness, contrast, saturation, gamma, grey and noise
    jittered per image. The per-image factors come from ``gen`` (CPU); the pixel noise from
    ``gen`` too on the CPU, from a generator of x's device seeded by ``gen`` elsewhere."""
    B = len(x)

    def col(v):
        return to_device(v, x.device).reshape(B, -1, 1, 1)

    gamma = torch.exp(_uniform(gen, B, -0.35, 0.35))
    sat = _uniform(gen, B, 0.3, 1.5)
    sat = torch.where(torch.rand(B, generator=gen) < 0.1, torch.zeros_like(sat), sat)
    contrast, brightness = _uniform(gen, B, 0.6, 1.4), _uniform(gen, B, 0.6, 1.4)
    cast = torch.exp(0.1 * torch.randn(B, 3, generator=gen))
    noise = _uniform(gen, B, 0, 0.04)
    pixel_gen = gen if x.device.type == "cpu" else step_generator(
        int(torch.randint(2 ** 62, (1,), generator=gen)), x.device)
    y = ((x + 1) / 2).clamp_min(0) ** col(gamma)
    grey = y.mean(1, keepdim=True)
    y = grey + (y - grey) * col(sat)
    mean = y.mean((1, 2, 3), keepdim=True)
    y = mean + (y - mean) * col(contrast)
    y = y * col(brightness)
    y = y * col(cast)
    y = y + col(noise) * torch.randn(y.shape, generator=pixel_gen, device=x.device)
    return (y.clamp(0, 1) * 2 - 1)


def _crops(source: LandmarkSource, index, config, gen, negative, jitter: bool):
    """Crops of ``source`` faces ``index`` -> (x (b, 3, R, R), q (b, P, 2), w (b, P))."""
    R = config.resolution
    b = len(index)
    images = source.images
    img = images[to_device(index, images.device)].permute(0, 3, 1, 2).float() / 127.5 - 1
    H, W = img.shape[-2:]
    box = source.boxes[index].clone()
    c = (box[:, :2] + box[:, 2:]) / 2
    s = box_side(box)
    angle = flip = None
    if jitter:
        s = s * torch.exp(config.scale_jitter * torch.randn(b, generator=gen).clamp(-2.5, 2.5))
        c = c + config.shift_jitter * s[:, None] * torch.randn(b, 2, generator=gen).clamp(-2.5, 2.5)
        angle = math.radians(config.rotate_deg) * (2 * torch.rand(b, generator=gen) - 1)
        flip = (torch.rand(b, generator=gen) < 0.5) if config.flip else None
        # negatives: a box of about the face's size, at least 0.8 of a side away from it
        away = _uniform(gen, b, 0.8, 1.6) * s
        phi = _uniform(gen, b, 0, 2 * math.pi)
        shift = torch.stack([torch.cos(phi), torch.sin(phi)], -1) * away[:, None]
        c = torch.where(negative[:, None], c + shift, c)
        s = torch.where(negative, s * torch.exp(_uniform(gen, b, -0.5, 0.5)), s)
    boxes = torch.cat([c - s[:, None] / 2, c + s[:, None] / 2], 1)
    theta = crop_theta(boxes, (W, H), angle, flip)
    x = crop_images(img, to_device(torch.as_tensor(theta, dtype=torch.float32), images.device), R)
    q = torch.as_tensor(image_to_crop(np.nan_to_num(source.points[index].numpy()), theta, (W, H)),
                        dtype=torch.float32)
    w = source.weight[index].clone()
    if flip is not None:      # always: a no-op where nothing is mirrored, and no read of flip
        m = torch.as_tensor(mirror_index())
        q = torch.where(flip[:, None, None], q[:, m], q)
        w = torch.where(flip[:, None], w[:, m], w)
    w = torch.where(negative[:, None], torch.zeros_like(w), w)
    return x, q, w


def draw_batch(sources: dict, config, step: int) -> dict:
    """The batch of training step ``step``.

    sources : kind -> LandmarkSource (kinds without faces are skipped)
    config : :class:`neural.landmarks.network.LandmarkConfig`

    Returns dict of ``image`` (B, 3, R, R) in [-1, 1] on the sources' images' device,
    ``points`` (B, 546, 2) crop-normalised, ``weight`` (B, 546), ``face`` (B,) 1.0 face /
    0.0 negative (on that device too)."""
    gen = torch.Generator().manual_seed(int(np.random.SeedSequence([config.seed, step])
                                            .generate_state(1)[0]))
    mix = [(k, f) for k, f in config.mix if f > 0 and k in sources and len(sources[k])]
    if not mix:
        raise InputError("no training faces: give at least one pack of a kind in the mix "
                         f"({', '.join(k for k, _ in config.mix)})")
    total = sum(f for _, f in mix)
    counts = np.floor(np.array([f / total for _, f in mix]) * config.batch_size).astype(int)
    counts[0] += config.batch_size - counts.sum()
    xs, qs, ws, faces = [], [], [], []
    for (kind, _), n in zip(mix, counts):
        if n == 0:
            continue
        src = sources[kind]
        index = torch.randint(len(src), (int(n),), generator=gen)
        negative = torch.rand(int(n), generator=gen) < config.negatives
        x, q, w = _crops(src, index, config, gen, negative, jitter=True)
        xs.append(x), qs.append(q), ws.append(w), faces.append((~negative).float())
    x = _colour_jitter(torch.cat(xs), gen)
    return {"image": x, **{k: to_device(torch.cat(v), x.device) for k, v in
                           (("points", qs), ("weight", ws), ("face", faces))}}


def validation_batch(source: LandmarkSource, config, n: int = 256, seed: int = 0) -> dict:
    """``n`` faces of ``source`` (a fixed draw), cropped by their face boxes without jitter:
    what :func:`draw_batch` returns, plus ``index`` (n,) the faces' rows in the source."""
    rng = np.random.default_rng(seed)
    index = np.sort(rng.choice(len(source), size=min(n, len(source)), replace=False))
    neg = torch.zeros(len(index), dtype=torch.bool)
    x, q, w = _crops(source, torch.as_tensor(index), config, None, neg, jitter=False)
    return {"image": x, "points": q, "weight": w, "face": torch.ones(len(index)),
            "index": index}


def negative_crops(source: LandmarkSource, config, n: int, kind: str, seed: int = 0) -> torch.Tensor:
    """``n`` crops that hold no whole face -> (n, 3, R, R) in [-1, 1], colour-jittered as
    training crops are.

    kind : "away": a box about the face's size at least 0.8 of a side away from it (the
        training's negatives, :func:`draw_batch`); "part": a box 0.25-0.45 of the face box's
        side inside the face (an eye, the mouth, a cheek: a face detector's false box); or
        "texture": no photo at all, noise (uniform or Gaussian, grey or coloured, at one of
        four grain sizes), flat colours and linear gradients
    """
    if kind not in NEGATIVE_KINDS:
        raise InputError(f"negative crops: kind must be one of {', '.join(NEGATIVE_KINDS)}, got {kind!r}")
    gen = torch.Generator().manual_seed(int(np.random.SeedSequence([config.seed, seed, 7])
                                            .generate_state(1)[0]))
    R = config.resolution
    if kind == "texture":
        return _colour_jitter(_textures(n, R, gen), gen)
    index = torch.randint(len(source), (n,), generator=gen)
    if kind == "away":
        x, _, _ = _crops(source, index, config, gen, torch.ones(n, dtype=torch.bool), jitter=True)
        return _colour_jitter(x, gen)
    img = source.images[index].permute(0, 3, 1, 2).float() / 127.5 - 1
    box = source.boxes[index]
    s = box_side(box)
    c = (box[:, :2] + box[:, 2:]) / 2 + (torch.rand(n, 2, generator=gen) - 0.5) * 0.6 * s[:, None]
    side = _uniform(gen, n, 0.25, 0.45) * s
    parts = torch.cat([c - side[:, None] / 2, c + side[:, None] / 2], 1)
    theta = crop_theta(parts, (img.shape[-1], img.shape[-2]))
    return _colour_jitter(crop_images(img, theta, R), gen)


def _textures(n: int, R: int, gen) -> torch.Tensor:
    """(n, 3, R, R) in [-1, 1]: noise, flat colours and gradients in equal shares."""
    out = torch.empty(n, 3, R, R)
    kind = torch.randint(3, (n,), generator=gen)
    for i in range(n):
        if kind[i] == 0:      # noise at one of four grain sizes, grey or coloured
            grain = 2 ** int(torch.randint(4, (1,), generator=gen))
            ch = 3 if torch.rand(1, generator=gen) < 0.5 else 1
            small = (torch.rand(1, ch, R // grain, R // grain, generator=gen) * 2 - 1
                     if torch.rand(1, generator=gen) < 0.5 else
                     (0.5 * torch.randn(1, ch, R // grain, R // grain, generator=gen)).clamp(-1, 1))
            out[i] = torch.nn.functional.interpolate(small, size=(R, R), mode="bilinear",
                                                     align_corners=False)[0].expand(3, R, R)
        elif kind[i] == 1:
            out[i] = (torch.rand(3, 1, 1, generator=gen) * 2 - 1).expand(3, R, R)
        else:
            a, b = torch.rand(2, 3, 1, 1, generator=gen) * 2 - 1
            phi = float(torch.rand(1, generator=gen)) * 2 * math.pi
            t = torch.linspace(-1, 1, R)
            ramp = (math.cos(phi) * t[None, :] + math.sin(phi) * t[:, None]) / 2 + 0.5
            out[i] = a + (b - a) * ramp
    return out
