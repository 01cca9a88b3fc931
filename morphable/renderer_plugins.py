"""The renderer plugin interface and its discovery through entry points.

A renderer turns a face normal map (and appearance parameters) into an image,
differentiably. Implementations register under the entry-point group
``morphable.renderers`` (``name = package.module:Class``); ``morphable`` itself never imports
torch or a plugin until a renderer is asked for by name.

A renderer class is constructed with keyword options and provides::

    render(normal_map, appearance) -> image
        normal_map : (B, 3, H, W) torch tensor, unit normals in the camera frame
                     (OpenGL: +z towards the viewer), zero outside the face
        appearance : dict of tensors (renderer-specific: SH lighting and albedo for
                     "classical", latent z and noise for "gar")
        image      : (B, 3, H, W) torch tensor in [0, 1]
    default_appearance(batch_size) -> dict     # a starting point for optimisation
    resolution : int or None                   # the normal-map size it expects (None: any)

Inverting a renderer (:mod:`morphable.refinement`) asks it, through the hooks of
:class:`RendererBase` (defaults there; both plugins derive from it), where the appearance
starts (``initial_appearance``), which appearance tensors move and how fast
(``learning_rates``), which pixels the photometric terms compare (``photometric_mask``),
what prior the appearance has (``appearance_prior``), what keeps it valid after a step
(``constrain_appearance``), which perceptual features it offers (``feature_network``), which
loss weights it changes (``default_weights``), whether it solves its appearance in closed form
from the face pixels (``solve_appearance``: the classical renderer's albedo texture and SH
light; the GAR's latent moves by gradient steps instead) and how its appearance follows a new
view of the face (``view_appearance``). The refinement never asks which renderer it has.

The pixel views these two hooks take describe one frame's crop: ``resolution`` R, ``pixels``
(N,) flat indices into the R x R crop of the face pixels, their camera-frame unit ``normals``
(N, 3), image colours ``target`` (N, 3) in [0, 1], robust mask ``weight`` (N,) in [0, 1], UV
coordinates ``uv`` (N, 2) of the surface point each sees (None for a model without UVs) and
the ``model`` (:class:`morphable.refinement.geometry.PixelView`).
"""
from __future__ import annotations

import inspect
from importlib import metadata
from typing import Protocol, runtime_checkable

from .errors import InputError

__all__ = ["Renderer", "RendererBase", "GROUP", "available_renderers", "get_renderer",
           "plugin_feature_network"]

GROUP = "morphable.renderers"


@runtime_checkable
class Renderer(Protocol):
    """What a renderer provides (the module docstring says what each member takes and gives)."""

    resolution: int | None

    def render(self, normal_map, appearance): ...

    def default_appearance(self, batch_size: int = 1) -> dict: ...


class RendererBase:
    """The inversion hooks of a renderer, with their defaults: the appearance starts at
    ``default_appearance``, nothing of it moves, the photometric terms compare the face
    pixels, no prior, no constraint, no feature network. Appearance dicts hold (1, ...)
    tensors or lists of them (e.g. per-layer noise)."""

    resolution: int | None = None
    learning_rates: dict = {}
    """Adam learning rate of each appearance entry refinement optimises (others stay fixed)."""
    default_weights: dict = {}
    """Overrides of the refinement's loss weights for this renderer (the user's still win)."""
    pixelwise: bool = False
    """True when each output pixel depends only on its own normal and appearance pixels (no
    convolution): the refinement may then render the face pixels alone, as a (1, 3, 1, N)
    strip."""

    def solve_appearance(self, appearances, views) -> bool:
        """Solve the appearance of every frame in closed form given the geometry, in place:
        ``appearances`` the frames' dicts, ``views`` their pixel views (module docstring).
        Returns False (the default) when the renderer has no closed form: its
        ``learning_rates`` entries then move by gradient steps."""
        return False

    def view_appearance(self, appearance, view) -> dict:
        """The appearance of a frame for a new pixel ``view`` of the face (after its
        visibility is re-cast, or for :func:`morphable.refinement.edit`); default: unchanged."""
        return appearance

    def initial_appearance(self, image, coverage, seed: int = 0) -> tuple[dict, str | None]:
        """Where the appearance starts for ``image`` (1, 3, R, R) in [0, 1] with the fitted
        face's ``coverage`` (1, 1, R, R) in [0, 1] -> (appearance, how it was chosen, or None
        when the renderer has nothing to say). ``seed``: for a random start."""
        import torch

        return {k: (v.detach().clone() if torch.is_tensor(v) else [e.clone() for e in v])
                for k, v in self.default_appearance(1).items()}, None

    def photometric_mask(self, coverage):
        """(1, 1, R, R) weight of each pixel in the photometric terms, from the fitted face's
        ``coverage``: the face only, where the renderer draws no background of its own."""
        return coverage

    def appearance_prior(self, appearance) -> dict:
        """Named loss terms (scalar tensors) on the appearance; their weights are the
        refinement's loss weights of the same names."""
        return {}

    def constrain_appearance(self, appearance) -> None:
        """Bring the appearance back into its valid range after a step (in place)."""

    @staticmethod
    def feature_network():
        """A perceptual feature network ``image (B, 3, H, W) in [0, 1] -> list of feature
        maps`` and its name, or None. A renderer class may offer one without being
        constructed (:func:`plugin_feature_network`)."""
        return None


def _entry_points() -> dict:
    return {ep.name: ep for ep in metadata.entry_points(group=GROUP)}


def available_renderers() -> list[str]:
    """Names of the installed renderers (e.g. ``["classical", "gar"]``)."""
    return sorted(_entry_points())


def get_renderer(name: str, **options) -> Renderer:
    """Construct the renderer registered as ``name``.

    Examples
    --------
    >>> "classical" in available_renderers()
    True
    >>> r = get_renderer("classical")
    >>> sorted(r.default_appearance(1))         # what its render() takes besides the normals
    ['albedo', 'background', 'sh']
    """
    eps = _entry_points()
    if name not in eps:
        raise InputError(f"renderer {name!r} is not installed (available: "
                         f"{', '.join(sorted(eps)) or 'none'}); the 'gar' renderer needs the "
                         f"neural extra: pip install -e '.[neural]'")
    cls = _load(eps[name])
    try:
        inspect.signature(cls).bind(**options)
    except TypeError as e:
        raise InputError(f"renderer {name!r}: {e}") from None
    renderer = cls(**options)
    if not isinstance(renderer, Renderer):
        raise InputError(f"renderer {name!r} ({eps[name].value}) does not implement render() "
                         f"and default_appearance()")
    return renderer


def _load(entry_point):
    try:
        return entry_point.load()
    except ImportError as e:
        raise InputError(f"renderer {entry_point.name!r} cannot be loaded ({e})") from None


def plugin_feature_network():
    """The first ``feature_network()`` (in name order) that an installed renderer class
    offers, or None; plugins that cannot be loaded are passed over. The refinement's default
    perceptual features for a renderer without its own (the classical one borrows the neural
    plugin's aux network N)."""
    for name, ep in sorted(_entry_points().items()):
        try:
            cls = _load(ep)
        except InputError:
            continue
        found = getattr(cls, "feature_network", lambda: None)()
        if found is not None:
            return found
    return None
