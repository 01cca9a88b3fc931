"""The ``gar`` renderer plugin: the Generative Adversarial Renderer behind the interface of
:mod:`morphable.renderer_plugins` (entry point ``morphable.renderers: gar``), with its inversion
hooks.

Weights: ``weights=`` (a ``generator.pt`` / ``checkpoint.pt`` of :mod:`neural.gar.train`), else
``$MORPHABLE_GAR_WEIGHTS``, else the committed ``neural/gar/weights/gar_tiny.pt``
(:mod:`neural.checkpoint`). Without any, construction fails with an InputError unless
``allow_untrained=True`` (then an untrained generator of ``config``, useful for tests and
shapes only). ``inverter=``: the inverting network V that starts an inversion's latent
("auto": the inverter beside the generator's weights file, ``inverter_<tag>.pt`` for
``gar_<tag>.pt`` and ``inverter_tiny.pt`` for other names, else the committed file of that
name, if present; None: none; a path or an
:class:`neural.gar.inverter.Inverter`). ``photometric_region``: the pixels an inversion's
photometric terms compare, "crop" (all: G renders a background too) or "face" (the fitted
face's coverage, as the classical renderer).

Appearance: ``z`` (B, z_dim) latent, ``noise`` list of per-layer maps eps (B, 1, r, r) as
from ``Generator.make_noise`` (zeros by default).

Examples
--------
>>> import torch
>>> r = GARRenderer(allow_untrained=True)
>>> n = torch.zeros(1, 3, 64, 64); n[:, 2] = 1.0
>>> r.render(n, r.default_appearance(1)).shape
torch.Size([1, 3, 64, 64])
"""
from __future__ import annotations

from pathlib import Path

import torch

from morphable.errors import InputError
from morphable.renderer_plugins import RendererBase

from .paths import WEIGHTS_ENV, companion_path, default_generator_path, inverter_name
from .networks import load_generator
from .config import get_config
from .networks import Generator
from .inverter import inverter_from

__all__ = ["GARRenderer"]


class GARRenderer(RendererBase):
    """G(n, z, eps) as a renderer: images in [0, 1] at ``resolution`` pixels.

    Inverted (:func:`morphable.refinement.refine`), it starts from ``z <- V(image)`` when it
    has an inverter V (else its default latent) and ``eps <- 0``, moves ``z`` and ``eps``,
    compares the whole crop (G renders a background too; ``photometric_region="face"``: the
    face only) and holds ``eps`` near 0 by the prior term ``eps`` = sum eps^2.
    """

    photometric_regions = ("crop", "face")

    learning_rates = {"z": 0.03, "noise": 0.03}

    def __init__(self, weights=None, allow_untrained: bool = False, config: str = "tiny",
                 seed: int = 0, inverter="auto", photometric_region: str = "crop"):
        if photometric_region not in self.photometric_regions:
            raise InputError(f"gar renderer: photometric_region {photometric_region!r}: choose "
                             f"from {', '.join(self.photometric_regions)}")
        self.photometric_region = photometric_region
        path = Path(weights) if weights else default_generator_path()
        if path is not None:
            self.generator = load_generator(path)
            self.weights = str(path)
        elif allow_untrained:
            torch.manual_seed(seed)
            self.generator = Generator(get_config(config)).eval().requires_grad_(False)
            self.weights = None
        else:
            raise InputError(f"gar renderer: no generator weights (pass weights=, set "
                             f"${WEIGHTS_ENV}, or train one: python -m neural.gar.train --config tiny)")
        self.resolution = self.generator.config.resolution
        self.seed = seed
        if isinstance(inverter, str) and inverter == "auto":
            # V trained against this generator: the inverter beside its weights file
            inverter = companion_path(self.weights, inverter_name(self.weights))
        self.inverter = inverter_from(inverter)

    @property
    def z_dim(self) -> int:
        return self.generator.config.z_dim

    def default_appearance(self, batch_size: int = 1) -> dict:
        """``z`` (B, z_dim) from a fixed seed, ``noise`` all zero."""
        g = torch.Generator().manual_seed(self.seed)
        return {"z": torch.randn(batch_size, self.z_dim, generator=g),
                "noise": [torch.zeros_like(e) for e in self.generator.make_noise(batch_size)]}

    def render(self, normal_map, appearance: dict):
        """(B, 3, H, W) normals -> (B, 3, R, R) image in [0, 1] (differentiable in the
        normals, ``z`` and ``noise``)."""
        if normal_map.dim() != 4 or normal_map.shape[1] != 3:
            raise InputError(f"normal map must be (B, 3, H, W), got {tuple(normal_map.shape)}")
        img = self.generator(normal_map.float(), appearance["z"], noise=appearance.get("noise"))
        return ((img + 1) / 2).clamp(0, 1)

    # --- inversion hooks (morphable.renderer_plugins.RendererBase) ---------------------------
    def initial_appearance(self, image, coverage, seed: int = 0) -> tuple[dict, str]:
        """``z`` = V's latent of ``image`` (1, 3, R, R) in [0, 1] (its prior part drawn with
        ``seed``) when the renderer has an inverter, else the default one; ``noise`` zero.
        The description names V's file."""
        app, _ = super().initial_appearance(image, coverage, seed)
        V = self.inverter
        if V is None:
            return app, "default"
        with torch.no_grad():
            app["z"] = V.latent(image * 2 - 1, generator=torch.Generator().manual_seed(seed))
        return app, f"inverter {V.source}" if getattr(V, "source", None) else "inverter"

    def photometric_mask(self, coverage):
        """The whole crop (G renders the background too), or ``coverage`` itself for
        ``photometric_region="face"``."""
        return coverage if self.photometric_region == "face" else torch.ones_like(coverage)

    def appearance_prior(self, appearance) -> dict:
        """``eps``: the squared noise maps, summed."""
        return {"eps": sum(e.pow(2).sum() for e in appearance["noise"])}

    @staticmethod
    def feature_network():
        """The encoder stages of the aux normal network N (:mod:`neural.gar.auxnets`): no VGG
        weights can be downloaded here."""
        from .auxnets import load_aux

        N = load_aux("N")
        return (lambda img: N.net.encoder(img * 2 - 1)), "aux N encoder (no VGG weights given)"

