"""Small auxiliary networks of the GAR losses, all on (B, 3, H, W) images in [-1, 1]:

- :class:`NormalNet` N: image -> unit normals (B, 3, H, W), camera frame;
- :class:`MaskNet` P: image -> face-mask probability (B, 1, H, W);
- :class:`LandmarkNet` L: image -> 68 heatmap logits (B, 68, H, W) and, by a soft-argmax,
  landmarks (B, 68, 2) in pixels (x right, y down, 0-based pixel centres);
- :class:`IdentityNet` R: image -> unit identity embedding (B, D).

N, P and L share a small U-Net; R is its encoder with global pooling. They are sized for
64 px training on a CPU (``width`` 16: about 0.1-0.4 M parameters each).

Examples
--------
>>> import torch
>>> x = torch.zeros(2, 3, 64, 64)
>>> NormalNet()(x).shape, MaskNet()(x).shape, LandmarkNet().landmarks(x).shape
(torch.Size([2, 3, 64, 64]), torch.Size([2, 1, 64, 64]), torch.Size([2, 68, 2]))
>>> bool(torch.allclose(IdentityNet()(x).norm(dim=1), torch.ones(2)))
True
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["UNet", "Encoder", "NormalNet", "MaskNet", "LandmarkNet", "IdentityNet", "NETS",
           "soft_argmax"]


def _conv(a, b):
    return nn.Sequential(nn.Conv2d(a, b, 3, padding=1), nn.GroupNorm(min(8, b), b),
                         nn.LeakyReLU(0.2))


class Encoder(nn.Module):
    """``depth`` stages of two 3x3 convs, each stage after the first halving the size;
    widths ``width * 2**i``. Returns the list of stage outputs, finest first."""

    def __init__(self, width=16, depth=4, in_channels=3):
        super().__init__()
        chans = [width * 2 ** i for i in range(depth)]
        self.stages = nn.ModuleList(
            nn.Sequential(_conv(a, b), _conv(b, b)) for a, b in zip([in_channels] + chans, chans))

    def forward(self, x):
        feats = []
        for i, stage in enumerate(self.stages):
            x = stage(F.avg_pool2d(x, 2) if i else x)
            feats.append(x)
        return feats


class UNet(nn.Module):
    """Encoder + decoder with skip connections: (B, 3, H, W) -> (B, out_channels, H, W);
    H and W must be divisible by ``2 ** (depth - 1)``."""

    def __init__(self, out_channels, width=16, depth=4):
        super().__init__()
        self.encoder = Encoder(width, depth)
        chans = [width * 2 ** i for i in range(depth)]
        self.up = nn.ModuleList(_conv(chans[i + 1] + chans[i], chans[i]) for i in range(depth - 1))
        self.head = nn.Conv2d(width, out_channels, 1)

    def forward(self, x):
        feats = self.encoder(x)
        y = feats[-1]
        for i in reversed(range(len(self.up))):
            y = F.interpolate(y, size=feats[i].shape[-2:], mode="bilinear", align_corners=False)
            y = self.up[i](torch.cat([y, feats[i]], 1))
        return self.head(y)


def soft_argmax(heatmaps: torch.Tensor) -> torch.Tensor:
    """Heatmap logits (B, K, H, W) -> expected pixel positions (B, K, 2) as (x, y), 0-based
    pixel centres, under a softmax over each map (differentiable)."""
    B, K, H, W = heatmaps.shape
    p = heatmaps.flatten(2).softmax(-1).reshape(B, K, H, W)
    xs = torch.arange(W, dtype=p.dtype, device=p.device)
    ys = torch.arange(H, dtype=p.dtype, device=p.device)
    return torch.stack([(p.sum(2) * xs).sum(-1), (p.sum(3) * ys).sum(-1)], -1)


class NormalNet(nn.Module):
    """N: image (B, 3, H, W) -> unit normals (B, 3, H, W) in the camera frame."""

    def __init__(self, width=16):
        super().__init__()
        self.net = UNet(3, width)

    def forward(self, image):
        return F.normalize(self.net(image), dim=1, eps=1e-6)


class MaskNet(nn.Module):
    """P: image (B, 3, H, W) -> face-mask probability (B, 1, H, W) in [0, 1]."""

    def __init__(self, width=16):
        super().__init__()
        self.net = UNet(1, width)

    def logits(self, image):
        return self.net(image)

    def forward(self, image):
        return torch.sigmoid(self.net(image))


class LandmarkNet(nn.Module):
    """L: image (B, 3, H, W) -> 68 heatmap logits (B, 68, H, W); :meth:`landmarks` gives
    (B, 68, 2) pixel positions by soft-argmax."""

    def __init__(self, width=16, n_landmarks=68):
        super().__init__()
        self.net = UNet(n_landmarks, width)

    def forward(self, image):
        return self.net(image)

    def landmarks(self, image):
        return soft_argmax(self(image))


class IdentityNet(nn.Module):
    """R: image (B, 3, H, W) -> unit identity embedding (B, dim)."""

    def __init__(self, width=16, dim=128):
        super().__init__()
        self.encoder = Encoder(width, 5)
        self.fc = nn.Linear(width * 16, dim, bias=False)
        # centring the embeddings keeps them from collapsing onto one shared direction
        # (pooled features of all faces are alike) before normalisation
        self.norm = nn.BatchNorm1d(dim, affine=False)

    def forward(self, image):
        f = self.encoder(image)[-1].mean(dim=(2, 3))
        return F.normalize(self.norm(self.fc(f)), dim=1, eps=1e-6)


NETS = {"N": NormalNet, "P": MaskNet, "L": LandmarkNet, "R": IdentityNet}
