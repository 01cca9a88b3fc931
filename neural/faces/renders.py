"""Random faces of a 3DMM rendered with exact labels, in the FFHQ-style framing.

:class:`SyntheticFaces`: random identities, expressions and poses rendered by the
rasterisation core (:mod:`morphable.raster`) with exact labels — camera-frame normal maps,
face masks, 68 landmarks, identity ids — and Lambertian images under random SH lighting,
procedural skin albedo and random backgrounds. :func:`template`: where the mean face's 68
landmarks fall in that framing, the target every aligned photo is warped to
(:func:`neural.gar.data.align_image`).

Framing: FFHQ's rule (:func:`morphable.refinement.face_frame`) — the crop is ``4 x`` the
inter-ocular distance wide and centred ``0.1`` of the way from the eye midpoint to the mouth
centre; for the SFM mean face this is a 257 mm wide square. Images are float tensors
(B, 3, R, R) in [-1, 1]; landmarks are pixels (x right, y down, 0-based pixel centres), NaN
where the model defines no fixed vertex.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch

from morphable.refinement.crop import face_frame

__all__ = ["SyntheticFaces", "template"]

# base skin reflectances (linear RGB) from light to dark; a face mixes two neighbours
_SKIN = np.array([[0.85, 0.66, 0.56], [0.78, 0.57, 0.45], [0.67, 0.47, 0.36],
                  [0.53, 0.36, 0.26], [0.38, 0.25, 0.18], [0.26, 0.17, 0.12]])


@lru_cache(maxsize=4)
def _model(name: str):
    from morphable import load_model

    return load_model(name)


def _camera(model, resolution: int, yaw=0.0, pitch=0.0, roll=0.0):
    from morphable.camera import Camera

    centre, width = face_frame(model.landmark_positions())
    return Camera.looking_at_face((resolution, resolution), yaw=yaw, pitch=pitch, roll=roll,
                                  face_width_px=150.0 * resolution / width, center=centre)


def template(resolution: int = 64, model: str = "sfm") -> np.ndarray:
    """(68, 2) pixel positions of the mean face's landmarks, frontal, in an aligned
    ``resolution`` crop (NaN where the model has no fixed landmark vertex).

    Examples
    --------
    >>> t = template(64)
    >>> t.shape, bool(t[36, 0] < 32 < t[45, 0])  # subject's right eye on the image's left
    ((68, 2), True)
    """
    m = _model(model)
    return _camera(m, resolution).project(m.landmark_positions())


class SyntheticFaces:
    """Random faces of a 3DMM rendered with exact labels.

    Parameters
    ----------
    model : model name or path (``morphable.load_model``)
    resolution : image side, px
    yaw_max, pitch_max, roll_max : degrees, poses are uniform in [-max, max]
    identity_std : spread of identity coefficients (1 = the model's own)
    expression_max : blendshape weights are uniform in [0, max] on one or two random
        expressions (PCA expressions: N(0, max^2))
    n_identities : None for a fresh identity per sample, or the size of a fixed pool
        (identity ids index the pool; albedo is tied to the identity)
    supersample : antialiasing samples per pixel along each axis
    seed : seed of the identity pool
    expression_active : blendshape models: how many random blendshapes a face may use

    Examples
    --------
    >>> data = SyntheticFaces(resolution=32)
    >>> b = data.sample(2, rng=0, pair=True)
    >>> b["image"].shape, b["normals_b"].shape
    (torch.Size([2, 3, 32, 32]), torch.Size([2, 3, 32, 32]))
    """

    def __init__(self, model="sfm", resolution=64, yaw_max=45.0, pitch_max=20.0, roll_max=10.0,
                 identity_std=1.0, expression_max=0.8, n_identities=None, supersample=2, seed=0,
                 expression_active=2):
        self.model = _model(model) if isinstance(model, str) else model
        self.resolution = int(resolution)
        self.pose_max = np.array([yaw_max, pitch_max, roll_max], dtype=np.float64)
        self.identity_std, self.expression_max = float(identity_std), float(expression_max)
        self.supersample = int(supersample)
        self.expression_active = int(expression_active)
        self.n_identities = n_identities
        if n_identities is not None:
            pool = np.random.default_rng(seed)
            self._pool = [self.draw_identity(pool) for _ in range(int(n_identities))]

    @classmethod
    def from_config(cls, config, **kwargs):
        """The generator described by a :class:`neural.gar.config.GARConfig`."""
        return cls(model=config.model, resolution=config.resolution, yaw_max=config.yaw_max,
                   pitch_max=config.pitch_max, roll_max=config.roll_max,
                   identity_std=config.identity_std, expression_max=config.expression_max, **kwargs)

    # --- random parameters --------------------------------------------------------------
    def draw(self, rng) -> dict:
        """The parameters of one random face, drawn from the numpy Generator ``rng`` in this
        order: ``identity`` (K,), ``albedo`` (V, 3) and ``tone`` (:meth:`draw_identity`),
        ``expression`` (E,), ``pose`` (3,) yaw, pitch, roll in degrees, ``sh`` (9, 3) and
        ``background`` (R, R, 3) — the arguments of :meth:`render` and the skin tone."""
        face = self.draw_identity(rng)
        face["expression"] = self.draw_expression(rng)
        face["pose"] = self.draw_pose(rng)
        face["sh"] = self.draw_light(rng)
        face["background"] = self.draw_background(rng)
        return face

    def draw_pose(self, rng) -> np.ndarray:
        """(3,) yaw, pitch, roll in degrees, uniform within the pose limits."""
        return rng.uniform(-1, 1, 3) * self.pose_max

    def draw_identity(self, rng) -> dict:
        """Shape coefficients, a procedural albedo (per-vertex RGB in [0, 1]) and its skin
        tone in units of its standard deviation (light -> dark)."""
        m = self.model
        alpha = rng.standard_normal(m.n_identity) * self.identity_std
        k = rng.uniform(0, len(_SKIN) - 1)
        tone = (k - (len(_SKIN) - 1) / 2) / ((len(_SKIN) - 1) / 12 ** 0.5)
        base = (1 - k % 1) * _SKIN[int(k)] + (k % 1) * _SKIN[min(int(k) + 1, len(_SKIN) - 1)]
        # low-frequency blotches: a few random plane waves over the mean shape (mm)
        x = m.mean / 100.0
        freq = rng.normal(0, 3.0, (4, 3))
        waves = np.sin(x @ freq.T + rng.uniform(0, 2 * np.pi, 4)) @ rng.normal(0, 0.04, (4, 3))
        albedo = base * (1 + waves)
        # lips redder, eyebrows darker (distances to the landmark vertices, mm)
        lm = m.landmark_positions()
        for group, tint, radius in ((slice(48, 68), (1.15, 0.8, 0.8), 8.0),
                                    (slice(17, 27), (0.45, 0.42, 0.4), 5.0)):
            pts = lm[group][~np.isnan(lm[group, 0])]
            d = np.min(np.linalg.norm(m.mean[:, None] - pts[None], axis=-1), axis=1)
            w = np.exp(-(d / radius) ** 2)[:, None]
            albedo = albedo * (1 - w + w * np.asarray(tint))
        return {"identity": alpha, "albedo": np.clip(albedo, 0.02, 1.0), "tone": tone}

    def draw_expression(self, rng) -> np.ndarray:
        """(E,) blendshape weights on up to ``expression_active`` expressions (each on with
        probability 0.7, weight uniform in [0, ``expression_max``]), or PCA coefficients."""
        m = self.model
        e = np.zeros(m.n_expression)
        if m.n_expression == 0:
            return e
        if m.expression_kind == "blendshapes":
            on = rng.choice(m.n_expression, size=min(self.expression_active, m.n_expression), replace=False)
            e[on] = rng.uniform(0, self.expression_max, len(on)) * (rng.random(len(on)) < 0.7)
        else:
            e = rng.standard_normal(m.n_expression) * self.expression_max
        return e

    def draw_light(self, rng) -> np.ndarray:
        """(9, 3) SH lighting: one tinted directional light from the camera's side, ambient."""
        from morphable.raster import DirectionalLight, sh_from_lights

        d = rng.normal(0, 1, 3)
        d[2] = abs(d[2]) + 0.5                      # from the camera's hemisphere
        tint = 1 + rng.normal(0, 0.08, 3)
        light = DirectionalLight(d, rng.uniform(0.4, 1.0) * tint)
        return sh_from_lights([light], ambient=rng.uniform(0.25, 0.6) * tint)

    def draw_background(self, rng) -> np.ndarray:
        """(R, R, 3) in [0, 1]: a colour gradient plus a few soft blobs."""
        R = self.resolution
        y, x = np.mgrid[0:R, 0:R] / R
        c0, c1 = rng.uniform(0, 1, 3), rng.uniform(0, 1, 3)
        t = np.clip(x * rng.uniform(-1, 1) + y * rng.uniform(-1, 1) + 0.5, 0, 1)[..., None]
        bg = (1 - t) * c0 + t * c1
        for _ in range(rng.integers(0, 4)):
            cx, cy, r = rng.uniform(0, 1), rng.uniform(0, 1), rng.uniform(0.05, 0.3)
            w = np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / r ** 2)[..., None]
            bg = (1 - w) * bg + w * rng.uniform(0, 1, 3)
        return bg

    # --- rendering ----------------------------------------------------------------------
    def render(self, identity, albedo, expression, pose, sh, background) -> dict:
        """One face -> dict of numpy arrays.

        identity (K,), albedo (V, 3) in [0, 1], expression (E,), pose (3,) yaw, pitch, roll
        in degrees, sh (9, 3), background (R, R, 3) -> ``image`` (R, R, 3) in [0, 1],
        ``normals`` (R, R, 3) camera frame, zero outside, ``mask`` (R, R) float coverage,
        ``landmarks`` (68, 2) px (NaN where undefined).
        """
        from morphable.raster import normal_map, render, visibility

        m = self.model
        cam = _camera(m, self.resolution, *pose)
        verts = m.vertices(identity, expression)
        vis = visibility(verts, m.triangles, cam, supersample=self.supersample)
        normals = normal_map(verts, m.triangles, vis=vis)            # (R, R, 3), resolved
        image = render(verts, m.triangles, colors=albedo, light=sh, background=background,
                       vis=vis)
        cover = vis.coverage()
        lm = cam.project(m.landmark_positions(identity, expression))
        return {"image": image, "normals": normals, "mask": cover,
                "landmarks": lm}

    def sample(self, batch_size: int, rng=None, pair: bool = False) -> dict:
        """A batch of random faces as torch tensors.

        Returns
        -------
        dict with ``image`` (B, 3, R, R) in [-1, 1], ``normals`` (B, 3, R, R), ``mask``
        (B, 1, R, R) in [0, 1], ``landmarks`` (B, 68, 2) px (NaN where undefined),
        ``identity_id`` (B,) int64 (-1 without a pool), ``identity`` (B, K) the identity
        coefficients and ``skin_tone`` (B,) the albedo's tone, both in units of their
        standard deviation, ``pose`` (B, 3) degrees; with
        ``pair=True`` also ``image_b``, ``normals_b``, ``mask_b``, ``landmarks_b``,
        ``pose_b``: the same identities (and albedo) under another expression, pose,
        light and background.
        """
        rng = np.random.default_rng(rng)
        views = ("", "_b") if pair else ("",)
        out = {f"{k}{v}": [] for v in views for k in ("image", "normals", "mask", "landmarks", "pose")}
        out["identity_id"], out["identity"], out["skin_tone"] = [], [], []
        for _ in range(batch_size):
            if self.n_identities is None:
                ident, iid = self.draw_identity(rng), -1
            else:
                iid = int(rng.integers(self.n_identities))
                ident = self._pool[iid]
            out["identity_id"].append(iid)
            out["identity"].append(ident["identity"])
            out["skin_tone"].append(ident["tone"])
            for v in views:
                # pose before expression (draw's order differs): the same batches as always
                pose = self.draw_pose(rng)
                r = self.render(ident["identity"], ident["albedo"], self.draw_expression(rng),
                                pose, self.draw_light(rng), self.draw_background(rng))
                out[f"image{v}"].append(r["image"].transpose(2, 0, 1) * 2 - 1)
                out[f"normals{v}"].append(r["normals"].transpose(2, 0, 1))
                out[f"mask{v}"].append(r["mask"][None])
                out[f"landmarks{v}"].append(r["landmarks"])
                out[f"pose{v}"].append(pose)
        batch = {k: torch.as_tensor(np.stack(v), dtype=torch.float32) for k, v in out.items()
                 if k != "identity_id"}
        batch["identity_id"] = torch.as_tensor(out["identity_id"], dtype=torch.int64)
        return batch
