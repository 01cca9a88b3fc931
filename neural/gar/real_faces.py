"""Real face photos for the GAR: the packed training set and its batches.

A *pack* is one ``.npz`` file (no pickles) of aligned face crops with the labels our own
fits give them: the screen normal map and face mask of the fit, baked in the crop's frame,
68 landmarks, the person, the source and the held-out flag. :mod:`neural.gar.build_real` writes
it from ``../shared/data``; this module reads and writes the format and draws batches in
the layout of :meth:`neural.faces.renders.SyntheticFaces.sample`, so that the trainer and the
auxiliary networks take either.

Decoded arrays (what :func:`load_pack` returns and :func:`save_pack` takes), N crops of
R x R pixels:

=============  ====================  ====================================================
key            shape, dtype           meaning
=============  ====================  ====================================================
``image``      (N, R, R, 3) uint8     aligned photo (FFHQ framing, :mod:`neural.gar.data`)
``normals``    (N, R, R, 3) float32   unit normals of the fit, camera frame (x right, y
                                      up, z towards the viewer), zero outside the face
``mask``       (N, R, R) float32      face coverage of the fit in [0, 1]
``landmarks``  (N, 68, 2) float32     iBUG-68 px in the crop (x right, y down, 0-based
                                      pixel centres), NaN where unknown
``person``     (N,) int64             person id (same id = same person), unique per
                                      photo where the source does not say
``held_out``   (N,) bool              the fixed held-out split (about 5 %, by person)
``source``     (N,) str               data set of the photo (e.g. ``"aflw"``, ``"london"``)
``name``       (N,) str               the photo's file, relative to the data folder
=============  ====================  ====================================================

Any further array whose first axis is N (e.g. the fit's ``fit_identity`` (N, K),
``fit_expression`` (N, E), ``fit_pose`` (N, 3) yaw, pitch, roll in degrees) is stored as
given; other arrays (e.g. a scalar setting) are stored unchanged too.

Stored form: images as JPEG (quality ``jpeg_quality``), normals and mask at R px or at
``normal_resolution`` = R / f (:func:`downsample_faces`; read back bilinearly enlarged to R,
each normal rescaled to unit length: a 128-px pack of 11k photos keeps its images within the
64 MiB that reach a GPU machine, at the cost of softer face outlines), normals as
``n_x, n_y`` quantised
to int8 steps of ``1 / normal_scale`` and delta-coded along rows (``n_z`` is recovered as
``sqrt(1 - n_x^2 - n_y^2)`` with its sign kept per pixel), the mask as uint8; background
pixels (zero normals) stay zero. Everything is zlib-compressed by
``np.savez_compressed``; quantisation costs at most ~0.5 degree at ``normal_scale=127``.

Examples
--------
>>> import numpy as np, tempfile, os
>>> R, N = 16, 3
>>> n = np.zeros((N, R, R, 3), np.float32); n[:, 4:12, 4:12, 2] = 1
>>> arrays = {"image": np.zeros((N, R, R, 3), np.uint8), "normals": n,
...           "mask": (n[..., 2] > 0).astype(np.float32),
...           "landmarks": np.full((N, 68, 2), np.nan, np.float32),
...           "person": np.arange(N), "held_out": np.array([False, False, True]),
...           "source": np.array(["x"] * N), "name": np.array(["a", "b", "c"])}
>>> path = os.path.join(tempfile.mkdtemp(), "p.npz")
>>> _ = save_pack(path, arrays)
>>> faces = RealFaces(path, split="train")
>>> len(faces), faces.resolution
(2, 16)
>>> b = faces.sample(4, rng=0, pair=True)
>>> b["image"].shape, b["normals_b"].shape, b["identity_id"].shape
(torch.Size([4, 3, 16, 16]), torch.Size([4, 3, 16, 16]), torch.Size([4]))
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from morphable.errors import InputError
from morphable.ibug68 import MIRROR

__all__ = ["save_pack", "load_pack", "RealFaces", "flip_faces", "downsample_faces",
           "REQUIRED_KEYS", "SPLITS"]

REQUIRED_KEYS = ("image", "normals", "mask", "landmarks", "person", "held_out", "source", "name")
SPLITS = ("train", "test", "all")
_FORMAT = 1


def _encode_jpeg(images: np.ndarray, quality: int) -> tuple:
    from PIL import Image

    blobs = []
    for img in images:
        buf = io.BytesIO()
        Image.fromarray(img).save(buf, format="JPEG", quality=int(quality), subsampling=0)
        blobs.append(np.frombuffer(buf.getvalue(), np.uint8))
    offsets = np.cumsum([0] + [len(b) for b in blobs]).astype(np.int64)
    return np.concatenate(blobs) if blobs else np.zeros(0, np.uint8), offsets


def _decode_jpeg(data: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    from PIL import Image

    return np.stack([np.asarray(Image.open(io.BytesIO(data[a:b].tobytes())).convert("RGB"))
                     for a, b in zip(offsets[:-1], offsets[1:])])


def save_pack(path, arrays: dict, jpeg_quality: int = 90, normal_scale: int = 127,
              normal_resolution: int | None = None) -> Path:
    """Write the decoded ``arrays`` (see the module's table) to ``path`` atomically; with
    ``normal_resolution`` (R divided by an integer), the normals and mask stored at that side.

    Returns the path. Raises :class:`~morphable.errors.InputError` naming the key when a
    required array is missing or its shape does not match.
    """
    from morphable.io.atomic import atomic_path

    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise InputError(f"{path}: pack arrays lack {', '.join(missing)}")
    image = np.asarray(arrays["image"])
    if image.ndim != 4 or image.shape[3] != 3 or image.shape[1] != image.shape[2]:
        raise InputError(f"{path}: image must be (N, R, R, 3), got {image.shape}")
    N, R = image.shape[:2]
    normals = np.asarray(arrays["normals"], np.float32)
    mask = np.clip(np.asarray(arrays["mask"], np.float32), 0, 1)
    if normals.shape != (N, R, R, 3) or mask.shape != (N, R, R):
        raise InputError(f"{path}: normals (N, R, R, 3) and mask (N, R, R) must match image "
                         f"{image.shape}, got {normals.shape} and {mask.shape}")
    if not 1 <= normal_scale <= 127:
        raise InputError(f"{path}: normal_scale must be in 1..127, got {normal_scale}")
    if normal_resolution is not None and normal_resolution != R:
        try:
            normals = _unit_vectors(_block_mean(normals, int(normal_resolution)))
        except InputError as e:
            raise InputError(f"{path}: normal_resolution: {e}") from None
        mask = _block_mean(mask, int(normal_resolution))
    mask_u8 = np.round(mask * 255).astype(np.uint8)
    q = np.round(np.clip(normals[..., :2], -1, 1) * normal_scale).astype(np.int16)
    # 0 background, 1 facing the camera, 2 facing away (grazing pixels of a perspective view)
    side = np.where(np.abs(normals).sum(-1) > 0, np.where(normals[..., 2] < 0, 2, 1), 0)
    q[side == 0] = 0
    # delta along rows: neighbouring normals are close, so the differences compress well
    delta = np.diff(q, axis=2, prepend=0).astype(np.int8)
    data, offsets = _encode_jpeg(image.astype(np.uint8), jpeg_quality)
    out = {"format": np.int64(_FORMAT), "normal_scale": np.int64(normal_scale),
           "image_jpeg": data, "image_offsets": offsets, "normals_delta": delta, "normals_side": side.astype(np.uint8), "mask_u8": mask_u8}
    for key, value in arrays.items():
        if key in ("image", "normals", "mask"):
            continue
        value = np.asarray(value)
        if key in REQUIRED_KEYS and (value.ndim == 0 or len(value) != N):
            raise InputError(f"{path}: {key} must have {N} rows, got shape {value.shape}")
        if value.dtype.kind == "O":
            value = value.astype(str)
        out[key] = value
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **out)
    return path


def load_pack(path) -> dict:
    """The decoded arrays of a pack (the module's table, plus any extra arrays)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: pack not found (build it with `make gar-data`)")
    try:
        with np.load(path, allow_pickle=False) as z:
            raw = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as e:
        raise InputError(f"{path}: not a readable pack ({str(e).splitlines()[0]})") from None
    stored = ("image_jpeg", "image_offsets", "normals_delta", "normals_side", "mask_u8", "normal_scale", "format")
    missing = [k for k in stored + REQUIRED_KEYS[3:] if k not in raw]
    if missing:
        raise InputError(f"{path}: not a pack of this format (lacks {', '.join(missing)})")
    if int(raw["format"]) != _FORMAT:
        raise InputError(f"{path}: pack format {int(raw['format'])}, this code reads {_FORMAT}")
    scale = float(raw.pop("normal_scale"))
    raw.pop("format")
    # the int8 differences wrap where neighbours differ by more than 127 steps (an occluding
    # contour); summed in int8 they wrap back, exactly, since every value lies in -127..127
    q = np.cumsum(raw.pop("normals_delta"), axis=2, dtype=np.int8).astype(np.float32) / scale
    mask_u8, side = raw.pop("mask_u8"), raw.pop("normals_side")
    nz = np.sqrt(np.clip(1 - (q ** 2).sum(-1), 0, 1)) * np.where(side == 2, -1, 1)
    normals = np.concatenate([q, nz[..., None]], axis=-1)
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    normals[side == 0] = 0
    image = _decode_jpeg(raw.pop("image_jpeg"), raw.pop("image_offsets"))
    mask = mask_u8.astype(np.float32) / 255
    if normals.shape[1] != image.shape[1]:
        # in chunks: the enlargement's float temporaries of a whole 128-px pack would need
        # several times the 2.3 GB of its normals
        R, step = image.shape[1], 256
        normals = np.concatenate([_enlarge(normals[i:i + step], R, unit=True)
                                  for i in range(0, len(normals), step)] or [np.zeros((0, R, R, 3), np.float32)])
        mask = np.concatenate([_enlarge(mask[i:i + step], R) for i in range(0, len(mask), step)]
                              or [np.zeros((0, R, R), np.float32)])
    out = {"image": image, "normals": normals.astype(np.float32), "mask": mask}
    out.update(raw)
    out["held_out"] = out["held_out"].astype(bool)
    return out


def _unit_vectors(a: np.ndarray) -> np.ndarray:
    """Vectors along the last axis rescaled to unit length, zero where they are (near) zero."""
    length = np.linalg.norm(a, axis=-1, keepdims=True)
    return np.where(length > 1e-6, a / np.maximum(length, 1e-12), 0).astype(np.float32)


def _block_mean(a, resolution: int) -> np.ndarray:
    """(N, R, R, ...) -> (N, resolution, resolution, ...) float32 means of f x f blocks,
    f = R / resolution; InputError unless f is an integer."""
    a = np.asarray(a, np.float32)
    R = a.shape[1]
    if resolution < 1 or R % resolution:
        raise InputError(f"a pack of {R} px cannot be area-downsampled to {resolution} px "
                         f"(not an integer factor)")
    f = R // resolution
    return a.reshape(a.shape[0], resolution, f, resolution, f, *a.shape[3:]).mean((2, 4))


def _enlarge(a: np.ndarray, size: int, unit: bool = False) -> np.ndarray:
    """(N, r, r, ...) -> (N, size, size, ...) bilinearly (pixel centres, edges clamped, as
    ``torch.nn.functional.interpolate(align_corners=False)``); ``unit``: vectors along the
    last axis rescaled to unit length, zero where every neighbour is zero."""
    r = a.shape[1]
    x = np.clip((np.arange(size) + 0.5) * r / size - 0.5, 0, r - 1)
    i0 = np.floor(x).astype(int)
    i1, w = np.minimum(i0 + 1, r - 1), (x - i0).astype(np.float32)
    shape = (1, -1) + (1,) * (a.ndim - 2)
    a = a[:, i0] * (1 - w).reshape(shape) + a[:, i1] * w.reshape(shape)
    shape = (1, 1, -1) + (1,) * (a.ndim - 3)
    a = a[:, :, i0] * (1 - w).reshape(shape) + a[:, :, i1] * w.reshape(shape)
    return _unit_vectors(a) if unit else a.astype(np.float32)


def downsample_faces(arrays: dict, resolution: int) -> dict:
    """The decoded ``arrays`` of a pack at R px (the module's table) at ``resolution`` px,
    R an integer multiple of it: images and masks area-averaged over f x f blocks
    (f = R / resolution), normals summed over the block's face pixels and renormalised (zero
    where the block holds no face; the packs' 2 x 2 supersampled bakes average the same way),
    landmarks moved to the new pixel centres ``(x + 0.5) / f - 0.5``. A new dict; arrays
    without pixels are shared. One 128-px pack serves a 64-px GAR this way.

    >>> import numpy as np
    >>> a = {"image": np.full((1, 4, 4, 3), 200, np.uint8), "mask": np.ones((1, 4, 4)),
    ...      "normals": np.tile(np.float32([0, 0, 1]), (1, 4, 4, 1)),
    ...      "landmarks": np.full((1, 68, 2), 1.5, np.float32)}
    >>> d = downsample_faces(a, 2)
    >>> d["image"].shape, float(d["landmarks"][0, 0, 0]), float(d["normals"][0, 1, 1, 2])
    ((1, 2, 2, 3), 0.5, 1.0)
    """
    R = int(np.asarray(arrays["image"]).shape[1])
    if resolution == R:
        return dict(arrays)
    out = dict(arrays)
    out["normals"] = _unit_vectors(_block_mean(arrays["normals"], resolution))
    out["image"] = np.round(_block_mean(arrays["image"], resolution)).astype(np.uint8)
    out["mask"] = _block_mean(arrays["mask"], resolution)
    out["landmarks"] = (np.asarray(arrays["landmarks"], np.float32) + 0.5) / (R // resolution) - 0.5
    return out


def flip_faces(image, normals, mask, landmarks):
    """Mirror crops left-right: (N, R, R, 3) images, (N, R, R, 3) normals (x negated),
    (N, R, R) masks, (N, 68, 2) px landmarks (x -> R - 1 - x, mirrored labels); numpy
    arrays or torch tensors (new ones, the inputs are not changed)."""
    R = image.shape[2]
    mirror = MIRROR
    if isinstance(image, np.ndarray):
        def flip(a):
            return a[:, :, ::-1].copy()
    else:
        import torch

        from ..training import to_device

        def flip(a):
            return a.flip(2)
        # the label order copied to the tensors' device without a wait
        mirror = to_device(torch.as_tensor(MIRROR), landmarks.device)
    n = flip(normals)
    n[..., 0] *= -1
    lm = landmarks[:, mirror]
    lm[..., 0] = R - 1 - lm[..., 0]
    return flip(image), n, flip(mask), lm


class RealFaces:
    """Batches of a pack, in the layout of :meth:`neural.faces.renders.SyntheticFaces.sample`.

    Parameters
    ----------
    path : pack file (:func:`save_pack`)
    split : ``"train"`` (not held out), ``"test"`` (held out) or ``"all"``
    flip : mirror each drawn crop with probability 1/2 (normals' x negated)
    device : torch device of the batches; the split's crops are held there as tensors
        (images as uint8) once, so that drawing a batch moves no data to the device
    resolution : side of the crops served, px; a pack at an integer multiple of it is
        area-downsampled once on load (:func:`downsample_faces`); default the pack's own

    The second view of a pair (``pair=True``) is another photo of the same person in the
    split when there is one (e.g. the London set's smiling photo), else the mirror image of
    the same photo: the same identity under another pose.
    """

    def __init__(self, path, split: str = "train", flip: bool = True, device="cpu",
                 resolution: int | None = None):
        if split not in SPLITS:
            raise InputError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
        arrays = load_pack(path)
        if resolution is not None:
            try:
                arrays = downsample_faces(arrays, int(resolution))
            except InputError as e:
                raise InputError(f"{path}: {e}") from None
        keep = {"train": ~arrays["held_out"], "test": arrays["held_out"],
                "all": np.ones(len(arrays["held_out"]), bool)}[split]
        if not keep.any():
            raise InputError(f"{path}: no {split} crops")
        n = len(keep)
        self.arrays = {k: (v[keep] if v.ndim and len(v) == n else v) for k, v in arrays.items()}
        self.path, self.split, self.flip = Path(path), split, bool(flip)
        self.resolution = int(self.arrays["image"].shape[1])
        person = self.arrays["person"]
        order = np.argsort(person, kind="stable")
        starts = np.flatnonzero(np.r_[True, person[order][1:] != person[order][:-1]])
        self._groups = np.split(order, starts[1:])
        self._group_of = np.empty(len(person), np.int64)
        for g, members in enumerate(self._groups):
            self._group_of[members] = g
        self.device = device
        self._tensors = None

    @property
    def tensors(self) -> dict:
        """The split's ``image`` (uint8), ``normals``, ``mask``, ``landmarks``, ``pose`` (the
        fit's, zero when the pack has none) and ``person`` as tensors on ``device``."""
        if self._tensors is None:
            import torch

            a = self.arrays
            pose = a["fit_pose"] if "fit_pose" in a else np.zeros((len(self), 3))
            cols = {"image": a["image"], "normals": a["normals"], "mask": a["mask"],
                    "landmarks": a["landmarks"].astype(np.float32),
                    "pose": np.asarray(pose, np.float32), "person": a["person"].astype(np.int64)}
            self._tensors = {k: torch.as_tensor(np.ascontiguousarray(v), device=self.device)
                             for k, v in cols.items()}
        return self._tensors

    def __len__(self) -> int:
        return len(self.arrays["image"])

    def partner(self, index: np.ndarray, rng) -> tuple:
        """(B,) indices of the second views and (B,) bool: True where it is the photo
        itself mirrored (no other photo of the person)."""
        out, mirrored = np.array(index), np.zeros(len(index), bool)
        for k, i in enumerate(index):
            others = self._groups[self._group_of[i]]
            others = others[others != i]
            if len(others):
                out[k] = others[rng.integers(len(others))]
            else:
                mirrored[k] = True
        return out, mirrored

    def batch(self, index, flipped=None) -> dict:
        """The crops ``index`` (B,) as torch tensors on ``device`` (``image`` in [-1, 1]),
        mirrored where ``flipped`` (B,) bool is True; ``identity_id`` (B,) stays a CPU
        tensor (the trainer picks other people's photos by it on the host)."""
        import torch

        from ..training import to_device

        # the host's choices reach the device without making the host wait (to_device)
        t = self.tensors
        host = np.asarray(index)
        index = to_device(torch.as_tensor(host), self.device)
        img, n, m, lm, pose = (t[k][index] for k in ("image", "normals", "mask", "landmarks",
                                                     "pose"))
        if flipped is not None:
            f = np.asarray(flipped, bool)
            if f.any():
                # every crop mirrored, then chosen per crop: a boolean index would make the
                # host wait for the device (it needs the count)
                ft = to_device(torch.as_tensor(f), self.device)
                img, n, m, lm = (torch.where(ft.reshape(-1, *[1] * (a.dim() - 1)), b, a)
                                 for a, b in zip((img, n, m, lm), flip_faces(img, n, m, lm)))
            # a mirror image turns yaw and roll the other way
            sign = to_device(torch.as_tensor(np.where(f[:, None], [-1, 1, -1], 1),
                                             dtype=pose.dtype), self.device)
            pose = pose * sign
        return {"image": img.permute(0, 3, 1, 2).float() / 127.5 - 1,
                "normals": n.permute(0, 3, 1, 2).contiguous(),
                "mask": m[:, None].float(),
                "landmarks": lm.float(),
                "pose": pose.float(),
                "identity_id": torch.as_tensor(self.arrays["person"][host])}

    def sample(self, batch_size: int, rng=None, pair: bool = False) -> dict:
        """``batch_size`` random crops (with replacement) as the dict of
        :meth:`neural.faces.renders.SyntheticFaces.sample`: ``image`` (B, 3, R, R) in [-1, 1],
        ``normals`` (B, 3, R, R), ``mask`` (B, 1, R, R), ``landmarks`` (B, 68, 2) px,
        ``pose`` (B, 3) degrees (the fit's, zero when the pack has none), ``identity_id``
        (B,) the person; with ``pair=True`` also the second views ``image_b``,
        ``normals_b``, ``mask_b``, ``landmarks_b``, ``pose_b``."""
        rng = np.random.default_rng(rng)
        index = rng.integers(len(self), size=int(batch_size))
        flipped = rng.random(len(index)) < 0.5 if self.flip else np.zeros(len(index), bool)
        out = self.batch(index, flipped)
        if pair:
            other, mirrored = self.partner(index, rng)
            flipped_b = np.where(mirrored, ~flipped, rng.random(len(index)) < 0.5 if self.flip
                                 else False)
            out.update({f"{k}_b": v for k, v in self.batch(other, flipped_b).items()
                        if k != "identity_id"})
        return out
