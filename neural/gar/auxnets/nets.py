"""Small auxiliary networks of the GAR losses, all on (B, 3, H, W) images in [-1, 1]:

- :class:`NormalNet` N: image -> unit normals (B, 3, H, W), camera frame;
- :class:`MaskNet` P: image -> face-mask probability (B, 1, H, W);
- :class:`LandmarkNet` L: image -> 68 heatmap logits (B, 68, H, W) and, by a soft-argmax,
  landmarks (B, 68, 2) in pixels (x right, y down, 0-based pixel centres);
- :class:`IdentityNet` R: image -> unit identity embedding (B, D).

N, P and L share a small U-Net; R is its encoder with a 4x4 pooled head. They are sized for
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
        """(B, 68, 2) pixel positions: the soft-argmax of each heatmap."""
        return soft_argmax(self(image))


class IdentityNet(nn.Module):
    """R: image (B, 3, H, W) -> unit identity embedding (B, dim).

    :meth:`predict` regresses the face's identity labels of the synthetic renders, all in
    units of their standard deviation: the skin tone, then the leading ``dim - 1`` 3DMM
    identity coefficients; the embedding is that prediction scaled to unit length. The labels
    of different people are independent and zero-mean, so unrelated faces have cosine near 0
    and two views of one face near 1, without a metric-learning objective (a classifier over
    a finite pool of synthetic identities did not generalise to unseen ones). At 64 px a 1σ
    change of an SFM shape mode moves the landmarks by only 0.1-0.5 px after the FFHQ-style
    framing, so there the embedding is mostly the tone.
    """

    def __init__(self, width=16, dim=16):
        super().__init__()
        self.encoder = Encoder(width, 5)
        self.fc = nn.Sequential(nn.Linear(width * 16 * 16, 128), nn.LeakyReLU(0.2),
                                nn.Linear(128, dim))

    def predict(self, image):
        """(B, 3, H, W) -> (B, dim) standardised skin tone and identity coefficients."""
        # a 4x4 grid of the last features, not a global mean: identity is in the face's
        # layout (outline, proportions), which global pooling discards
        f = F.adaptive_avg_pool2d(self.encoder(image)[-1], 4)
        return self.fc(f.flatten(1))

    def forward(self, image):
        return F.normalize(self.predict(image), dim=1, eps=1e-6)


NETS = {"N": NormalNet, "P": MaskNet, "L": LandmarkNet, "R": IdentityNet}
