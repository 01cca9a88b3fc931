"""3DDFA-V2's released MobileNet-0.5 (Guo et al., "Towards Fast, Accurate and Stable 3D Dense
Face Alignment", ECCV 2020) as a peer of the alignment benchmarks, run from its released files
by a loader and a network of our own (torch).

The method, as released: a square crop around the face, resized to 120 x 120 px (BGR,
``(v - 127.5) / 128``); a MobileNet-V1 of width 0.5 regresses 62 normalised parameters, which
its ``param_mean`` / ``param_std`` de-normalise into a 3 x 4 affine camera (scaled rotation and
offset, crop pixels), 40 BFM shape and 10 expression coefficients; the 68 iBUG keypoints are
the BFM's mean plus its bases at those keypoints times the coefficients, through the camera,
mapped from the crop back to the photo. The crop is 3DDFA-V2's from landmarks (its
``crop_policy="landmark"``): a square of side √2 x the larger side of the 68 points' extent,
on its centre, which is what a box means here (:mod:`morphable.detection`: a face box is its
68 points' extent).

**Files** (research use: the keypoint bases are a BFM2009 derivative, for academic use only;
3DDFA-V2's code and weights are MIT-licensed), read from a folder the user points to
(``folder=``, else ``$MORPHABLE_3DDFA_DIR``), never shipped with this repository:

- ``mb05_120x120.pth``: the released weights (3DDFA_V2 ``weights/``);
- ``param_mean_std_62d_120x120.pkl``: the parameters' mean and std (3DDFA_V2 ``configs/``);
- the BFM's 68 keypoints, either ``bfm_noneck_v3.pkl`` (3DDFA_V2 ``configs/``: ``u``,
  ``w_shp``, ``w_exp`` and the ``keypoints`` rows) or its keypoint part as 3DDFA's C++ port
  ships it: ``u_base.txt`` (204 values), ``w_shp_base.txt`` (204 x 40), ``w_exp_base.txt``
  (204 x 10) (``cleardusk/3DDFA``, ``c++/weights/``).

Pickles are read with an unpickler that builds NumPy arrays and nothing else; the weights with
``torch.load(weights_only=True)``.

Examples
--------
>>> peer = ThreeDDFA("/work/peers/3ddfa_v2")                    # doctest: +SKIP
>>> peer.ibug68(image, box=(120, 140, 330, 370)).shape           # (H, W, 3) uint8 -> px  # doctest: +SKIP
(68, 2)
"""
from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np

from morphable.errors import InputError

__all__ = ["DIR_ENV", "WEIGHTS_FILE", "PARAM_STATS_FILE", "BFM_FILE", "KEYPOINT_FILES", "INPUT_PX",
           "N_SHAPE", "N_EXPRESSION", "BLOCKS", "peer_dir", "add_dir_argument", "unavailable", "mobilenet_v1",
           "load_weights", "load_param_stats", "load_keypoint_bases", "crop_box", "crop",
           "keypoints_in_crop", "crop_to_image", "ThreeDDFA"]

DIR_ENV = "MORPHABLE_3DDFA_DIR"
WEIGHTS_FILE = "mb05_120x120.pth"
PARAM_STATS_FILE = "param_mean_std_62d_120x120.pkl"
BFM_FILE = "bfm_noneck_v3.pkl"
KEYPOINT_FILES = ("u_base.txt", "w_shp_base.txt", "w_exp_base.txt")
INPUT_PX = 120
N_SHAPE, N_EXPRESSION = 40, 10
N_PARAMS = 12 + N_SHAPE + N_EXPRESSION
BLOCKS = (("dw2_1", 32, 64, 1), ("dw2_2", 64, 128, 2), ("dw3_1", 128, 128, 1), ("dw3_2", 128, 256, 2),
          ("dw4_1", 256, 256, 1), ("dw4_2", 256, 512, 2), ("dw5_1", 512, 512, 1), ("dw5_2", 512, 512, 1),
          ("dw5_3", 512, 512, 1), ("dw5_4", 512, 512, 1), ("dw5_5", 512, 512, 1), ("dw5_6", 512, 1024, 2),
          ("dw6", 1024, 1024, 1))
"""MobileNet-V1's depthwise-separable blocks after its first convolution (32 channels, stride
2): (name in the released state dict, input and output channels at width 1, stride)."""


def peer_dir(folder=None) -> Path | None:
    """``folder`` if given, else ``$MORPHABLE_3DDFA_DIR``, else None."""
    if folder is not None:
        return Path(folder)
    env = os.environ.get(DIR_ENV)
    return Path(env) if env else None


def add_dir_argument(parser) -> None:
    """``--3ddfa-dir`` (``dest="ddfa_dir"``) on an argparse ``parser``: the folder of the
    released files."""
    parser.add_argument("--3ddfa-dir", dest="ddfa_dir", type=Path, default=None,
                        help=f"folder of 3DDFA-V2's released files for its peer row (default: ${DIR_ENV}; "
                             "research use, evaluation/peers_3ddfa.py lists them)")


def unavailable(folder=None) -> str | None:
    """Why the peer cannot run (no folder, a file missing, no torch) in a few words, or None."""
    f = peer_dir(folder)
    if f is None:
        return f"no folder of its released files (--3ddfa-dir or ${DIR_ENV})"
    if not f.is_dir():
        return f"{f} is not a folder"
    missing = [n for n in (WEIGHTS_FILE, PARAM_STATS_FILE) if not (f / n).is_file()]
    if not (f / BFM_FILE).is_file() and not all((f / n).is_file() for n in KEYPOINT_FILES):
        missing.append(f"{BFM_FILE} or {', '.join(KEYPOINT_FILES)}")
    if missing:
        return f"{f} lacks {'; '.join(missing)}"
    try:
        import torch  # noqa: F401
    except ImportError:
        return "it needs torch (pip install torch)"
    return None


class _ArraysOnly(pickle.Unpickler):
    """An unpickler for dicts of NumPy arrays: it builds ndarrays and dtypes, nothing else."""

    _ALLOWED = {"ndarray": np.ndarray, "dtype": np.dtype, "_reconstruct": np.zeros(0).__reduce__()[0]}

    def find_class(self, module, name):
        if module.split(".")[0] == "numpy" and name in self._ALLOWED:
            return self._ALLOWED[name]
        raise pickle.UnpicklingError(f"{module}.{name} is not part of an array")


def _arrays(path: Path) -> dict:
    try:
        with open(path, "rb") as fh:
            d = _ArraysOnly(fh, encoding="latin1").load()
    except (OSError, pickle.UnpicklingError, EOFError, ValueError) as e:
        raise InputError(f"{path}: not a pickle of arrays ({e})") from None
    if not isinstance(d, dict):
        raise InputError(f"{path}: expected a dict of arrays, got {type(d).__name__}")
    return d


def mobilenet_v1(widen_factor: float = 0.5, n_outputs: int = N_PARAMS):
    """3DDFA-V2's MobileNet-V1, its modules named as in the released state dict (``conv1``,
    ``bn1``, ``dw2_1.conv_dw``, ..., ``fc``): (B, 3, 120, 120) -> (B, ``n_outputs``)."""
    from collections import OrderedDict

    from torch import nn

    def ch(c):
        return int(c * widen_factor)

    def block(cin, cout, stride):
        return nn.Sequential(OrderedDict(
            conv_dw=nn.Conv2d(cin, cin, 3, stride, 1, groups=cin, bias=False), bn_dw=nn.BatchNorm2d(cin),
            relu_dw=nn.ReLU(inplace=True),
            conv_sep=nn.Conv2d(cin, cout, 1, bias=False), bn_sep=nn.BatchNorm2d(cout),
            relu_sep=nn.ReLU(inplace=True)))

    layers = OrderedDict(conv1=nn.Conv2d(3, ch(32), 3, 2, 1, bias=False), bn1=nn.BatchNorm2d(ch(32)),
                         relu=nn.ReLU(inplace=True))
    layers.update((name, block(ch(cin), ch(cout), s)) for name, cin, cout, s in BLOCKS)
    layers.update(avgpool=nn.AdaptiveAvgPool2d(1), flatten=nn.Flatten(), fc=nn.Linear(ch(1024), n_outputs))
    return nn.Sequential(layers)


def load_weights(path):
    """The released checkpoint (``{"state_dict": ...}``, keys ``module.*``) -> our
    :func:`mobilenet_v1` in eval mode, its width read from ``conv1`` (0.5: 16 channels). The
    parameter head ``fc_param`` is our ``fc``; ``fc_lm``, a landmark head used only in training,
    is left out, as the released inference leaves it out. InputError naming the file for a
    checkpoint of another layout."""
    import torch

    path = Path(path)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        state = ckpt["state_dict"]
        widen = state["module.conv1.weight"].shape[0] / 32
    except Exception as e:      # torch raises many kinds for a file that is not a checkpoint
        raise InputError(f"{path}: not a 3DDFA-V2 checkpoint ({type(e).__name__}: {e})") from None
    ours = {}
    for k, v in state.items():
        k = k.removeprefix("module.")
        if not k.startswith("fc_lm."):
            ours[k.replace("fc_param.", "fc.", 1)] = v
    net = mobilenet_v1(widen, n_outputs=ours.get("fc.bias", torch.zeros(N_PARAMS)).shape[0])
    try:
        net.load_state_dict(ours, strict=True)
    except RuntimeError as e:
        raise InputError(f"{path}: not the layout of 3DDFA-V2's MobileNet-V1 "
                         f"({' '.join(str(e).split())[:300]})") from None
    return net.eval()


def load_param_stats(path) -> tuple[np.ndarray, np.ndarray]:
    """``param_mean_std_62d_120x120.pkl`` -> its ``mean`` and ``std`` (62,) float64 (12 camera
    entries, 40 shape, 10 expression coefficients)."""
    d = _arrays(Path(path))
    try:
        mean, std = (np.asarray(d[k], dtype=np.float64).ravel() for k in ("mean", "std"))
    except KeyError as e:
        raise InputError(f"{path}: no {e} array") from None
    if mean.shape != (N_PARAMS,) or std.shape != (N_PARAMS,):
        raise InputError(f"{path}: expected {N_PARAMS} means and stds, got {mean.shape}, {std.shape}")
    return mean, std


def load_keypoint_bases(folder) -> dict:
    """The BFM at the 68 keypoints from ``folder`` (``bfm_noneck_v3.pkl`` if there, else the three
    text files): ``mean`` (68, 3), ``shape`` (68, 3, 40), ``expression`` (68, 3, 10), in the
    BFM's units (the released camera's scale maps them to crop pixels)."""
    f = Path(folder)
    if (f / BFM_FILE).is_file():
        d = _arrays(f / BFM_FILE)
        try:
            rows = np.asarray(d["keypoints"]).astype(np.int64).ravel()
            u = np.asarray(d["u"], dtype=np.float64).ravel()[rows]
            shp = np.asarray(d["w_shp"], dtype=np.float64)[rows, :N_SHAPE]
            exp = np.asarray(d["w_exp"], dtype=np.float64)[rows, :N_EXPRESSION]
        except (KeyError, IndexError) as e:
            raise InputError(f"{f / BFM_FILE}: not 3DDFA-V2's BFM ({type(e).__name__}: {e})") from None
        source = f / BFM_FILE
    else:
        try:
            u, shp, exp = (np.loadtxt(f / n, ndmin=2) for n in KEYPOINT_FILES)
        except (OSError, ValueError) as e:
            raise InputError(f"{f}: the keypoint bases {', '.join(KEYPOINT_FILES)} ({e})") from None
        source = f / KEYPOINT_FILES[0]
    if u.size != 204 or shp.shape != (204, N_SHAPE) or exp.shape != (204, N_EXPRESSION):
        raise InputError(f"{source}: expected 204 keypoint rows with {N_SHAPE} shape and "
                         f"{N_EXPRESSION} expression bases, got {u.size}, {shp.shape}, {exp.shape}")
    # rows x, y, z of keypoint 0, then of keypoint 1, ...
    return {"mean": u.reshape(68, 3), "shape": shp.reshape(68, 3, N_SHAPE),
            "expression": exp.reshape(68, 3, N_EXPRESSION)}


def crop_box(box) -> np.ndarray:
    """A face box, its 68 points' extent (4,) ``(left, top, right, bottom)`` px -> the square crop
    box (4,) px: side √2 x the extent's larger side, on its centre."""
    b = np.asarray(box, dtype=np.float64)
    c = (b[:2] + b[2:]) / 2
    half = np.sqrt(2.0) * np.max(b[2:] - b[:2]) / 2
    return np.concatenate([c - half, c + half])


def crop(image, roi, size: int = INPUT_PX):
    """(H, W, 3) uint8 RGB and a crop box (4,) px -> the network's input (1, 3, size, size)
    float32 tensor: the box rounded to whole pixels (black outside the photo), resized
    bilinearly (pixel centres, no anti-aliasing, rounded to 8 bits), BGR, ``(v - 127.5) / 128``."""
    import torch
    import torch.nn.functional as F

    H, W = image.shape[:2]
    x0, y0, x1, y1 = np.round(roi).astype(int)
    if x1 - x0 < 1 or y1 - y0 < 1:
        raise InputError(f"crop box {np.round(roi, 1).tolist()} is empty")
    out = np.zeros((y1 - y0, x1 - x0, 3), dtype=np.uint8)
    sx, sy, ex, ey = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if ex > sx and ey > sy:
        out[sy - y0:ey - y0, sx - x0:ex - x0] = image[sy:ey, sx:ex, :3]
    t = torch.from_numpy(np.ascontiguousarray(out[..., ::-1])).permute(2, 0, 1)[None].float()
    t = F.interpolate(t, size=(size, size), mode="bilinear", align_corners=False).round().clamp(0, 255)
    return (t - 127.5) / 128.0


def keypoints_in_crop(params, bases: dict) -> np.ndarray:
    """De-normalised parameters (62,) -> the 68 keypoints (68, 3) in the crop's frame (x right,
    y up, 1-based, crop px): the 3 x 4 camera ``params[:12]`` applied to the BFM's mean plus
    ``params[12:52]`` x its shape and ``params[52:]`` x its expression bases."""
    p = np.asarray(params, dtype=np.float64)
    P = p[:12].reshape(3, 4)
    X = bases["mean"] + bases["shape"] @ p[12:12 + N_SHAPE] + bases["expression"] @ p[12 + N_SHAPE:]
    return X @ P[:, :3].T + P[:, 3]


def crop_to_image(points, roi, size: int = INPUT_PX) -> np.ndarray:
    """Keypoints in the crop's frame (n, 3) (x right, y up, 1-based, as the network was trained)
    -> (n, 2) photo px (0-based, y down) through the crop box ``roi`` (4,) px."""
    p = np.asarray(points, dtype=np.float64)
    scale = (np.asarray(roi[2:]) - roi[:2]) / size
    return np.stack([(p[:, 0] - 1) * scale[0] + roi[0], (size - p[:, 1]) * scale[1] + roi[1]], -1)


class ThreeDDFA:
    """3DDFA-V2's MobileNet-0.5 from its released files in ``folder`` (default
    ``$MORPHABLE_3DDFA_DIR``); InputError with :func:`unavailable`'s reason when it cannot run."""

    def __init__(self, folder=None):
        why = unavailable(folder)
        if why:
            raise InputError(f"3ddfa-v2: {why}")
        f = peer_dir(folder)
        self.net = load_weights(f / WEIGHTS_FILE)
        self.mean, self.std = load_param_stats(f / PARAM_STATS_FILE)
        self.bases = load_keypoint_bases(f)

    def params(self, image, roi) -> np.ndarray:
        """(H, W, 3) uint8 RGB, crop box (4,) px -> the de-normalised parameters (62,)."""
        import torch

        with torch.inference_mode():
            out = self.net(crop(image, roi))[0].double().numpy()
        return out * self.std + self.mean

    def ibug68(self, image, box) -> np.ndarray:
        """(H, W, 3) uint8 RGB and the face's box, its 68 points' extent (4,) px -> the 68 iBUG
        keypoints (68, 2) px (0-based, x right, y down; 3D convention: a hidden jaw point lies
        on the jaw)."""
        roi = crop_box(box)
        return crop_to_image(keypoints_in_crop(self.params(image, roi), self.bases), roi)
