"""The optional step after the landmark fit: a refinement of the fit on the pictures' pixels.

:func:`refine_fit` takes the refinement by its name: ``"photometric"`` (the classical
renderer's inversion: albedo texture and SH light in closed form, docs/photometric.md;
``"classical"`` is the same), or another installed renderer plugin's name (``"gar"``,
:func:`morphable.renderer_plugins.get_renderer`). All frames are refined together through
:func:`morphable.refinement.refine_shared`: one identity shared by the frames, each frame's
expression and pose.
"""
from __future__ import annotations

__all__ = ["refine_fit", "METHODS", "renderer_of"]

METHODS = {"photometric": "classical"}
"""Refinement names that are not a renderer's own -> the renderer they invert."""


def renderer_of(method: str) -> str:
    """The renderer a refinement method inverts (``"photometric"`` -> ``"classical"``)."""
    return METHODS.get(method, method)


def refine_fit(fit, pictures, method: str, **options) -> tuple:
    """Refine a landmark fit on its pictures, all frames together.

    Parameters
    ----------
    fit : FitResult of N frames (:func:`morphable.fitting.fit_landmarks`)
    pictures : the N :class:`~morphable.pipeline.inputs.Picture` objects of its frames, in order
    method : str, "photometric" (= "classical") or a renderer's name ("gar")
    **options : keywords of :func:`morphable.refinement.refine_shared` (``steps``,
        ``weights``, ``renderer_options``, ``features``, ``resolution``, ``seed``,
        ``trace_every``, ``recast_every``)

    Returns
    -------
    (FitResult, runs, states): the refined fit (one identity for all frames); per frame the
    refinement's report (``photometric_loss`` per step, ``mask_coverage``, ``runtime_s``,
    ...) and its :class:`~morphable.refinement.Refinement` (for
    :func:`morphable.refinement.edit`).
    """
    from ..refinement import refine_shared

    return refine_shared([p.pixels() for p in pictures], fit, renderer_of(method),
                         labels=[p.label for p in pictures], **options)
