"""The Generative Adversarial Renderer: ``image = G(normals, z, noise)`` and its discriminator.

Architecture (paper Sec. 3.1, StyleGAN2 building blocks):

- :class:`MappingNetwork` ``M``: pixel-normalised ``z`` -> 8 equalised-lr linear layers -> ``w``.
- :class:`RenderBlock`, one per resolution 4, 8, ..., R: twice
  ``[upsample] -> ModulatedConv2d 3x3 (modulated + demodulated by w) -> NormalInjection
  -> + bias + scaled Gaussian noise -> leaky ReLU``, then a :class:`ToRGB` whose output is
  added to the upsampled RGB of the previous block (skip architecture).
- :class:`Discriminator`: StyleGAN2 residual discriminator with a minibatch-std layer.

Shapes are batch first: images (B, 3, R, R) in about [-1, 1], normal maps (B, 3, H, W)
camera-frame unit vectors (zero in the background; any H, W, resized per block),
latents (B, z_dim). Upsampling and downsampling are bilinear / average pooling rather than
StyleGAN2's FIR filters, to keep the forward passes short and readable.

Examples
--------
>>> import torch
>>> from neural.gar.config import get_config
>>> cfg = get_config("tiny")
>>> G, D = Generator(cfg), Discriminator(cfg)
>>> n = torch.zeros(2, 3, 64, 64); n[:, 2] = 1.0
>>> img = G(n, torch.randn(2, cfg.z_dim))
>>> img.shape, D(img).shape
(torch.Size([2, 3, 64, 64]), torch.Size([2, 1]))
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ..checkpoint import load_network
from .config import GARConfig

__all__ = ["MappingNetwork", "ModulatedConv2d", "NormalInjection", "NoiseInjection",
           "RenderBlock", "ToRGB", "Generator", "Discriminator", "MinibatchStd",
           "resize_normals", "load_generator"]


def lrelu(x: torch.Tensor) -> torch.Tensor:
    """Leaky ReLU (slope 0.2) scaled by sqrt(2) to keep unit variance (StyleGAN2)."""
    return F.leaky_relu(x, 0.2) * math.sqrt(2.0)


def resize_normals(normals: torch.Tensor, size: int) -> torch.Tensor:
    """(B, 3, H, W) -> (B, 3, size, size); area averaging when shrinking keeps the zero
    background zero and blends the silhouette."""
    if normals.shape[-2:] == (size, size):
        return normals
    mode = "area" if size <= min(normals.shape[-2:]) else "bilinear"
    kwargs = {} if mode == "area" else {"align_corners": False}
    return F.interpolate(normals, size=(size, size), mode=mode, **kwargs)


class EqualLinear(nn.Module):
    """Linear layer with equalised learning rate: weights stored ~N(0, 1/lr_mul), scaled at
    run time by ``lr_mul / sqrt(in_features)``."""

    def __init__(self, in_features, out_features, bias_init=0.0, lr_mul=1.0, activation=False):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(out_features, in_features) / lr_mul)
        self.bias = nn.Parameter(torch.full((out_features,), float(bias_init)))
        self.scale = lr_mul / math.sqrt(in_features)
        self.lr_mul = lr_mul
        self.activation = activation

    def forward(self, x):
        y = F.linear(x, self.weight * self.scale, self.bias * self.lr_mul)
        return lrelu(y) if self.activation else y


class EqualConv2d(nn.Module):
    """Conv2d with equalised learning rate ('same' padding)."""

    def __init__(self, in_channels, out_channels, kernel_size, bias=True):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(out_channels, in_channels, kernel_size, kernel_size))
        self.bias = nn.Parameter(torch.zeros(out_channels)) if bias else None
        self.scale = 1.0 / math.sqrt(in_channels * kernel_size ** 2)
        self.padding = kernel_size // 2

    def forward(self, x):
        return F.conv2d(x, self.weight * self.scale, self.bias, padding=self.padding)


def pixel_norm(z):
    """(B, D) -> each row scaled to unit mean square: M's first operation, so G depends on
    ``z`` only through ``pixel_norm(z)`` (its direction)."""
    return z * torch.rsqrt(z.pow(2).mean(dim=1, keepdim=True) + 1e-8)


class MappingNetwork(nn.Module):
    """M: z (B, z_dim) -> w (B, w_dim), ``n_layers`` leaky-ReLU MLP layers (paper: 8)."""

    def __init__(self, z_dim=512, w_dim=512, n_layers=8, lr_mul=0.01):
        super().__init__()
        dims = [z_dim] + [w_dim] * n_layers
        self.layers = nn.Sequential(*[EqualLinear(a, b, lr_mul=lr_mul, activation=True)
                                      for a, b in zip(dims[:-1], dims[1:])])

    def forward(self, z):
        return self.layers(pixel_norm(z))


class ModulatedConv2d(nn.Module):
    """StyleGAN2 modulated convolution, one kernel per sample.

    With style ``s = A(w)`` (B, C_in) from a learned affine map (bias 1) the kernel is
    ``k'_{o,c,i,j} = s_c k_{o,c,i,j}`` and, when ``demodulate``,
    ``k''_{o,c,i,j} = k'_{o,c,i,j} / sqrt(sum_{c,i,j} k'^2_{o,c,i,j} + eps)``, so that unit-variance
    i.i.d. inputs give unit-variance outputs. ``upsample`` doubles the input bilinearly first.
    """

    def __init__(self, in_channels, out_channels, kernel_size, w_dim, demodulate=True,
                 upsample=False, eps=1e-8):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(out_channels, in_channels, kernel_size, kernel_size))
        self.scale = 1.0 / math.sqrt(in_channels * kernel_size ** 2)
        self.affine = EqualLinear(w_dim, in_channels, bias_init=1.0)
        self.demodulate, self.upsample, self.eps = demodulate, upsample, eps
        self.padding = kernel_size // 2

    def kernels(self, w: torch.Tensor) -> torch.Tensor:
        """(B, w_dim) -> per-sample kernels (B, C_out, C_in, k, k)."""
        style = self.affine(w)                                            # (B, C_in)
        k = self.weight[None] * self.scale * style[:, None, :, None, None]
        if self.demodulate:
            k = k * torch.rsqrt(k.pow(2).sum(dim=(2, 3, 4), keepdim=True) + self.eps)
        return k

    def forward(self, x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """x (B, C_in, H, W), w (B, w_dim) -> (B, C_out, H', W') (H' = 2H when upsampling)."""
        if self.upsample:
            x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)
        B, C, H, W = x.shape
        k = self.kernels(w)
        # a grouped convolution runs the B different kernels in one call
        y = F.conv2d(x.reshape(1, B * C, H, W), k.reshape(-1, C, *k.shape[-2:]),
                     padding=self.padding, groups=B)
        return y.reshape(B, -1, H, W)


class NormalInjection(nn.Module):
    """Normal Injection Module: multiplies the features per pixel by the normal map.

    Mapping from 3 normal channels to L feature channels (our choice, the paper leaves it
    open): a learned 1x1 projection ``P`` (L, 3) without bias, plus (``background=True``) a
    learned per-channel gain ``b`` (L,) where the normal map is empty,

    ``f''_{l,x,y} = f'_{l,x,y} * (sum_k P_{l,k} n_{k,x,y} + b_l (1 - |n_{x,y}|^2))``

    where ``n`` is the normal map resized to the feature resolution. On the face (unit
    normals) it is linear in ``n``, so flipping ``n`` flips the injected features. Without
    ``b`` a zero normal (the background) gives exactly zero features at every layer, which
    leaves hair, neck and scene nothing but the noise inputs to be drawn from (the generators
    trained before the option, whose samples show a cloudy texture around a bare face mask);
    with ``b`` (starting at 1) the background features pass on, styled by the latent.
    ``1 - |n|^2`` rather than ``1 - |n|`` because a norm has no gradient at zero, and the
    refinement differentiates through ``n``. ``P`` starts with N(0, 1) entries so that ``P n``
    has unit variance per channel for any unit normal (Var = sum_k n_k^2 Var P = 1), which
    keeps the activations at unit scale through the blocks, on the face and (b = 1) off it.
    """

    def __init__(self, channels: int, background: bool = True):
        super().__init__()
        self.projection = nn.Parameter(torch.randn(channels, 3))
        self.background = nn.Parameter(torch.ones(channels)) if background else None

    def normal_features(self, normals: torch.Tensor, size: int) -> torch.Tensor:
        """(B, 3, H, W) -> ``P n`` (+ ``b (1 - |n|^2)``) (B, L, size, size)."""
        n = resize_normals(normals, size)
        p = torch.einsum("lk,bkxy->blxy", self.projection, n)
        if self.background is None:
            return p
        empty = (1.0 - (n * n).sum(1, keepdim=True)).clamp(min=0.0)
        return p + self.background[:, None, None] * empty

    def forward(self, features: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """features (B, L, h, h), normals (B, 3, H, W) -> (B, L, h, h)."""
        return features * self.normal_features(normals, features.shape[-1])


class NoiseInjection(nn.Module):
    """Adds per-pixel Gaussian noise (B, 1, h, w) times a learned per-layer strength (init 0)."""

    def __init__(self):
        super().__init__()
        self.strength = nn.Parameter(torch.zeros(()))

    def forward(self, x, noise=None):
        if noise is None:
            noise = torch.randn(x.shape[0], 1, *x.shape[-2:], device=x.device, dtype=x.dtype)
        return x + self.strength * noise


class ToRGB(nn.Module):
    """1x1 modulated (not demodulated) convolution to RGB, plus the upsampled previous RGB."""

    def __init__(self, in_channels, w_dim):
        super().__init__()
        self.conv = ModulatedConv2d(in_channels, 3, 1, w_dim, demodulate=False)
        self.bias = nn.Parameter(torch.zeros(1, 3, 1, 1))

    def forward(self, x, w, skip=None):
        rgb = self.conv(x, w) + self.bias
        if skip is not None:
            rgb = rgb + F.interpolate(skip, scale_factor=2, mode="bilinear", align_corners=False)
        return rgb


class RenderBlock(nn.Module):
    """One resolution of the generator: two styled layers, each
    ``modulated conv 3x3 -> NormalInjection -> + bias + noise -> leaky ReLU``, then ToRGB.
    The first convolution upsamples x2 unless ``upsample=False`` (the 4x4 block);
    ``background`` is :class:`NormalInjection`'s."""

    n_styles = 3   # conv0, conv1, to_rgb
    n_noises = 2

    def __init__(self, in_channels, out_channels, w_dim, upsample=True, background=True):
        super().__init__()
        self.conv0 = ModulatedConv2d(in_channels, out_channels, 3, w_dim, upsample=upsample)
        self.conv1 = ModulatedConv2d(out_channels, out_channels, 3, w_dim)
        self.nim0 = NormalInjection(out_channels, background)
        self.nim1 = NormalInjection(out_channels, background)
        self.bias0 = nn.Parameter(torch.zeros(1, out_channels, 1, 1))
        self.bias1 = nn.Parameter(torch.zeros(1, out_channels, 1, 1))
        self.noise0, self.noise1 = NoiseInjection(), NoiseInjection()
        self.to_rgb = ToRGB(out_channels, w_dim)

    def forward(self, x, rgb, normals, ws, noise=(None, None)):
        """x (B, C_in, h, h), rgb (B, 3, h, h) or None, normals (B, 3, H, W),
        ws (B, 3, w_dim) -> x (B, C_out, h', h'), rgb (B, 3, h', h')."""
        x = self.conv0(x, ws[:, 0])
        x = lrelu(self.noise0(self.nim0(x, normals) + self.bias0, noise[0]))
        x = self.conv1(x, ws[:, 1])
        x = lrelu(self.noise1(self.nim1(x, normals) + self.bias1, noise[1]))
        return x, self.to_rgb(x, ws[:, 2], rgb)


class Generator(nn.Module):
    """G(n, z, eps): normal map + latent (+ per-layer noise) -> image (B, 3, R, R).

    Parameters
    ----------
    config : :class:`neural.gar.config.GARConfig` (resolution, latent sizes, channels).
    """

    def __init__(self, config):
        super().__init__()
        self.config = config
        self.mapping = MappingNetwork(config.z_dim, config.w_dim, config.mapping_layers,
                                      config.mapping_lr_mul)
        res = config.resolutions
        self.input = nn.Parameter(torch.randn(1, config.channels(4), 4, 4))
        self.blocks = nn.ModuleList(
            RenderBlock(config.channels(r // 2) if r > 4 else config.channels(4),
                        config.channels(r), config.w_dim, upsample=r > 4,
                        background=config.nim_background) for r in res)
        self.register_buffer("w_avg", torch.zeros(config.w_dim))

    @property
    def n_ws(self) -> int:
        return RenderBlock.n_styles * len(self.blocks)

    def make_noise(self, batch: int, generator: torch.Generator | None = None) -> list:
        """Per-layer noise maps eps: a list of (batch, 1, r, r) tensors, two per block."""
        from ..training import to_device

        # drawn on the CPU so that a CPU generator gives the same maps on any device; copied
        # without making the host wait for the GPU (pinned memory, asynchronous)
        return [to_device(torch.randn(batch, 1, r, r, generator=generator), self.input.device)
                for r in self.config.resolutions for _ in range(RenderBlock.n_noises)]

    def synthesis(self, normals: torch.Tensor, w: torch.Tensor, noise=None) -> torch.Tensor:
        """normals (B, 3, H, W), w (B, w_dim) or (B, n_ws, w_dim), noise None (fresh random),
        "zero", or a list from :meth:`make_noise` -> image (B, 3, R, R)."""
        B = normals.shape[0]
        if w.dim() == 2:
            w = w[:, None].expand(B, self.n_ws, w.shape[-1])
        if noise is None:
            noise = [None] * (2 * len(self.blocks))
        elif isinstance(noise, str) and noise == "zero":
            noise = [torch.zeros(())] * (2 * len(self.blocks))
        x, rgb = self.input.expand(B, -1, -1, -1), None
        for i, block in enumerate(self.blocks):
            ws = w[:, 3 * i: 3 * i + 3]
            x, rgb = block(x, rgb, normals, ws, noise[2 * i: 2 * i + 2])
        return rgb

    def forward(self, normals: torch.Tensor, z: torch.Tensor, noise=None,
                truncation: float = 1.0) -> torch.Tensor:
        """normals (B, 3, H, W), z (B, z_dim) -> image (B, 3, R, R) in about [-1, 1].

        ``truncation`` < 1 pulls w towards the running average ``w_avg`` (updated in
        training mode)."""
        w = self.mapping(z)
        if self.training:
            with torch.no_grad():
                # (w is bfloat16 under autocast; the running mean stays float32)
                self.w_avg.lerp_(w.detach().float().mean(0), 0.005)
        if truncation != 1.0:
            w = self.w_avg + truncation * (w - self.w_avg)
        return self.synthesis(normals, w, noise)


class MinibatchStd(nn.Module):
    """Appends the standard deviation across groups of ``group_size`` samples, averaged
    over channels and pixels, as one extra feature channel (StyleGAN2)."""

    def __init__(self, group_size=4):
        super().__init__()
        self.group_size = group_size

    def forward(self, x):
        B, C, H, W = x.shape
        g = min(self.group_size, B)
        while B % g:
            g -= 1
        y = x.reshape(g, B // g, C, H, W)
        y = (y.var(dim=0, unbiased=False) + 1e-8).sqrt().mean(dim=(1, 2, 3))   # (B // g,)
        y = y.repeat(g).reshape(B, 1, 1, 1).expand(B, 1, H, W)
        return torch.cat([x, y], dim=1)


class DiscriminatorBlock(nn.Module):
    """Residual block: conv 3x3, conv 3x3, average-pool /2; skip: pool /2, 1x1 conv;
    the sum is scaled by 1/sqrt(2)."""

    def __init__(self, in_channels, out_channels):
        super().__init__()
        self.conv0 = EqualConv2d(in_channels, in_channels, 3)
        self.conv1 = EqualConv2d(in_channels, out_channels, 3)
        self.skip = EqualConv2d(in_channels, out_channels, 1, bias=False)

    def forward(self, x):
        y = F.avg_pool2d(lrelu(self.conv1(lrelu(self.conv0(x)))), 2)
        return (y + self.skip(F.avg_pool2d(x, 2))) / math.sqrt(2.0)


class Discriminator(nn.Module):
    """StyleGAN2 residual discriminator: image (B, 3, R, R) -> realness logit (B, 1)."""

    def __init__(self, config):
        super().__init__()
        ch = config.channels
        R = config.resolution
        self.from_rgb = EqualConv2d(3, ch(R), 1)
        self.blocks = nn.Sequential(*[DiscriminatorBlock(ch(r), ch(r // 2))
                                      for r in reversed(config.resolutions[1:])])
        self.mbstd = MinibatchStd()
        self.conv = EqualConv2d(ch(4) + 1, ch(4), 3)
        self.fc = EqualLinear(ch(4) * 16, ch(4), activation=True)
        self.out = EqualLinear(ch(4), 1)

    def forward(self, image):
        x = lrelu(self.from_rgb(image))
        x = self.blocks(x)
        x = lrelu(self.conv(self.mbstd(x)))
        return self.out(self.fc(x.flatten(1)))


def load_generator(path, ema: bool = True):
    """A :class:`neural.gar.networks.Generator` (eval mode) from ``generator.pt`` or ``checkpoint.pt``
    of :mod:`neural.gar.train`; from a checkpoint, ``ema=False`` takes the raw generator instead
    of its moving average."""
    def build(ckpt):
        G = Generator(GARConfig.from_dict(ckpt["config"]))
        G.load_state_dict(ckpt["G_ema"] if ema and "G_ema" in ckpt else ckpt["G"])
        return G

    return load_network(path, build, "generator weights not found", "not a GAR checkpoint")
