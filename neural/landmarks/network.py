"""The landmark network: from a face crop, the 546 surface points of
:mod:`neural.faces.points` (3D convention), a σ each, and a face/no-face score.

After Wood et al., *3D Face Reconstruction with Dense Landmarks* (ECCV 2022): direct
regression of every point's position with an isotropic Gaussian uncertainty, trained by its
negative log-likelihood (:func:`gaussian_nll`); the backbone is a small residual CNN sized for
one CPU thread (:class:`LandmarkConfig`).

The crop: a square face box, optionally rotated and mirrored, resampled to R x R; its geometry
(``theta``, crop-normalised coordinates ``q`` in [-1, 1] and back to pixels) is
:mod:`neural.landmarks.cropping`'s, numpy, shared with the detector; :func:`crop_images` cuts
the trainer's crops with torch's ``grid_sample``.

Conventions: images (B, 3, R, R) float in [-1, 1]; pixels x right, y down, 0-based pixel
centres; σ in pixels of the image the points are given in.

>>> import torch
>>> net = LandmarkNet(LandmarkConfig(widths=(8, 8, 8, 8, 8), hidden=16)).eval()
>>> out = net(torch.zeros(2, 3, 128, 128))
>>> out["points"].shape, out["log_sigma"].shape, out["score"].shape
(torch.Size([2, 546, 2]), torch.Size([2, 546]), torch.Size([2]))
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import torch
import torch.nn.functional as F
from torch import nn

from ..faces.points import N_POINTS

__all__ = ["ARCHES", "LandmarkConfig", "LandmarkNet", "gaussian_nll", "crop_images", "points_in_crop_px",
           "save_landmark_net", "load_landmark_net"]


@dataclass(frozen=True)
class LandmarkConfig:
    """The landmark network and its training (sizes px, angles degrees).

    .. rubric:: Network

    resolution : crop side (px); a multiple of 2 ** len(widths).

    widths : channels of the stride-2 stages (the first is the stem); the last feature map
        is ``resolution / 2 ** len(widths)`` on a side, flattened into the head.

    blocks : residual blocks after each stage's down-sampling convolution (one per stage).
    hidden : width of the head's hidden layer.
    sigma_min_px, sigma_max_px : the range σ is clamped to (crop px).

    .. rubric:: Training

    steps, batch_size, lr (AdamW, one-cycle cosine after ``warmup`` steps), weight_decay, seed.

    mix : fraction of each batch from each pack kind (``synthetic``, ``annotated``,
        ``profiled``; kinds without a pack are dropped and the rest renormalised).

    negatives : fraction of each batch that is a crop away from the face (score target 0).

    scale_jitter, shift_jitter : the crop box's log-scale and centre (× side) jitter, standing
        in for face detectors' boxes; rotate_deg : in-plane rotation range; flip : mirror half.

    print_every, sample_every, checkpoint_every : in steps.
    """
    resolution: int = 128
    widths: tuple = (16, 32, 64, 96, 128)
    blocks: tuple = (0, 0, 1, 1, 1)
    hidden: int = 512
    n_points: int = N_POINTS
    sigma_min_px: float = 0.25
    sigma_max_px: float = 64.0

    steps: int = 200_000
    batch_size: int = 64
    lr: float = 2e-3
    warmup: int = 300
    weight_decay: float = 1e-4
    seed: int = 0
    mix: tuple = (("synthetic", 0.6), ("annotated", 0.25), ("profiled", 0.15))
    negatives: float = 0.08
    scale_jitter: float = 0.2
    shift_jitter: float = 0.15
    rotate_deg: float = 20.0
    flip: bool = True
    print_every: int = 50
    sample_every: int = 2000
    checkpoint_every: int = 500

    def __post_init__(self):
        if len(self.blocks) != len(self.widths):
            raise ValueError(f"blocks {self.blocks}: one count per stage of widths {self.widths}")
        if self.resolution % 2 ** len(self.widths):
            raise ValueError(f"resolution {self.resolution}: not a multiple of "
                             f"{2 ** len(self.widths)}")

    @property
    def feature_side(self) -> int:
        return self.resolution // 2 ** len(self.widths)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["widths"], d["blocks"] = list(self.widths), list(self.blocks)
        d["mix"] = [list(m) for m in self.mix]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "LandmarkConfig":
        known = {f.name for f in fields(cls)}
        d = {k: v for k, v in d.items() if k in known}
        for k in ("widths", "blocks"):
            if k in d:
                d[k] = tuple(d[k])
        if "mix" in d:
            d["mix"] = tuple((str(a), float(b)) for a, b in d["mix"])
        return cls(**d)


ARCHES = {
    "small": {},
    "wide": {"resolution": 160, "widths": (16, 32, 64, 128, 160), "blocks": (0, 1, 2, 2, 1),
             "hidden": 384},
}
"""Named network sizes (:class:`LandmarkConfig` fields; ``--arch`` of
:mod:`neural.landmarks.train`): ``small`` is the config's default (128 px, 2.62 M
parameters, the CPU recipe's); ``wide`` is sized for a GPU run: 160 px, more channels and
residual blocks, 3.67 M parameters, 14.7 MB of weights, about 7 ms per face on one CPU
thread where ``small`` takes about 3 ms (docs/gpu_runs.md: the command and the load). A
weights file holds its config, so the detector loads either."""


def _conv(cin, cout, stride=1):
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout),
                         nn.ReLU(inplace=True))


class _Residual(nn.Module):
    def __init__(self, c):
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(c, c, 3, 1, 1, bias=False), nn.BatchNorm2d(c),
                                  nn.ReLU(inplace=True), nn.Conv2d(c, c, 3, 1, 1, bias=False),
                                  nn.BatchNorm2d(c))

    def forward(self, x):
        return F.relu(x + self.body(x))


class LandmarkNet(nn.Module):
    """Crop -> points, log σ, face score.

    ``forward(x)``: x (B, 3, R, R) in [-1, 1] -> dict of ``points`` (B, P, 2) crop-normalised
    coordinates, ``log_sigma`` (B, P) log of σ in crop px (clamped to the config's range),
    ``score`` (B,) the face logit. ``meta`` (dict) is saved with the weights (training data,
    steps, ...)."""

    def __init__(self, config: LandmarkConfig = LandmarkConfig()):
        super().__init__()
        self.config = config
        self.meta = {}
        layers, cin = [], 3
        for width, blocks in zip(config.widths, config.blocks):
            layers.append(_conv(cin, width, stride=2))
            layers += [_Residual(width) for _ in range(blocks)]
            cin = width
        self.features = nn.Sequential(*layers)
        side = config.feature_side
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(cin * side * side, config.hidden),
                                  nn.ReLU(inplace=True), nn.Linear(config.hidden, 3 * config.n_points + 1))
        nn.init.zeros_(self.head[-1].weight)
        nn.init.zeros_(self.head[-1].bias)
        with torch.no_grad():     # σ starts at 8 crop px: gradients of scale with the errors
            self.head[-1].bias[2 * config.n_points:3 * config.n_points] = math.log(8.0)

    def forward(self, x: torch.Tensor) -> dict:
        P = self.config.n_points
        h = self.head(self.features(x)).float()
        lo, hi = math.log(self.config.sigma_min_px), math.log(self.config.sigma_max_px)
        return {"points": h[:, :2 * P].reshape(-1, P, 2),
                "log_sigma": h[:, 2 * P:3 * P].clamp(lo, hi),
                "score": h[:, -1]}

    def set_mean_points(self, q: torch.Tensor) -> None:
        """Start the point outputs at ``q`` (P, 2) crop-normalised (e.g. the training labels'
        mean), so that the first steps learn offsets rather than the template."""
        with torch.no_grad():
            self.head[-1].bias[:2 * self.config.n_points] = q.reshape(-1).to(self.head[-1].bias)


def gaussian_nll(pred: torch.Tensor, log_sigma: torch.Tensor, target: torch.Tensor,
                 weight: torch.Tensor) -> torch.Tensor:
    """Mean negative log-likelihood of 2D isotropic Gaussians (constant dropped).

    pred, target (B, P, 2) px; log_sigma (B, P) log px; weight (B, P) >= 0 (0: unlabelled,
    whatever ``target`` holds there, NaN included). Per point:
    ``|pred - target|^2 / (2 σ^2) + 2 log σ``; the result is the weighted mean."""
    target = torch.where(weight[..., None] > 0, target, pred.detach())
    d2 = ((pred - target) ** 2).sum(-1)
    nll = d2 * torch.exp(-2 * log_sigma) / 2 + 2 * log_sigma
    return (nll * weight).sum() / weight.sum().clamp_min(1.0)


def crop_images(images: torch.Tensor, theta, resolution: int) -> torch.Tensor:
    """images (B, 3, H, W) float -> (B, 3, R, R) crops (bilinear; zero outside the image) at
    ``theta`` (B, 2, 3) (:func:`neural.landmarks.cropping.crop_theta`, array or tensor)."""
    grid = F.affine_grid(torch.as_tensor(theta).to(images), (len(images), 3, resolution, resolution),
                         align_corners=False)
    return F.grid_sample(images, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def save_landmark_net(net: LandmarkNet, path) -> None:
    """The config, ``meta`` and CPU weights, written atomically."""
    from morphable.io.atomic import atomic_path

    from ..training import cpu_state

    with atomic_path(path) as tmp:
        torch.save({"config": net.config.to_dict(), "meta": net.meta, "state": cpu_state(net)}, tmp)


def load_landmark_net(path) -> LandmarkNet:
    """A frozen :class:`LandmarkNet` in eval mode from :func:`save_landmark_net`'s file (or a
    training checkpoint); InputError naming the file when it is missing or not one."""
    from ..checkpoint import load_network

    def build(ckpt):
        net = LandmarkNet(LandmarkConfig.from_dict(ckpt["config"]))
        net.load_state_dict(ckpt["state"] if "state" in ckpt else ckpt["net"])
        net.meta = dict(ckpt.get("meta", {}))
        return net

    return load_network(path, build, "landmark network weights not found",
                        "not a landmark network file")


def points_in_crop_px(q, resolution: int):
    """Crop-normalised coordinates -> crop px (numpy arrays or tensors)."""
    return (q + 1) * resolution / 2 - 0.5

