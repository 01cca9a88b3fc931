"""The physically based scene of one scan: VTK's PBR through pyvista, off-screen.

Material: the scan's texture (or vertex colours, or a skin tone) as base colour, a
dielectric specular lobe (``roughness``, ``metallic``). Light: image-based light from the
video's background photo plus the condition's scene lights, fixed in the world (the head
turns under them), with cast shadows (VTK's shadow maps). The camera is the video's own
(:class:`morphable.camera.Camera`, pinhole or affine), so the scan's landmarks project where
the protocol says. Nothing here is shared with ``morphable.raster``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from morphable.errors import InputError

from .camera_effects import SENSORS, background_crop, develop

__all__ = ["Look", "LOOKS", "render_view", "render_frames"]


@dataclass(frozen=True)
class Look:
    """The material and light of one kind of video.

    Attributes
    ----------
    roughness : PBR roughness of the skin in [0, 1] (lower: a sharper, brighter highlight)
    metallic : PBR metalness in [0, 1] (skin: 0)
    environment_gain : brightness of the image-based light (the background photo), 0: none
    lights : tuple of (direction, intensity, colour, distance_mm): direction (3,) towards the
        light in the frontal camera frame (x right, y up, z towards the camera); distance 0
        for a directional light, else a spot light at that distance from the head
    shadows : cast shadows from the scene lights
    """

    roughness: float
    metallic: float
    environment_gain: float
    lights: tuple
    shadows: bool = True


LOOKS = {
    "soft": Look(0.55, 0.0, 1.0, (((0.3, 0.4, 1.0), 1.8, (1.0, 0.97, 0.92), 0.0),
                                  ((-0.7, 0.1, 0.6), 0.7, (0.9, 0.95, 1.0), 0.0))),
    "lamp": Look(0.45, 0.0, 0.6, (((0.9, 0.25, 0.45), 4.0, (1.0, 0.85, 0.65), 900.0),
                                  ((-0.4, 0.6, 0.7), 0.4, (0.8, 0.9, 1.0), 0.0))),
    "sun": Look(0.4, 0.0, 0.6, (((-0.45, 0.85, 0.35), 3.5, (1.0, 0.96, 0.88), 0.0),)),
}
"""Look per condition light (:attr:`evaluation.videos.Condition.light`)."""

SKIN = (0.78, 0.6, 0.5)
"""Base colour of a scan without texture or vertex colours."""


def _mesh(scan):
    """The scan as pyvista PolyData: one point per (vertex, uv) corner pair, the scan's
    smooth vertex normals, texture coordinates or ``rgb`` colours."""
    import pyvista as pv

    from morphable.normals import vertex_normals

    v = np.asarray(scan.vertices, dtype=np.float64)
    t = np.asarray(scan.triangles, dtype=np.int64)
    if len(v) == 0 or len(t) == 0 or not np.isfinite(v).all():
        raise InputError(f"{scan.source or 'scan'}: an empty mesh or non-finite vertices")
    textured = scan.uv is not None and scan.texture is not None
    corner_uv = (scan.triangle_uv if scan.triangle_uv is not None else t) if textured else t
    pairs, inverse = np.unique(np.c_[t.reshape(-1), np.asarray(corner_uv).reshape(-1)], axis=0,
                               return_inverse=True)
    faces = inverse.reshape(-1, 3)
    mesh = pv.PolyData(v[pairs[:, 0]], np.c_[np.full(len(faces), 3), faces].ravel())
    mesh.point_data["Normals"] = vertex_normals(v, t)[pairs[:, 0]]
    mesh.point_data.active_normals_name = "Normals"
    if textured:
        mesh.active_texture_coordinates = np.asarray(scan.uv, dtype=np.float64)[pairs[:, 1]]
    elif scan.colors is not None:
        mesh.point_data["rgb"] = np.round(np.clip(scan.colors[pairs[:, 0]], 0, 1) * 255).astype(np.uint8)
    return mesh


def _texture(image, srgb: bool = True):
    """(H, W, 3) float [0, 1] image (row 0 at the top) -> vtkTexture, mip-mapped."""
    import pyvista as pv

    tex = pv.Texture(np.round(np.clip(image, 0, 1) * 255).astype(np.uint8))
    tex.SetInterpolate(True)
    tex.SetMipmap(True)
    if srgb:
        tex.SetUseSRGBColorSpace(True)
    return tex


class _Scene:
    """One off-screen plotter with the scan's actor, its lights and camera."""

    def __init__(self, scan, size, supersample: int, look: Look):
        import pyvista as pv

        W, H = size
        self.size, self.ss, self.shots = (int(W), int(H)), int(supersample), 0
        self.plotter = pv.Plotter(off_screen=True, window_size=(W * self.ss, H * self.ss), lighting=None)
        mesh = _mesh(scan)
        kw = dict(pbr=True, roughness=look.roughness, metallic=look.metallic, smooth_shading=True)
        if "rgb" in mesh.point_data:
            actor = self.plotter.add_mesh(mesh, scalars="rgb", rgb=True, **kw)
        else:
            actor = self.plotter.add_mesh(mesh, color=SKIN, **kw)
        if scan.uv is not None and scan.texture is not None:
            actor.GetProperty().SetBaseColorTexture(_texture(scan.texture))
        if look.shadows:
            self.plotter.enable_shadows()
        self.centre = np.nanmean(np.asarray(scan.landmarks, dtype=np.float64), 0)
        if not np.isfinite(self.centre).all():
            self.centre = np.asarray(scan.vertices).mean(0)

    def light(self, look: Look, frontal_rotation, environment=None):
        """Scene lights fixed in the world (directions given in the frontal camera frame)
        and the image-based light from ``environment`` ((h, 2h, 3) equirectangular)."""
        import pyvista as pv

        self.plotter.remove_all_lights()
        for direction, intensity, colour, distance in look.lights:
            d = frontal_rotation.T @ (np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction))
            light = pv.Light(light_type="scene light", intensity=intensity, color=colour)
            light.focal_point = tuple(self.centre)
            light.position = tuple(self.centre + d * (distance or 2000.0))
            light.positional = bool(distance)
            if distance:
                light.cone_angle = 45.0
            self.plotter.add_light(light)
        if environment is not None and look.environment_gain > 0:
            self.plotter.set_environment_texture(_texture(environment * look.environment_gain), is_srgb=True)

    def shoot(self, camera) -> np.ndarray:
        """The scan seen by ``camera`` -> (H, W, 4) float in [0, 1], alpha its coverage."""
        W, H = self.size
        if tuple(camera.image_size) != (W, H):
            raise InputError(f"camera image size {tuple(camera.image_size)} differs from the "
                             f"scene's {(W, H)}")
        R = np.asarray(camera.rotation, dtype=np.float64)
        forward, up = R.T @ np.array([0.0, 0.0, -1.0]), R.T @ np.array([0.0, 1.0, 0.0])
        vc = self.plotter.camera
        depth = float(camera.depth(self.centre[None])[0])
        if camera.kind == "affine":
            position = camera.centre + R.T @ np.array([0.0, 0.0, 1.0]) * 2000.0
            depth = float(np.dot(self.centre - position, forward))
            vc.enable_parallel_projection()
            vc.parallel_scale = H / 2.0 / camera.scale
        else:
            position = camera.centre
            vc.disable_parallel_projection()
            vc.view_angle = float(np.degrees(2 * np.arctan(H / 2.0 / camera.focal)))
        vc.position = tuple(position)
        vc.focal_point = tuple(position + forward * depth)
        vc.up = tuple(up)
        # VTK's window centre: the principal point's offset from the image centre in [-1, 1]
        cx, cy = camera.principal
        vc.SetWindowCenter(-2.0 * (cx - (W - 1) / 2.0) / W, 2.0 * (cy - (H - 1) / 2.0) / H)
        vc.clipping_range = (max(depth - 400.0, 1.0), depth + 400.0)
        if self.shots:
            # pyvista's screenshot renders on its first call only: later ones would return
            # the first frame again
            self.plotter.render_window.Render()
        self.shots += 1
        img = self.plotter.screenshot(return_img=True, transparent_background=True)
        img = np.asarray(img, dtype=np.float64)[:H * self.ss, :W * self.ss] / 255.0
        return img.reshape(H, self.ss, W, self.ss, 4).mean((1, 3))

    def close(self):
        self.plotter.close()


def _frontal_rotation(cameras) -> np.ndarray:
    """(3, 3) the rotation nearest the mean of the cameras' rotations: the video's central
    view, in whose frame :attr:`Look.lights` are given."""
    u, _, vt = np.linalg.svd(np.mean([c.rotation for c in cameras], 0))
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def _environment(background, height: int = 64) -> np.ndarray:
    """A background crop as an equirectangular environment of ``height`` rows: the crop and
    its mirror side by side (a 2:1 panorama without a seam), (height, 2 height, 3). Small:
    the image-based light is low-pass filtered anyway, and VTK's filtering of it is the
    costliest step of a frame in software OpenGL."""
    from PIL import Image

    small = Image.fromarray(np.round(np.clip(background, 0, 1) * 255).astype(np.uint8))
    half = np.asarray(small.resize((height, height), Image.BILINEAR), dtype=np.float64) / 255.0
    return np.concatenate([half, half[:, ::-1]], 1)


def _shade(scan, cameras, look: Look, rotation, background, supersample: int):
    """The scan under ``look`` (lights in the frame of ``rotation``, the image-based light
    from ``background``) seen by each of ``cameras`` -> yields (H, W, 4) float in [0, 1]
    images, one scene for them all (VTK compiles its shaders and filters the environment
    once: seconds in software OpenGL)."""
    scene = _Scene(scan, cameras[0].image_size, supersample, look)
    try:
        scene.light(look, rotation, _environment(background))
        for camera in cameras:
            yield scene.shoot(camera)
    finally:
        scene.close()


def render_view(scan, camera, condition: str = "cooperative", seed: int = 0,
                supersample: int = 2, photos=None) -> np.ndarray:
    """One physically based frame of ``scan`` seen by ``camera`` -> (H, W, 3) uint8.

    Parameters
    ----------
    scan : :class:`evaluation.scans.Scan` (mm; texture, vertex colours or neither)
    camera : :class:`morphable.camera.Camera`, world = the scan's frame
    condition : a key of :data:`evaluation.videos.CONDITIONS`: the look, lights and sensor
    seed : int, decides the background and the noise
    supersample : render at this many times the size, then average (anti-aliasing)
    photos : background photos (:func:`evaluation.pbr.camera_effects.background_photos`)
    """
    from ..videos import CONDITIONS

    if condition not in CONDITIONS:
        raise InputError(f"unknown condition {condition!r}; choose from {', '.join(CONDITIONS)}")
    look = LOOKS[CONDITIONS[condition].light]
    rng = np.random.default_rng([seed, list(CONDITIONS).index(condition)])
    background = background_crop(camera.image_size, rng, photos)
    rgba, = _shade(scan, [camera], look, camera.rotation, background, supersample)
    return develop(rgba, background, SENSORS[condition], rng)


def render_frames(scan, video, frames=None, seed: int = 0, supersample: int = 2,
                  photos=None) -> np.ndarray:
    """Physically based frames of a synthetic video -> (k, H, W, 3) float in [0, 1].

    The drop-in for :func:`evaluation.videos.render_frames` (same cameras, so the same
    landmarks). The video has one background (and image-based light) drawn from
    ``(seed, condition)``; frame ``i`` draws its noise from ``(seed, condition, i)``, so a
    frame is the same whichever others are rendered.

    Parameters
    ----------
    scan : :class:`evaluation.scans.Scan`
    video : :class:`evaluation.videos.Video`
    frames : frame indices (default the sampled ones)
    seed : int
    supersample : see :func:`render_view`
    photos : background photos (default :func:`~evaluation.pbr.camera_effects.background_photos`)
    """
    from ..videos import CONDITIONS

    cond = list(CONDITIONS).index(video.condition)
    look = LOOKS[CONDITIONS[video.condition].light]
    frames = video.sampled if frames is None else np.asarray(frames)
    background = background_crop(video.image_size, np.random.default_rng([seed, cond]), photos)
    cameras = [video.cameras[i] for i in frames]
    out = []
    for i, rgba in zip(frames, _shade(scan, cameras, look, _frontal_rotation(video.cameras),
                                      background, supersample)):
        rng = np.random.default_rng([seed, cond, int(i)])
        out.append(develop(rgba, background, SENSORS[video.condition], rng) / 255.0)
    return np.stack(out)
