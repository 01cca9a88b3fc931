"""Configurations of the GAR: ``tiny`` (64x64, trains on 2 CPU cores), ``tiny-gpu`` (the same
network, sized for a few minutes on one large GPU), ``tiny128-gpu`` (128x128, one more
block, for the same GPU) and ``base`` (256x256, documented for a GPU). A config is a plain
dataclass; checkpoints store it as a dict.

Examples
--------
>>> cfg = get_config("tiny")
>>> cfg.resolution, cfg.channels(4), cfg.channels(64)
(64, 128, 32)
>>> get_config("base").channels(256)
64
>>> get_config("tiny", steps=10).steps
10
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

__all__ = ["GARConfig", "CONFIGS", "get_config"]


@dataclass(frozen=True)
class GARConfig:
    """Every hyper-parameter of one GAR setup (sizes in pixels, angles in degrees).

    .. rubric:: Network

    resolution : output image side (power of two, >= 8); blocks run 4, 8, ..., resolution.
    z_dim, w_dim : latent sizes; mapping_layers : depth of the mapping MLP (paper: 8).

    channel_base, channel_max : feature channels at resolution r are
        ``min(channel_max, channel_base // r)`` (StyleGAN2's rule), for G and D alike.

    aux_width : base width of the auxiliary networks N, P, L, R.

    aux_resolution : side (px) of the images the auxiliary networks take; G's renders and
        the normal maps are area-downsampled to it for L_n, L_ldmk and L_id (a 128-px G
        trained with the 64-px aux networks). None (default): ``resolution``.

    nim_background : the Normal Injection Module's background gain
        (:class:`neural.gar.networks.NormalInjection`): True lets features pass where the normal map
        is empty (hair, neck, scene); False zeroes them there, as the generators trained
        before the option did (their saved configs load as False).

    .. rubric:: Losses (paper defaults)

    lambda_n = 2, lambda_ldmk = 2, lambda_id = 1, lambda_adv = 1; ``r1_gamma`` weights the R1
    penalty, applied every ``r1_every`` discriminator steps (lazy regularisation).
    contrastive_every : the landmark and identity contrastive terms in every k-th generator
    step only, weighted k (lazy, as R1 is: the same objective in expectation). Those terms
    render 2B of a step's 3B images, so k = 4 makes a CPU step 1.5-1.7x as fast
    (docs/neural.md); 1 (default) computes them in every step.
    landmark_set : the landmarks L_ldmk compares: ``"model"`` (those the 3DMM defines, SFM:
    50 of 68), ``"all"`` (68) or ``"auto"``: the model's on synthetic data; on real photos
    the list the L network's checkpoint states (``meta["landmark_index"]``), else the model's
    for an L trained on synthetic renders (``meta["training_data"]`` ``SyntheticFaces...``,
    which has not learnt the other points), else all 68.

    .. rubric:: Discriminator augmentation

    augment : DiffAugment policy (:mod:`neural.augment`), e.g. ``"color,translation,cutout"``;
    ``""`` off; ``None`` (default): on with all three for real photos (``--data``), off on
    synthetic renders.

    .. rubric:: Data

    model : 3DMM of the synthetic faces; yaw_max, pitch_max, roll_max : uniform pose ranges;
    identity_std : spread of identity coefficients; expression_max : upper bound of
    blendshape weights (or PCA std) of random expressions.
    """

    name: str = "tiny"
    resolution: int = 64
    z_dim: int = 128
    w_dim: int = 128
    mapping_layers: int = 8
    mapping_lr_mul: float = 0.01
    channel_base: int = 2048
    channel_max: int = 128
    aux_width: int = 8
    aux_resolution: int | None = None
    nim_background: bool = True
    # optimisation
    batch_size: int = 8
    g_lr: float = 2e-3
    d_lr: float = 2e-3
    betas: tuple = (0.0, 0.99)
    r1_gamma: float = 1.0
    r1_every: int = 16
    contrastive_every: int = 1
    lambda_n: float = 2.0
    lambda_ldmk: float = 2.0
    lambda_id: float = 1.0
    lambda_adv: float = 1.0
    landmark_set: str = "auto"
    augment: str | None = None
    steps: int = 4000
    sample_every: int = 200
    checkpoint_every: int = 200
    print_every: int = 100
    seed: int = 0
    # synthetic data
    model: str = "sfm"
    yaw_max: float = 45.0
    pitch_max: float = 20.0
    roll_max: float = 10.0
    identity_std: float = 1.0
    expression_max: float = 0.8

    def __post_init__(self):
        r = self.resolution
        if r < 8 or r & (r - 1):
            raise ValueError(f"config {self.name!r}: resolution must be a power of two >= 8, got {r}")
        a = self.aux_size
        if a < 8 or a > r or r % a:
            raise ValueError(f"config {self.name!r}: aux_resolution must divide resolution "
                             f"{r} and be >= 8, got {a}")
        if self.contrastive_every < 1:
            raise ValueError(f"config {self.name!r}: contrastive_every must be >= 1, got "
                             f"{self.contrastive_every}")
        if self.landmark_set not in ("auto", "model", "all"):
            raise ValueError(f"config {self.name!r}: landmark_set must be auto, model or all, "
                             f"got {self.landmark_set!r}")

    @property
    def aux_size(self) -> int:
        """Side (px) of the auxiliary networks' input: ``aux_resolution`` or ``resolution``."""
        return int(self.aux_resolution or self.resolution)

    def channels(self, resolution: int) -> int:
        """Feature channels of the block at ``resolution`` pixels."""
        return int(min(self.channel_max, self.channel_base // resolution))

    @property
    def resolutions(self) -> list:
        """Block resolutions of the generator, 4 ... resolution."""
        out, r = [], 4
        while r <= self.resolution:
            out.append(r)
            r *= 2
        return out

    @property
    def lambdas(self) -> dict:
        return {"n": self.lambda_n, "ldmk": self.lambda_ldmk, "id": self.lambda_id,
                "adv": self.lambda_adv}

    def to_dict(self) -> dict:
        d = asdict(self)
        d["betas"] = list(self.betas)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "GARConfig":
        known = {f.name for f in fields(cls)}
        d = {k: v for k, v in d.items() if k in known}
        if "betas" in d:
            d["betas"] = tuple(d["betas"])
        # saved before the option existed: their generators have no background gain
        d.setdefault("nim_background", False)
        return cls(**d)


CONFIGS = {
    "tiny": GARConfig(),
    # tiny's network (so its weights load wherever tiny's do) for one H200-class GPU in about
    # 7 minutes: batch 64, 5000 steps is an estimate of the throughput, not a measurement
    # (neural/gar/README.md); R1 gamma by StyleGAN2-ADA's rule 0.0002 R^2 / batch
    "tiny-gpu": GARConfig(name="tiny-gpu", batch_size=64, r1_gamma=0.0128, steps=5000,
                          sample_every=1000, checkpoint_every=1000, print_every=100),
    # 128 px with Normal Injection at each of its six resolutions: channel_base doubled so
    # that the 64 and 128 px blocks keep 64 and 32 channels (tiny's last two widths); the
    # committed 64-px aux networks judge its renders area-downsampled; R1 gamma by the same
    # rule, 0.0002 * 128^2 / 64
    "tiny128-gpu": GARConfig(name="tiny128-gpu", resolution=128, channel_base=4096,
                             aux_resolution=64, batch_size=64, r1_gamma=0.0512, steps=5000,
                             sample_every=1000, checkpoint_every=1000, print_every=100),
    # StyleGAN2 256x256 channel schedule: 512 up to 32 px, then 256, 128, 64
    "base": GARConfig(name="base", resolution=256, z_dim=512, w_dim=512, channel_base=16384,
                      channel_max=512, aux_width=32, batch_size=16, g_lr=2e-3, d_lr=2e-3,
                      r1_gamma=1.0, steps=200_000, sample_every=1000, checkpoint_every=5000),
}


def get_config(name: str = "tiny", **overrides) -> GARConfig:
    """The named config with some fields replaced (``get_config("tiny", steps=10)``)."""
    if name not in CONFIGS:
        raise ValueError(f"unknown GAR config {name!r}; choose from {', '.join(CONFIGS)}")
    return replace(CONFIGS[name], **overrides)
