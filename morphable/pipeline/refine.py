"""The optional step after the landmark fit: a refinement of the fit on the pictures' pixels.

:func:`refine_fit` takes the refinement by its name. Today every name is a renderer's
(:func:`morphable.renderer_plugins.get_renderer`: ``"classical"``, ``"gar"``, or another
installed plugin's): each frame is refined in turn by inverting that renderer
(:func:`morphable.refinement.refine`). A refinement of another kind takes its own name here,
with its own options.
"""
from __future__ import annotations

__all__ = ["refine_fit"]


def refine_fit(fit, pictures, method: str, **options) -> tuple:
    """Refine a landmark fit on its pictures.

    Parameters
    ----------
    fit : FitResult of N frames (:func:`morphable.fitting.fit_landmarks`)
    pictures : the N :class:`~morphable.pipeline.inputs.Picture` objects of its frames, in order
    method : str, a renderer's name: every frame refined by inverting it
    **options : keywords of :func:`morphable.refinement.refine` (``steps``, ``weights``,
        ``renderer_options``, ``features``, ``resolution``, ``seed``, ``trace_every``)

    Returns
    -------
    (FitResult, runs, states): the refined fit; per frame the refinement's report
    (``photometric_loss`` per step, ``runtime_s``, ...) and its
    :class:`~morphable.refinement.Refinement` (for :func:`morphable.refinement.edit`).
    """
    from ..refinement import refine

    runs, states = [], []
    for i, picture in enumerate(pictures):
        fit, run, state = refine(picture.pixels(), fit, method, frame=i, return_state=True, **options)
        runs.append(run)
        states.append(state)
    return fit, runs, states
