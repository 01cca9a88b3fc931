"""A second rendering of the Florence protocol's frames that shares nothing with our fitter.

The protocol's frames (:mod:`evaluation.videos`) are rendered by ``morphable.raster`` with the
Lambertian, spherical-harmonic-like shading that a photometric fitter assumes: judging such a
fitter on them is an inverse crime. :func:`render_frames` renders the same videos (same
cameras, so the same landmarks) with VTK's physically based renderer through pyvista
(off-screen, EGL or OSMesa): the scan's texture (or vertex colours) as base colour, a
specular lobe (roughness, metallic), image-based light from a photo plus scene lights with
cast shadows, then a real-photo background, defocus blur, sensor noise and JPEG compression
(:mod:`evaluation.pbr.camera_effects`), every random choice seeded per frame.

Command: ``python -m evaluation.florence ... --detect --renderer pbr``.

Backgrounds are crops of 300-W photos (AFW and HELEN, **research, non-commercial use only**)
away from their annotated faces (:func:`~evaluation.pbr.camera_effects.background_crop`).

Modules: :mod:`~evaluation.pbr.renderer` (the scene: mesh, material, lights, camera) and
:mod:`~evaluation.pbr.camera_effects` (background, defocus, noise, JPEG).
"""
from .camera_effects import SENSORS, Sensor, background_crop, background_photos, develop
from .renderer import LOOKS, Look, render_frames, render_view

__all__ = ["LOOKS", "Look", "SENSORS", "Sensor", "render_frames", "render_view",
           "background_crop", "background_photos", "develop"]
