"""The inverting network V (paper Sec. 3.2): image -> latent ``z`` of the GAR.

V's encoder mirrors the generator: a 1x1 fromRGB, then one block per generator resolution
R, ..., 8, 4 (two 3x3 convolutions with the channel count of the generator block of the same
resolution, then 2x average pooling), so the encoder feature ``R_i(I)`` has the shape of the
generator feature ``G_i(n, z)``. The per-channel mean and standard deviation of every
``R_i(I)`` are concatenated and an MLP as deep and wide as the mapping network M predicts
``z_hat``. Training loss, on ``I = G(n, z, eps)``:

``L_z = ||PN(z_hat) - PN(z)||^2 + sum_i ||G_i(n, z) - R_i(I)||^2``  (means over elements),

where ``PN`` is the pixel normalisation that the mapping network applies first: G sees only
the direction of ``z``, so its length cannot be recovered from an image and the paper's
``||z_hat - z||^2`` would spend V's capacity on it.

:meth:`Inverter.latent` is the latent to start a reconstruction from. V recovers only part of
``z``'s direction (the mean cosine ``c`` between ``PN(z_hat)`` and ``z``, measured after
training and stored in the network), and ``PN(z_hat)`` alone is an atypical latent (its energy
sits in the few directions V can see), which renders worse than a random one. So the latent is
``c PN(z_hat) + sqrt(1 - c^2) e`` with ``e ~ N(0, I)``: V's estimate where it knows, the prior
where it does not (for unit-variance Gaussians, the regression of ``z`` on ``PN(z_hat)``).

Examples
--------
>>> import torch
>>> from neural.gar.config import get_config
>>> from neural.gar.networks import Generator
>>> cfg = get_config("tiny")
>>> G, V = Generator(cfg), Inverter(cfg)
>>> n = torch.zeros(2, 3, 64, 64); n[:, 2] = 1.0
>>> img, g_feats = generator_features(G, n, torch.randn(2, cfg.z_dim), noise="zero")
>>> z_hat, v_feats = V(img)
>>> z_hat.shape, [f.shape[-1] for f in v_feats] == [f.shape[-1] for f in g_feats]
(torch.Size([2, 128]), True)
"""
from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn


from .paths import default_inverter_path
from ..checkpoint import load_network
from .config import GARConfig
from .networks import EqualConv2d, EqualLinear, lrelu, pixel_norm

__all__ = ["Inverter", "generator_features", "inverter_loss", "load_inverter", "save_inverter",
           "inverter_from"]


def generator_features(G, normals, z, noise=None):
    """Run G and keep each Render Block's output feature map.

    Returns (image (B, 3, R, R) in about [-1, 1], [G_i (B, C_r, r, r) for r = 4 ... R])."""
    w = G.mapping(z)
    B = normals.shape[0]
    w = w[:, None].expand(B, G.n_ws, w.shape[-1])
    if noise is None:
        noise = [None] * (2 * len(G.blocks))
    elif isinstance(noise, str) and noise == "zero":
        noise = [torch.zeros(())] * (2 * len(G.blocks))
    x, rgb, feats = G.input.expand(B, -1, -1, -1), None, []
    for i, block in enumerate(G.blocks):
        x, rgb = block(x, rgb, normals, w[:, 3 * i: 3 * i + 3], noise[2 * i: 2 * i + 2])
        feats.append(x)
    return rgb, feats


class Inverter(nn.Module):
    """V: image (B, 3, R, R) in [-1, 1] -> (z_hat (B, z_dim), [R_i (B, C_r, r, r), r = 4 ... R])."""

    def __init__(self, config: GARConfig):
        super().__init__()
        self.config = config
        ch, res = config.channels, config.resolutions
        self.from_rgb = EqualConv2d(3, ch(config.resolution), 1)
        blocks, c_in = [], ch(config.resolution)
        for r in reversed(res):
            blocks.append(nn.ModuleList([EqualConv2d(c_in, ch(r), 3), EqualConv2d(ch(r), ch(r), 3)]))
            c_in = ch(r)
        self.blocks = nn.ModuleList(blocks)
        dims = [2 * sum(ch(r) for r in res)] + [config.w_dim] * (config.mapping_layers - 1)
        self.mlp = nn.Sequential(*[EqualLinear(a, b, activation=True) for a, b in zip(dims[:-1], dims[1:])],
                                 EqualLinear(dims[-1], config.z_dim))
        # mean cosine of PN(z_hat) and z on renders of training normal maps (set after training)
        self.register_buffer("direction_cosine", torch.ones(()))

    def forward(self, image):
        x = lrelu(self.from_rgb(image))
        feats = []
        for i, (c0, c1) in enumerate(self.blocks):
            if i:
                x = F.avg_pool2d(x, 2)
            x = lrelu(c1(lrelu(c0(x))))
            feats.append(x)
        feats = feats[::-1]                                  # 4 ... R, the generator's order
        stats = [torch.cat([f.mean((2, 3)), (f.var((2, 3), unbiased=False) + 1e-8).sqrt()], 1)
                 for f in feats]
        return self.mlp(torch.cat(stats, 1)), feats

    def latent(self, image, generator=None):
        """(B, 3, R, R) in [-1, 1] -> (B, z_dim) the calibrated starting latent (see the
        module docstring); ``generator`` seeds the prior part."""
        z_hat, _ = self(image)
        c = float(self.direction_cosine.clamp(0, 1))
        # drawn on the CPU so that a CPU generator gives the same latent on any device
        prior = torch.randn(z_hat.shape, generator=generator).to(z_hat.device)
        return c * pixel_norm(z_hat) + (1 - c * c) ** 0.5 * prior


def inverter_loss(V, G, normals, z, noise="zero"):
    """L_z on a batch rendered here: (total, {"z": ..., "features": ...}) — scalars."""
    with torch.no_grad():
        image, g_feats = generator_features(G, normals, z, noise)
    z_hat, v_feats = V(image)
    lz = (pixel_norm(z_hat) - pixel_norm(z)).pow(2).mean()
    lf = sum((g - v).pow(2).mean() for g, v in zip(g_feats, v_feats))
    return lz + lf, {"z": lz.detach(), "features": lf.detach()}


def save_inverter(V, path, **meta) -> Path:
    """Write ``{"config", "state_dict", "meta"}`` atomically."""
    from morphable.io.atomic import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save({"config": V.config.to_dict(), "state_dict": V.state_dict(), "meta": meta}, tmp)
    return path


def load_inverter(path) -> Inverter:
    """An Inverter (eval mode, frozen) from :func:`save_inverter`'s file."""
    def build(ckpt):
        V = Inverter(GARConfig.from_dict(ckpt["config"]))
        V.load_state_dict(ckpt["state_dict"])
        V.meta = ckpt.get("meta", {})
        return V

    V = load_network(path, build, "inverter weights not found", "not an inverter checkpoint")
    V.source = str(path)    # named in the reports of the refinements it starts
    return V


def inverter_from(inverter) -> Inverter | None:
    """The Inverter that ``inverter`` names: "auto" (the committed one if present,
    :func:`neural.gar.paths.default_inverter_path`), None, a path or an Inverter; or None."""
    if isinstance(inverter, str) and inverter == "auto":
        inverter = default_inverter_path()
    if inverter is None:
        return None
    return inverter if isinstance(inverter, Inverter) else load_inverter(inverter)
