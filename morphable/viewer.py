"""3D inspection with pyvista (extra ``viz``): meshes, landmarks, scans, per-vertex errors.

Off-screen screenshots work headless: VTK's wheels render through EGL/OSMesa when there is
no display; ``xvfb-run`` is the fallback that ``make`` installs.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import InputError
from .io.atomic import atomic_path
from .logs import quiet_vtk

__all__ = ["VIEWS", "show_mesh", "parse_size"]

# camera direction (from the face towards the camera) and up vector, model axes
VIEWS = {
    "front": ((0, 0, 1), (0, 1, 0)),
    "left": ((1, 0, 0.15), (0, 1, 0)),    # the subject's left side
    "right": ((-1, 0, 0.15), (0, 1, 0)),
    "top": ((0, 1, 0.3), (0, 0, -1)),
}


def parse_size(text: str) -> tuple[int, int]:
    """``"1024x768"`` -> (1024, 768)."""
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 1024x768") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise InputError(f"--size {text!r}: each side must be 16..8192 pixels")
    return w, h


def _polydata(vertices, triangles):
    import pyvista as pv

    faces = np.hstack([np.full((len(triangles), 1), 3), np.asarray(triangles)]).ravel()
    return pv.PolyData(np.asarray(vertices, dtype=np.float64), faces)


def _textured(vertices, triangles, texture):
    """(PolyData split along UV seams with its texture coordinates, pyvista Texture)."""
    import pyvista as pv

    from .io.mesh import uv_unwelded
    from .raster import as_texture

    try:
        uv, tuv, image = texture
    except (TypeError, ValueError):
        raise InputError("texture must be (uv, triangle_uv, image)") from None
    t = np.asarray(triangles, dtype=np.int64)
    uv = np.asarray(uv, dtype=np.float64)
    tuv = t if tuv is None else np.asarray(tuv, dtype=np.int64)
    if uv.ndim != 2 or uv.shape[1] != 2 or tuv.shape != t.shape or tuv.max() >= len(uv):
        raise InputError(f"texture uv must be (T, 2) with triangle_uv {t.shape} ids into it")
    v, f, vuv = uv_unwelded(vertices, t, uv, tuv)
    poly = _polydata(v, f)
    poly.active_texture_coordinates = vuv
    img = np.round(255 * np.clip(as_texture(image), 0, 1)).astype(np.uint8)
    return poly, pv.numpy_to_texture(img)


def show_mesh(vertices, triangles, *, landmarks=None, scan=None, errors=None,
              error_range=None, image=None, view: str = "front", size=(1024, 768),
              screenshot=None, title: str | None = None, texture=None):
    """Draw a mesh with optional landmarks, an overlaid scan and a per-vertex error map.

    Parameters
    ----------
    vertices : (V, 3) float, mm
    triangles : (F, 3) int
    landmarks : (L, 3) float, mm, or None — drawn as red spheres (2 mm radius)
    scan : (vertices (S, 3), triangles (G, 3)) or None — drawn semi-transparent
    errors : (V,) float, mm, or None — colour map with a scale bar; NaN drawn grey
    error_range : (lo, hi) mm or None (default 0 .. 95th percentile)
    image : (H, W, 3) uint8 or path, or None — a photo as the window background
    view : "front", "left", "right" or "top"
    size : (width, height) pixels
    screenshot : path or None — write a PNG off-screen (atomically) instead of opening a window
    texture : (uv (T, 2), triangle_uv (F, 3) or None, image (h, w, 3) or path) or None — the
        surface coloured by a texture through its UVs (v up), unless ``errors`` are drawn

    Returns
    -------
    Path of the screenshot, or None after an interactive window closed.
    """
    import pyvista as pv

    if view not in VIEWS:
        raise InputError(f"--view {view!r}: choose from {', '.join(VIEWS)}")
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.isfinite(v).all():
        raise InputError("mesh vertices must be a finite, non-empty (V, 3) array")
    off_screen = screenshot is not None or not os.environ.get("DISPLAY")
    if off_screen:
        quiet_vtk()
    plotter = pv.Plotter(off_screen=off_screen, window_size=list(size))
    plotter.set_background("white")
    mesh = _polydata(v, triangles)
    if errors is not None:
        e = np.asarray(errors, dtype=np.float64)
        if e.shape != (len(v),):
            raise InputError(f"errors: {e.shape[0] if e.ndim else 0} values for {len(v)} vertices")
        lo, hi = error_range or (0.0, float(np.nanpercentile(e, 95)) if np.isfinite(e).any() else 1.0)
        mesh["error (mm)"] = e
        plotter.add_mesh(mesh, scalars="error (mm)", cmap="viridis", clim=(lo, max(hi, lo + 1e-6)),
                         nan_color="lightgrey", smooth_shading=True,
                         scalar_bar_args={"title": "error (mm)", "color": "black"})
    elif texture is not None:
        textured, tex = _textured(v, triangles, texture)
        plotter.add_mesh(textured, texture=tex, smooth_shading=True, ambient=0.35, diffuse=0.65)
    else:
        plotter.add_mesh(mesh, color="#d9b99b", smooth_shading=True, specular=0.2)
    if scan is not None:
        plotter.add_mesh(_polydata(*scan), color="#6fa8dc", opacity=0.4, smooth_shading=True)
    if landmarks is not None:
        pts = np.asarray(landmarks, dtype=np.float64)
        pts = pts[np.isfinite(pts).all(1)]
        plotter.add_mesh(pv.PolyData(pts).glyph(geom=pv.Sphere(radius=2.0), scale=False,
                                                orient=False), color="red")
    if image is not None:
        path = image if isinstance(image, (str, Path)) else None
        if path is None:
            from PIL import Image

            tmp = Path(os.environ.get("TMPDIR", "/tmp")) / f"morphable_bg_{os.getpid()}.png"
            Image.fromarray(np.asarray(image, dtype=np.uint8)).save(tmp)
            path = tmp
        plotter.add_background_image(str(path))
    if title:
        plotter.add_text(title, font_size=10, color="black")
    direction, up = VIEWS[view]
    plotter.view_vector(direction, viewup=up)
    plotter.reset_camera()  # frames everything drawn: mesh, scan and landmarks
    try:
        if screenshot is not None:
            with atomic_path(screenshot, suffix=".png") as tmp:
                plotter.screenshot(str(tmp))
            return Path(screenshot)
        plotter.show()
        return None
    finally:
        plotter.close()
