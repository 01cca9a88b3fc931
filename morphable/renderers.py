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
"""
from __future__ import annotations

from importlib import metadata
from typing import Protocol, runtime_checkable

from .errors import InputError

__all__ = ["Renderer", "GROUP", "available_renderers", "get_renderer"]

GROUP = "morphable.renderers"


@runtime_checkable
class Renderer(Protocol):
    resolution: int | None

    def render(self, normal_map, appearance): ...

    def default_appearance(self, batch_size: int = 1) -> dict: ...


def _entry_points() -> dict:
    return {ep.name: ep for ep in metadata.entry_points(group=GROUP)}


def available_renderers() -> list[str]:
    """Names of the installed renderers (e.g. ``["classical", "gar"]``)."""
    return sorted(_entry_points())


def get_renderer(name: str, **options) -> Renderer:
    """Construct the renderer registered as ``name``.

    Examples
    --------
    >>> "classical" in available_renderers()  # doctest: +SKIP
    True
    >>> r = get_renderer("classical")  # doctest: +SKIP
    """
    eps = _entry_points()
    if name not in eps:
        raise InputError(f"renderer {name!r} is not installed (available: "
                         f"{', '.join(sorted(eps)) or 'none'}); the 'gar' renderer needs the "
                         f"neural extra: pip install -e '.[neural]'")
    try:
        cls = eps[name].load()
    except ImportError as e:
        raise InputError(f"renderer {name!r} cannot be loaded ({e})") from None
    renderer = cls(**options)
    if not isinstance(renderer, Renderer):
        raise InputError(f"renderer {name!r} ({eps[name].value}) does not implement render() "
                         f"and default_appearance()")
    return renderer
