"""Synthetic faces with exact labels: the training-data engine of a landmark network.

:class:`SyntheticEngine` draws a random face of a 3DMM (SFM or ICT FaceKit: identity,
expression, pose up to yaw 90, pitch 40, roll 30 degrees), dresses it in a UV texture extracted
from a real photo (:func:`texture_bank`, :mod:`morphable.texture`; the procedural albedo of
:class:`neural.faces.renders.SyntheticFaces` when there is none), lights it (``soft``, ``lamp``,
``sun``, ``coloured``: directional lights with cast shadows, :func:`morphable.raster.render`),
puts it on a background cut from a real photo (:func:`background_bank`) with a perspective
camera of varied distance and face size, and degrades the picture (occluders, blur,
down-sampling, noise, JPEG loss).

Labels (:meth:`SyntheticEngine.render`), for every point of a landmark scheme — the 68 iBUG
points and mediapipe's 478 face-mesh points, as points of the model's surface
(:mod:`morphable.fitting.schemes`):

- ``points68`` (68, 2), ``points478`` (478, 2): pixels (x right, y down, 0-based pixel
  centres) where the surface point projects, whether it is seen or not (the 3D convention);
- ``visible68``, ``visible478``: the camera sees the point (a ray cast from it towards the
  camera hits no triangle, :func:`morphable.raster.visibility.points_in_view`) and it projects
  inside the image;
- ``occluded68``, ``occluded478``: an occluder drawn over the picture covers the point's pixel;
- the parameters: identity (K,), expression (E,), pose (3,) yaw, pitch, roll in degrees (the
  camera's Euler angles), the camera (rotation, translation mm, focal px, principal px,
  distance mm), light kind, texture and degradations.

iBUG-68 on SFM: SFM has no fixed vertex for the 17 jaw points and two inner-mouth points;
those rows take the face-mesh scheme's counterpart of the iBUG point (``LandmarkScheme.ibug68``),
a fixed surface point near the jaw line, and ``defined68`` says which rows have a point at all
(NaN rows otherwise, never silently: ``defined68`` is False there).

Examples
--------
>>> eng = SyntheticEngine("sfm", resolution=32, degrade=False)
>>> face = eng.sample(0)
>>> face["image"].shape, face["points478"].shape
((32, 32, 3), (478, 2))
"""
from __future__ import annotations

import dataclasses
import io
import logging
import time
from pathlib import Path

import numpy as np

from morphable.errors import FitError, InputError
from morphable.labels import VIEW_OFFSET_MM, label_schemes  # noqa: F401  (VIEW_OFFSET_MM: re-exported)

__all__ = ["LIGHTS", "POSE_MAX", "SyntheticEngine", "label_schemes", "texture_bank", "yaw_grid", "check",
           "background_bank", "label_exactness", "london_photos", "w300_photos"]

log = logging.getLogger("neural.faces.synthetic")

LIGHTS = ("soft", "lamp", "sun", "coloured")
"""Light kinds: ``soft`` three weak lights and much ambient; ``lamp`` a warm key light and a
fill; ``sun`` one strong light and little ambient (hard shadows); ``coloured`` two lights of
saturated colours. All are directional (the raster has no point lights) with cast shadows."""

POSE_MAX = (90.0, 40.0, 30.0)
"""Yaw, pitch, roll limits, degrees; poses are uniform within them."""

DISTANCE_MM = (300.0, 2500.0)
"""Camera distance range (log-uniform), mm: from a close selfie to a portrait lens."""


FACE_FRACTION = (0.3, 0.6)
"""150 mm of face at its centre spans this fraction of the image side (uniform)."""


# --- real material: textures and backgrounds -------------------------------------------------
def london_photos(data) -> list:
    """The London set's neutral front photos under the data folder (CC BY 4.0), sorted."""
    return sorted((Path(data) / "faces" / "frl_london" / "neutral_front").glob("*.jpg"))


def w300_photos(data) -> list:
    """The 300-W photos with a ``.pts`` beside them (research use only), sorted."""
    return sorted(p for p in (Path(data) / "images" / "300w").rglob("*")
                  if p.suffix.lower() in (".png", ".jpg") and p.with_suffix(".pts").is_file())


def texture_bank(photos, model="sfm", size: int = 256, cache=None) -> tuple:
    """UV textures of ``model`` extracted from face photos: each photo fitted with face-mesh
    landmarks (:func:`morphable.pipeline.fit_images`) and textured
    (:func:`morphable.texture.extract_texture`).

    Parameters
    ----------
    photos : list of paths
    model : model name
    size : texels per side
    cache : path of an .npz that keeps the textures (read when it holds this model, size and
        photos; written atomically otherwise)

    Returns
    -------
    (textures (T, S, S, 3) uint8, names (T,) str, failures: list of "name: reason")
    """
    from morphable.io.atomic import atomic_path

    photos = [Path(p) for p in photos]
    names = [p.name for p in photos]
    cache = Path(cache) if cache is not None else None
    if cache is not None and cache.is_file():
        try:
            with np.load(cache, allow_pickle=False) as z:
                if (str(z["model"]) == str(model) and int(z["size"]) == size
                        and list(z["photos"]) == names):
                    return z["textures"], z["names"], list(z["failures"])
        except (OSError, ValueError, KeyError, EOFError):
            log.warning("%s: unreadable texture cache, extracting again", cache)
    from morphable.pipeline import fit_images
    from morphable.texture import extract_texture

    textures, kept, failures = [], [], []
    t0 = time.perf_counter()
    for p in photos:
        try:
            res = fit_images(p, model=model, landmark_detector="facemesh").fit
            tex = extract_texture(res, [p], size=size)
        except (FitError, InputError) as e:
            failures.append(f"{p.name}: {str(e).splitlines()[0]}")
            continue
        textures.append(np.round(tex.image * 255).astype(np.uint8))
        kept.append(p.name)
    log.info("textures: %d of %d photos in %.0f s", len(kept), len(photos), time.perf_counter() - t0)
    textures = np.stack(textures) if textures else np.zeros((0, size, size, 3), np.uint8)
    if cache is not None:
        with atomic_path(cache) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, model=np.array(str(model)), size=np.int64(size), photos=np.array(names),
                         textures=textures, names=np.array(kept, dtype=str),
                         failures=np.array(failures, dtype=str))
    return textures, np.array(kept, dtype=str), failures


def background_bank(photos, side: int = 128, per_photo: int = 2, seed: int = 0) -> np.ndarray:
    """Square patches of real photos away from their annotated face: (N, side, side, 3) uint8.

    ``photos``: paths with an iBUG ``.pts`` beside each; a patch is a random square of 1/4 to
    1/2 of the photo's shorter side that does not meet the landmarks' box grown by 20 %
    (photos where none fits give none), resized to ``side``."""
    from PIL import Image

    from morphable.io.landmark_files import read_pts

    rng = np.random.default_rng(seed)
    out = []
    for p in photos:
        img = Image.open(p).convert("RGB")
        W, H = img.size
        lm = read_pts(p.with_suffix(".pts"))
        lo, hi = lm.min(0), lm.max(0)
        lo, hi = lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo)
        for _ in range(per_photo):
            for _try in range(20):
                s = int(rng.uniform(0.25, 0.5) * min(W, H))
                x, y = int(rng.integers(0, W - s + 1)), int(rng.integers(0, H - s + 1))
                if x + s < lo[0] or x > hi[0] or y + s < lo[1] or y > hi[1]:
                    patch = img.crop((x, y, x + s, y + s)).resize((side, side), Image.Resampling.BILINEAR)
                    out.append(np.asarray(patch))
                    break
    return np.stack(out) if out else np.zeros((0, side, side, 3), np.uint8)


# --- the engine -------------------------------------------------------------------------------
class SyntheticEngine:
    """Random labelled faces of a 3DMM (see the module's docstring).

    Parameters
    ----------
    model : "sfm", "ict" or a model path
    resolution : image side, px
    textures : (T, S, S, 3) uint8 UV textures of this model (:func:`texture_bank`); empty:
        procedural albedo (:meth:`neural.faces.renders.SyntheticFaces.draw_identity`) only
    backgrounds : (N, s, s, 3) uint8 photo patches (:func:`background_bank`); empty:
        procedural backgrounds (:meth:`neural.faces.renders.SyntheticFaces.draw_background`)
    pose_max : yaw, pitch, roll limits, degrees
    distance_mm : (near, far) camera distance, mm, log-uniform
    face_fraction : (low, high) fraction of the image side that 150 mm of face spans
    texture_share : probability that a face wears a photo texture (when there are any)
    identity_std, expression_max : as :class:`neural.faces.renders.SyntheticFaces`
    expression_active : how many random blendshapes a face may use (default: 2 for models
        of fewer than 10 blendshapes, 8 otherwise)
    supersample : antialiasing samples per pixel along each axis
    occluders, degrade : draw occluders / blur, down-sample, add noise, JPEG-compress
    """

    def __init__(self, model="sfm", resolution: int = 128, textures=(), backgrounds=(),
                 pose_max=POSE_MAX, distance_mm=DISTANCE_MM, face_fraction=FACE_FRACTION,
                 texture_share: float = 0.8, identity_std: float = 1.0, expression_max: float = 0.8,
                 expression_active=None, supersample: int = 2, occluders: bool = True,
                 degrade: bool = True):
        from morphable.refinement.crop import face_frame

        from .renders import SyntheticFaces

        probe = SyntheticFaces(model=model, resolution=resolution, supersample=supersample)
        n_exp = probe.model.n_expression
        if expression_active is None:
            expression_active = 2 if n_exp < 10 else 8
        self.faces = SyntheticFaces(model=probe.model, resolution=resolution, yaw_max=pose_max[0],
                                    pitch_max=pose_max[1], roll_max=pose_max[2],
                                    identity_std=identity_std, expression_max=expression_max,
                                    supersample=supersample, expression_active=expression_active)
        self.model = self.faces.model
        self.resolution = int(resolution)
        self.supersample = int(supersample)
        self.textures = np.asarray(textures) if len(textures) else np.zeros((0, 1, 1, 3), np.uint8)
        self.backgrounds = (np.asarray(backgrounds) if len(backgrounds)
                            else np.zeros((0, 1, 1, 3), np.uint8))
        self.distance_mm, self.face_fraction = tuple(distance_mm), tuple(face_fraction)
        self.texture_share = float(texture_share)
        self.occluders, self.degrade = bool(occluders), bool(degrade)
        self.schemes = label_schemes(self.model)
        self.centre = face_frame(self.model.landmark_positions())[0]
        if len(self.textures):
            from morphable.texture import texture_layout

            self.uv, self.triangle_uv, _ = texture_layout(self.model, self.textures.shape[1])

    # --- random parameters ----------------------------------------------------------------
    def draw(self, rng) -> dict:
        """The parameters of one face from the numpy Generator (or seed) ``rng``: identity
        (K,), expression (E,), pose (3,) degrees, albedo (V, 3) and texture (index, -1 for the
        procedural albedo), camera (distance mm, face width px, principal shift px), light
        (kind and :class:`morphable.raster.DirectionalLight` list, ambient RGB), background
        (R, R, 3) in [0, 1] and its source, occluders and degradations."""
        rng = np.random.default_rng(rng)
        f = self.faces
        R = self.resolution
        p = f.draw_identity(rng)
        p["expression"] = f.draw_expression(rng)
        p["pose"] = f.draw_pose(rng)
        use_tex = len(self.textures) and rng.random() < self.texture_share
        p["texture"] = int(rng.integers(len(self.textures))) if use_tex else -1
        lo, hi = np.log(self.distance_mm)
        p["distance_mm"] = float(np.exp(rng.uniform(lo, hi)))
        p["face_width_px"] = float(rng.uniform(*self.face_fraction) * R)
        p["shift_px"] = rng.normal(0, 0.06 * R, 2)
        p.update(self.draw_light(rng))
        if len(self.backgrounds):
            k = int(rng.integers(len(self.backgrounds)))
            bg = self.backgrounds[k].astype(np.float64) / 255
            if rng.random() < 0.5:
                bg = bg[:, ::-1]
            p["background"], p["background_id"] = _resize(bg, R), k
        else:
            p["background"], p["background_id"] = f.draw_background(rng), -1
        p["occluders"] = self.draw_occluders(rng) if self.occluders else []
        p["degradation"] = self.draw_degradation(rng) if self.degrade else {}
        return p

    def draw_light(self, rng) -> dict:
        """``light`` (kind, one of :data:`LIGHTS`), ``lights`` (list of DirectionalLight,
        directions in the camera frame, +z towards the viewer) and ``ambient`` (3,) RGB."""
        from morphable.raster import DirectionalLight

        kind = LIGHTS[int(rng.integers(len(LIGHTS)))]

        def direction(front=0.0):
            d = rng.normal(0, 1, 3)
            d[2] = abs(d[2]) + front
            return d

        white = np.ones(3)
        if kind == "soft":
            lights = [DirectionalLight(direction(0.5), rng.uniform(0.15, 0.3) * white)
                      for _ in range(3)]
            ambient = rng.uniform(0.45, 0.7) * white
        elif kind == "lamp":
            warm = np.array([1.0, 0.85, 0.65]) * rng.uniform(0.7, 1.1)
            lights = [DirectionalLight(direction(0.2), warm),
                      DirectionalLight(direction(0.5), rng.uniform(0.05, 0.2) * white)]
            ambient = rng.uniform(0.12, 0.3) * white
        elif kind == "sun":
            lights = [DirectionalLight(direction(-0.2), rng.uniform(1.0, 1.4) * np.array([1, 0.97, 0.9]))]
            ambient = rng.uniform(0.05, 0.2) * np.array([0.8, 0.9, 1.1])
        else:
            lights = [DirectionalLight(direction(0.2), _saturated(rng) * rng.uniform(0.5, 0.9))
                      for _ in range(2)]
            ambient = rng.uniform(0.1, 0.3) * _saturated(rng)
        return {"light": kind, "lights": lights, "ambient": ambient}

    def draw_occluders(self, rng) -> list:
        """0-2 occluders: dicts ``kind`` ("polygon" or "bar"), ``points`` (k, 2) px and
        ``colour`` (3,) in [0, 1]."""
        R = self.resolution
        out = []
        for _ in range(int(rng.choice(3, p=[0.5, 0.35, 0.15]))):
            c = rng.uniform(0.25, 0.75, 2) * R
            if rng.random() < 0.5:
                k = int(rng.integers(3, 8))
                ang = np.sort(rng.uniform(0, 2 * np.pi, k))
                r = rng.uniform(0.05, 0.2) * R * rng.uniform(0.6, 1.0, k)
                pts = c + np.stack([np.cos(ang), np.sin(ang)], 1) * r[:, None]
                out.append({"kind": "polygon", "points": pts, "colour": rng.uniform(0, 1, 3)})
            else:
                a, half = rng.uniform(0, np.pi), rng.uniform(0.2, 0.6) * R
                d = np.array([np.cos(a), np.sin(a)]) * half
                width = rng.uniform(0.02, 0.08) * R
                nrm = np.array([-d[1], d[0]]) / half * width
                pts = np.array([c - d - nrm, c + d - nrm, c + d + nrm, c - d + nrm])
                out.append({"kind": "bar", "points": pts, "colour": rng.uniform(0, 1, 3)})
        return out

    def draw_degradation(self, rng) -> dict:
        """``blur_px`` Gaussian radius (0 for none), ``downsample`` factor >= 1,
        ``noise`` standard deviation in [0, 1] units, ``jpeg`` quality (0 for none)."""
        return {"blur_px": float(rng.uniform(0.3, 1.5)) if rng.random() < 0.3 else 0.0,
                "downsample": float(rng.uniform(1.5, 4.0)) if rng.random() < 0.3 else 1.0,
                "noise": float(rng.uniform(0.005, 0.04)) if rng.random() < 0.4 else 0.0,
                "jpeg": int(rng.integers(20, 90)) if rng.random() < 0.5 else 0}

    def camera(self, pose, distance_mm, face_width_px, shift_px):
        """The perspective camera of a face: looking at the face's centre from
        ``distance_mm`` at ``pose`` (yaw, pitch, roll degrees), 150 mm spanning
        ``face_width_px``, the principal point shifted by ``shift_px`` (2,) from the centre."""
        from morphable.camera import Camera

        R = self.resolution
        cam = Camera.looking_at_face((R, R), *pose, kind="perspective", face_width_px=face_width_px,
                                     distance_mm=distance_mm, center=self.centre)
        return dataclasses.replace(cam, principal=cam.principal + np.asarray(shift_px, np.float64))

    # --- rendering --------------------------------------------------------------------------
    def render(self, p: dict) -> dict:
        """One face from its parameters (:meth:`draw`) -> dict: ``image`` (R, R, 3) uint8;
        ``points68`` (68, 2), ``points478`` (478, 2) float32 px; ``visible68``,
        ``visible478``, ``occluded68``, ``occluded478``, ``defined68`` (bool); ``camera``
        (the Camera); ``mask`` (R, R) float32 face coverage; ``occluder_mask`` (R, R) bool."""
        from morphable.labels import project_labels
        from morphable.raster import render, visibility

        m, R = self.model, self.resolution
        cam = self.camera(p["pose"], p["distance_mm"], p["face_width_px"], p["shift_px"])
        verts = m.vertices(p["identity"], p["expression"])
        vis = visibility(verts, m.triangles, cam, supersample=self.supersample)
        if p["texture"] >= 0:
            look = {"texture": (self.uv, self.triangle_uv,
                                self.textures[p["texture"]].astype(np.float32) / 255)}
        else:
            look = {"colors": p["albedo"]}
        image = render(verts, m.triangles, light=p["lights"], ambient=p["ambient"],
                       background=p["background"], shadows=True, vis=vis, **look)
        out = {"camera": cam, "mask": vis.coverage().astype(np.float32)}
        out.update(project_labels(verts, m.triangles, cam, self.schemes, offset_mm=VIEW_OFFSET_MM))
        out["defined68"] = self.schemes["68"].defined.copy()
        image, occ = _occlude(image, p["occluders"])
        out["occluder_mask"] = occ
        for key in self.schemes:
            xy = out[f"points{key}"]
            ij = np.clip(np.nan_to_num(np.round(xy), nan=-1).astype(int), 0, R - 1)
            out[f"occluded{key}"] = occ[ij[:, 1], ij[:, 0]] & np.isfinite(xy).all(1)
        out["image"] = _degrade(image, p["degradation"], p.get("noise_seed", 0))
        return out

    def sample(self, rng) -> dict:
        """:meth:`draw` then :meth:`render` -> the render's dict plus the parameters
        (``identity``, ``expression``, ``pose`` ...)."""
        rng = np.random.default_rng(rng)
        p = self.draw(rng)
        p["noise_seed"] = int(rng.integers(2 ** 31))
        out = self.render(p)
        out["params"] = p
        return out


def _saturated(rng) -> np.ndarray:
    """A random saturated RGB colour of max component 1."""
    c = rng.uniform(0, 1, 3) ** 3
    return c / c.max()


def _resize(img, R: int) -> np.ndarray:
    """(h, w, 3) float in [0, 1] -> (R, R, 3) bilinear."""
    from PIL import Image

    if img.shape[:2] == (R, R):
        return np.ascontiguousarray(img)
    u8 = Image.fromarray(np.round(np.clip(img, 0, 1) * 255).astype(np.uint8))
    return np.asarray(u8.resize((R, R), Image.Resampling.BILINEAR)).astype(np.float64) / 255


def _occlude(image, occluders) -> tuple:
    """Draw the occluders over (R, R, 3) float image -> (image, (R, R) bool mask)."""
    from PIL import Image, ImageDraw

    R = image.shape[0]
    mask = Image.new("L", (R, R), 0)
    img = image.copy()
    for o in occluders:
        one = Image.new("L", (R, R), 0)
        # PIL's pixel centres are at +0.5
        ImageDraw.Draw(one).polygon([tuple(q + 0.5) for q in o["points"]], fill=255)
        m = np.asarray(one) > 0
        img[m] = o["colour"]
        mask.paste(255, mask=one)
    return img, np.asarray(mask) > 0


def _degrade(image, d: dict, seed: int) -> np.ndarray:
    """(R, R, 3) float in [0, 1] -> uint8 after blur, down-sampling (and back), noise, JPEG."""
    from PIL import Image, ImageFilter

    R = image.shape[0]
    img = Image.fromarray(np.round(np.clip(image, 0, 1) * 255).astype(np.uint8))
    if d.get("blur_px", 0) > 0:
        img = img.filter(ImageFilter.GaussianBlur(d["blur_px"]))
    if d.get("downsample", 1) > 1:
        small = max(4, int(round(R / d["downsample"])))
        img = img.resize((small, small), Image.Resampling.BOX).resize((R, R), Image.Resampling.BILINEAR)
    a = np.asarray(img).astype(np.float64) / 255
    if d.get("noise", 0) > 0:
        a = a + np.random.default_rng(seed).normal(0, d["noise"], a.shape)
    out = np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)
    if d.get("jpeg", 0) > 0:
        buf = io.BytesIO()
        Image.fromarray(out).save(buf, format="JPEG", quality=int(d["jpeg"]))
        out = np.asarray(Image.open(buf).convert("RGB"))
    return out


# --- checks --------------------------------------------------------------------------------
def label_exactness(engine: SyntheticEngine, p: dict, labels: dict, supersample: int = 8) -> dict:
    """Do the labels land on their own surface? Two checks independent of how the labels were
    made (projection, and a ray cast from the point towards the camera):

    1. a camera ray through each label's exact pixel position (sub-pixel) is cast into the
       face of parameters ``p``: for a visible label its first hit must be the labelled
       surface point, for a hidden one a hit must come before the point;
    2. the face is ray cast again on a grid of ``supersample`` samples per pixel (what the
       rendered image shows, finer): the sample nearest a visible label (at most
       ``0.71 / supersample`` px away) must see the label's own surface.

    Returns dict: over the M visible defined points of both schemes, (M,) arrays
    ``in_front_mm`` (check 1: how far before the labelled point the camera ray first hits the
    mesh, mm, 0 when it reaches the point or passes it: a ray through a vertex or edge can
    slip between triangles), ``own_ray`` (the hit triangle shares a vertex with the labelled
    point's triangle), ``offset_px`` (check 2: image distance of the seen surface point from
    the label, px; NaN where the sample misses the face: a point on the mesh's border),
    ``own_raster`` (its triangle shares a vertex with the label's); over the H hidden defined
    points inside the image, ``hidden_blocked`` (H,) bool (check 1's ray stops at the point
    or before it, within 0.01 mm).
    """
    from morphable.raster import visibility
    from morphable.raster.visibility import cast, scene

    m = engine.model
    cam = labels["camera"]
    if cam.kind == "affine":
        raise InputError("label_exactness: the engine's cameras are perspective")
    verts = m.vertices(p["identity"], p["expression"])
    vis = visibility(verts, m.triangles, cam, supersample=supersample)
    tid, bary = vis.triangle_id, vis.barycentric
    Hs, Ws = vis.shape
    sc = scene(verts, m.triangles)
    out = {k: [] for k in ("in_front_mm", "own_ray", "offset_px", "own_raster", "hidden_blocked")}

    def own(t, tri_of_label):
        corners = np.where((t >= 0)[:, None], m.triangles[np.maximum(t, 0)], -2)
        return (corners[:, :, None] == tri_of_label[:, None, :]).any((1, 2))

    for key, scheme in engine.schemes.items():
        xy_all = labels[f"points{key}"].astype(np.float64)
        P_all = scheme.points(verts)
        with np.errstate(invalid="ignore"):
            inside = ((xy_all > -0.5) & (xy_all < engine.resolution - 0.5)).all(1)
        # check 1: a ray from the pinhole through the label's pixel position
        dc = np.stack([(xy_all[:, 0] - cam.principal[0]) / cam.focal,
                       (cam.principal[1] - xy_all[:, 1]) / cam.focal, -np.ones(len(xy_all))], 1)
        dc /= np.linalg.norm(dc, axis=1, keepdims=True)
        d = dc @ cam.rotation
        rays = np.concatenate([np.broadcast_to(cam.centre, d.shape), d], 1)
        ok = np.isfinite(rays).all(1)
        t_hit = np.full(len(d), np.inf)
        tri = np.full(len(d), -1)
        t_hit[ok], tri[ok], _ = cast(sc, rays[ok].astype(np.float32))
        dist = np.linalg.norm(P_all - cam.centre, axis=1)
        seen = labels[f"visible{key}"] & scheme.defined
        out["in_front_mm"].append(np.maximum(dist[seen] - t_hit[seen], 0.0))
        out["own_ray"].append(own(tri[seen], scheme.vertices[seen]))
        hidden = ~labels[f"visible{key}"] & scheme.defined & inside
        out["hidden_blocked"].append(t_hit[hidden] <= dist[hidden] + 0.01)
        # check 2: the sample nearest the label; (i, j) sits at ((j + .5) / s - .5, (i + .5) / s - .5)
        xy = xy_all[seen]
        j = np.clip(np.floor((xy[:, 0] + 0.5) * supersample).astype(int), 0, Ws - 1)
        i = np.clip(np.floor((xy[:, 1] + 0.5) * supersample).astype(int), 0, Hs - 1)
        t = tid[i, j]
        hit = t >= 0
        S = np.full((len(xy), 3), np.nan)
        S[hit] = np.einsum("nk,nkc->nc", bary[i[hit], j[hit]].astype(np.float64),
                           verts[m.triangles[t[hit]]])
        out["offset_px"].append(np.linalg.norm(cam.project(S) - xy, axis=1))
        out["own_raster"].append(own(t, scheme.vertices[seen]))
    return {k: np.concatenate(v) for k, v in out.items()}


def yaw_grid(engine: SyntheticEngine, yaws=(-90, -60, -30, 0, 30, 60, 90), rows: int = 3,
             seed: int = 0) -> np.ndarray:
    """A picture of random faces over yaw: ``rows`` faces per yaw (column), each drawn at
    random and then turned to the column's yaw, visible 68-point labels drawn as green
    dots, hidden ones red -> (rows * R, len(yaws) * R, 3) uint8."""
    R = engine.resolution
    out = np.zeros((rows * R, len(yaws) * R, 3), np.uint8)
    for r in range(rows):
        rng = np.random.default_rng([seed, r])
        p = engine.draw(rng)
        for c, yaw in enumerate(yaws):
            q = dict(p, pose=np.array([yaw, p["pose"][1] * 0.5, p["pose"][2] * 0.5]), occluders=[])
            f = engine.render(q)
            img = f["image"].copy()
            for xy, vis in zip(f["points68"], f["visible68"]):
                if not np.isfinite(xy).all():
                    continue
                i, j = int(round(xy[1])), int(round(xy[0]))
                if 0 <= i < R and 0 <= j < R:
                    img[i, j] = (0, 255, 0) if vis else (255, 0, 0)
            out[r * R:(r + 1) * R, c * R:(c + 1) * R] = img
    return out


def check(model: str = "sfm", n: int = 20, resolution: int = 128, seed: int = 0,
          supersample: int = 8) -> dict:
    """:func:`label_exactness` over ``n`` random faces (procedural albedo and backgrounds:
    the labels do not depend on them) -> summary dict."""
    eng = SyntheticEngine(model, resolution, degrade=False, occluders=False)
    parts = []
    t0 = time.perf_counter()
    for k in range(n):
        f = eng.sample(np.random.default_rng([seed, k]))
        parts.append(label_exactness(eng, f["params"], f, supersample))
    ex = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    hit = np.isfinite(ex["offset_px"])
    return {"model": model, "faces": n, "resolution": resolution, "supersample": supersample,
            "visible_labels": int(len(ex["in_front_mm"])),
            "ray_nothing_in_front_share": float(np.mean(ex["in_front_mm"] <= 0.01)),
            "ray_own_triangle_share": float(ex["own_ray"].mean()),
            "raster_on_face_share": float(hit.mean()),
            "raster_offset_px_max": float(ex["offset_px"][hit].max()),
            "raster_own_triangle_share": float(ex["own_raster"][hit].mean()),
            "hidden_labels": int(len(ex["hidden_blocked"])),
            "hidden_blocked_share": float(ex["hidden_blocked"].mean()),
            "seconds": round(time.perf_counter() - t0, 1)}


def main(argv=None) -> int:
    """``python -m neural.faces.synthetic check|grid``: the label check (JSON to stdout) or the
    picture of faces over yaw (``--out`` PNG)."""
    import argparse
    import json
    import sys

    from morphable.errors import MorphableError

    ap = argparse.ArgumentParser(prog="python -m neural.faces.synthetic", description=main.__doc__)
    ap.add_argument("what", choices=("check", "grid"))
    ap.add_argument("--model", default="sfm")
    ap.add_argument("--n", type=int, default=20, help="check: faces")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data", default="../shared/data", help="grid: London photos for textures")
    ap.add_argument("--textures", type=int, default=4, help="grid: photo textures (0: none)")
    ap.add_argument("--out", help="grid: the PNG")
    a = ap.parse_args(argv)
    try:
        if a.what == "check":
            print(json.dumps(check(a.model, a.n, a.resolution, a.seed)))
            return 0
        if not a.out:
            raise InputError("grid: --out PNG is required")
        from PIL import Image

        from morphable.io.atomic import atomic_path

        tex = ()
        if a.textures:
            tex = texture_bank(london_photos(a.data)[:a.textures], a.model, 256)[0]
        eng = SyntheticEngine(a.model, a.resolution, textures=tex, texture_share=1.0, degrade=False)
        img = yaw_grid(eng, seed=a.seed)
        with atomic_path(a.out) as tmp:
            Image.fromarray(img).save(tmp, format="PNG")
        return 0
    except MorphableError as e:
        print(f"neural.faces.synthetic: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
