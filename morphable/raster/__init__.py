"""Rasterisation: visibility by ray casting (open3d / Embree), normal, depth and mask maps in
screen and UV space, a differentiable (torch) interpolation path, Lambertian shading, vertex
colours read from a photo, and PNG export.

open3d, torch and PIL load inside the functions that use them, not at import.

Examples
--------
>>> import numpy as np
>>> from morphable.camera import Camera
>>> from morphable.raster import visibility, normal_map, interpolate
>>> square = np.array([[-50., -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]])
>>> tris = np.array([[0, 1, 2], [0, 2, 3]])
>>> cam = Camera.looking_at_face(image_size=(64, 64), kind="perspective")
>>> vis = visibility(square, tris, cam)
>>> normal_map(square, tris, cam, vis=vis)[32, 32]
array([0., 0., 1.])
"""
from .colors import vertex_colors
from .framing import frame_mesh
from .interpolate import interpolate
from .normal_maps import normal_map, sample_normals, tangent_frames, uv_layout, uv_normal_map
from .png import read_depth_png, save_depth_png, save_image_png, save_mask_png, save_normal_png
from .shaded_images import render
from .shading import (DirectionalLight, sh_basis, sh_from_lights, shade_directional, shade_sh,
                      shade_sh_torch)
from .texture import as_texture, sample_texture
from .visibility import Visibility, uv_visibility, visibility

__all__ = ["Visibility", "visibility", "uv_visibility", "interpolate", "normal_map",
           "sample_normals", "uv_normal_map", "uv_layout", "tangent_frames", "render",
           "DirectionalLight", "sh_basis", "shade_sh", "shade_sh_torch", "shade_directional",
           "sh_from_lights", "sample_texture", "as_texture", "frame_mesh", "save_normal_png",
           "save_depth_png", "save_mask_png", "save_image_png", "read_depth_png", "vertex_colors"]
