"""The reconstruction methods of the Florence protocol: one class each, and their registry.

A method is made once per run and prepared once per scan (:func:`prepare_methods`;
:meth:`Method.prepare` does what is the same for every video of the scan, untimed: the surface
fit of a reference method, eos' model, the GAR renderer), then reconstructs the face of each
video from its sampled frames (:func:`reconstruct_video`, which calls
:meth:`Method.reconstruct` on the frames with enough landmarks; the fit is timed). Adding a
method is one subclass of :class:`Method` added to :data:`METHODS`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from morphable.errors import FitError, InputError
from morphable.fitting import fit_landmarks_3d, fit_surface, outer_skin
from morphable.metrics import submesh

from ..peers import EosFitter
from ..scans import Scan

__all__ = ["MIN_LANDMARKS", "METHODS", "Frames", "Reconstruction", "Method", "Ours",
           "OursIndependent", "Eos", "MeanFace", "ScanFit", "SurfaceFit", "Landmarks3D", "Gar",
           "prepare_methods", "reconstruct_video", "gar_refiner"]

MIN_LANDMARKS = 10
"""Frames with fewer landmarks are dropped before reconstruction."""


@dataclass
class Frames:
    """The sampled frames of one video: what a method reconstructs the face from.

    Attributes
    ----------
    landmarks : (N, L, 2) px, NaN where missing: 68 iBUG points, or the face mesh's 478
        (detected with it); :meth:`ibug68` gives the 68 of either
    image_size : (W, H) px
    images : (N, H, W, 3) float in [0, 1], the frames themselves, or None (read or rendered
        only when a method has ``needs_images``)
    focal_px : the video camera's focal length (px) when known, else None
    detected : (N,) bool, the frames whose landmarks a detector found, or None
    landmark_std_px : (N, L) px, each point's predicted error where the detector gives one (the
        landmark network), else None
    """

    landmarks: np.ndarray
    image_size: tuple
    images: np.ndarray | None = None
    focal_px: float | None = None
    detected: np.ndarray | None = None
    landmark_std_px: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.landmarks)

    def ibug68(self) -> np.ndarray:
        """(N, 68, 2) px: the landmarks as 68 iBUG points (for methods that take only those;
        the face mesh's through :data:`morphable.detection.facemesh.FACEMESH_TO_IBUG68`)."""
        return ibug68_points(self.landmarks)


def ibug68_points(landmarks) -> np.ndarray:
    """(N, 68, 2) px of (N, 68 or 478, 2) landmarks (see :meth:`Frames.ibug68`)."""
    lm = np.asarray(landmarks, dtype=np.float64)
    if lm.shape[1] == 68:
        return lm
    from morphable.detection.facemesh import to_ibug68

    return to_ibug68(lm)


@dataclass
class Reconstruction:
    """One method's reconstruction of one video.

    Attributes
    ----------
    vertices : (V, 3) mm, the average of the per-frame meshes (model frame)
    triangles : (F, 3) int
    landmarks : (68, 3) mm on ``vertices``, NaN where the model has no fixed landmark vertex
    seconds : float, fitting time for the whole video (model loading excluded)
    n_frames : int
    info : dict, method-specific figures (landmark residuals...)
    vertex_ids : (V,) int, the model vertex of each row of ``vertices`` (models with eyes,
        teeth and a mouth interior are reduced to their skin surface)
    n_model_vertices : int, vertices of the full model (size of the per-vertex error maps)
    """

    vertices: np.ndarray
    triangles: np.ndarray
    landmarks: np.ndarray
    seconds: float
    n_frames: int
    info: dict = field(default_factory=dict)
    vertex_ids: np.ndarray | None = None
    n_model_vertices: int = 0

    @classmethod
    def from_vertices(cls, model, vertices, seconds: float, n_frames: int,
                      info: dict | None = None) -> Reconstruction:
        """Package a model-frame mesh ((V, 3) mm of all the model's vertices): landmarks from
        the model's ids, its outer skin only (:func:`morphable.fitting.outer_skin`: a scan has
        no eyeballs, teeth or nostrils' insides)."""
        lm = np.full((68, 3), np.nan)
        ok = model.landmark_ids >= 0
        lm[ok] = vertices[model.landmark_ids[ok]]
        tri = model.triangles
        ids = np.arange(model.n_vertices)
        keep = outer_skin(model)
        if not keep.all():
            ids, tri = submesh(tri, keep)
        return cls(vertices[ids], tri, lm, seconds, n_frames, dict(info or {}), ids,
                   model.n_vertices)


class Method:
    """A reconstruction method of the protocol: subclass it, name it, add it to :data:`METHODS`.

    One instance serves one run: :meth:`prepare` once per scan, then :meth:`reconstruct` per
    video. Work that is the same for every video (loading, fitting the scan itself) belongs
    in :meth:`prepare` or in the instance, so that it is neither repeated nor timed.
    """

    name: ClassVar[str] = ""
    needs_images: ClassVar[bool] = False
    """Whether :meth:`reconstruct` uses ``frames.images`` (the protocol then renders the
    synthetic frames or reads the real ones)."""

    model = None
    scan: Scan | None = None

    def prepare(self, model, scan: Scan | None = None) -> None:
        """Get ready for the videos of ``scan`` with ``model`` (MorphableModel); untimed.
        Subclasses that do more call this first. An error here stops the run (a FitError
        of :meth:`reconstruct` fails one cell only)."""
        self.model, self.scan = model, scan

    def reconstruct(self, frames: Frames, settings: dict) -> Reconstruction:
        """The face of one video from its frames (each with at least :data:`MIN_LANDMARKS`
        landmarks); ``settings``: the method's own, e.g. its iterations. The time of the fit
        goes in ``Reconstruction.seconds``."""
        raise NotImplementedError


def _video_fit_options(settings: dict, frames: Frames) -> dict:
    """Landmark-fit settings for a video's frames: a pinhole camera with the video's focal
    length when it is known (unless ``settings["camera"]`` says otherwise), the landmark
    noise the detector's σ where it gives one (``Frames.landmark_std_px``), else estimated (a
    video's is unknown: detector, resolution, blur), unless set, and for frames whose
    landmarks were detected (``Frames.detected``) the detector's settings
    (:func:`morphable.fitting.options.detected_settings`: its model error, its frames one
    look at the face in a shared fit, the face mesh's convention) unless set."""
    from morphable.fitting.options import detected_settings

    out = dict(settings)
    focal_px, detected = frames.focal_px, frames.detected
    out.setdefault("camera", "perspective" if focal_px is not None else "affine")
    if out["camera"] == "perspective" and focal_px is not None:
        out.setdefault("focal_px", focal_px)
    out.setdefault("landmark_std_px", "auto" if frames.landmark_std_px is None
                   else frames.landmark_std_px)
    if detected is not None and np.any(detected):
        for k, v in detected_settings(detected, np.shape(frames.landmarks)[1]).items():
            if k != "convention" or "contour" not in out:
                out.setdefault(k, v)
    return out


class Ours(Method):
    """:func:`morphable.fitting.fit_landmarks` on all the frames, one identity shared by them;
    the per-frame meshes averaged. It fits whatever points the frames have (the face mesh's
    478 when it detected them).

    ``settings``: the fit's keyword arguments (``n_iterations``, ``n_identity``...). A pinhole
    camera with the video's focal length where it is known (unless ``settings["camera"]`` is
    "affine"), else an affine one; the landmark noise the detector's σ where it gives one
    (``Frames.landmark_std_px``), else estimated (``landmark_std_px="auto"``); and, for
    detected frames, the detector's model error
    (:data:`morphable.fitting.noise.DETECTED_MODEL_STD_MM`), unless ``settings`` give
    ``landmark_std_px`` / ``model_std_mm``.
    """

    name = "ours"
    shared_identity = True

    def prepare(self, model, scan: Scan | None = None) -> None:
        super().prepare(model, scan)
        try:
            from morphable.fitting import fit_landmarks
        except ImportError as e:
            raise InputError(f"method {self.name}: morphable.fitting is not available ({e})") from None
        self.fit_landmarks = fit_landmarks

    def reconstruct(self, frames: Frames, settings: dict) -> Reconstruction:
        options = _video_fit_options(settings, frames)
        t = time.perf_counter()
        res = self.fit_landmarks(self.model, frames.landmarks, frames.image_size,
                                 shared_identity=self.shared_identity, **options)
        v = res.vertices().mean(0)
        dt = time.perf_counter() - t
        return Reconstruction.from_vertices(
            self.model, v, dt, len(frames),
            {"landmark_rmse_px": float(np.mean(res.landmark_rmse_px)),
             "landmark_std_px": float(np.mean(res.landmark_std_px)),
             "camera": options["camera"]})


class OursIndependent(Ours):
    """:class:`Ours` with an identity per frame (independent fits), averaged."""

    name = "ours-independent"
    shared_identity = False


class OursPhotometric(Ours):
    """:class:`Ours`' shared landmark fit, then the photometric refinement of all the frames
    at once (:func:`morphable.refinement.refine_shared`: one identity, an albedo texture,
    each frame's light, a robust mask) with the ``renderer`` of the class ("classical");
    the refined per-frame meshes averaged. ``settings``: ``steps`` (Adam steps, default
    100), ``weights`` (loss-weight overrides), ``resolution`` (crop px, default the
    refinement's); the others go to the landmark fit as for :class:`Ours`. Torch runs on
    one thread (the refinement's speed target is one core)."""

    name = "ours-photometric"
    needs_images = True
    renderer = "classical"

    def prepare(self, model, scan: Scan | None = None) -> None:
        super().prepare(model, scan)
        import torch

        from morphable.refinement import refine_shared

        torch.set_num_threads(1)
        self.refine_shared = refine_shared

    def reconstruct(self, frames: Frames, settings: dict) -> Reconstruction:
        if frames.images is None:
            raise InputError(f"method {self.name}: needs the video frames (synthetic videos render them)")
        settings = dict(settings)
        refine = {k: settings.pop(k) for k in ("steps", "weights", "resolution") if k in settings}
        options = _video_fit_options(settings, frames)
        t = time.perf_counter()
        res = self.fit_landmarks(self.model, frames.landmarks, frames.image_size,
                                 shared_identity=True, **options)
        refined, reports, _ = self.refine_shared(list(frames.images), res, self.renderer, **refine)
        v = refined.vertices().mean(0)
        dt = time.perf_counter() - t
        return Reconstruction.from_vertices(self.model, v, dt, len(frames), {
            "mask_coverage": [round(float(r["mask_coverage"]), 3) for r in reports],
            "photometric_residual": [round(float(r["photometric_residual"]), 4) for r in reports],
            "fallback": [bool(r["fallback"]) for r in reports],
            "refine_s": round(float(reports[0]["runtime_s"]), 2), "camera": options["camera"]})


class OursPhotometricGar(OursPhotometric):
    """:class:`OursPhotometric` with the GAR as the refinement's renderer (the neural plugin)."""

    name = "ours-photometric-gar"
    renderer = "gar"

    def __init__(self):
        gar_refiner()      # the plugin is installed: fails before the run's videos


class Eos(Method):
    """eos-py's fit (:class:`evaluation.peers.EosFitter`) of the SFM it ships with, whatever
    the protocol's model, one affine camera and fit per frame, averaged. ``settings``: the
    fitter's (``num_iterations``, ``lambda_identity``); one fitter per settings, loaded once
    per run."""

    name = "eos"

    def __init__(self):
        self.fitters = {}

    def prepare(self, model, scan: Scan | None = None) -> None:
        from morphable import load_model

        super().prepare(model, scan)
        self.sfm = load_model("sfm")

    def reconstruct(self, frames: Frames, settings: dict) -> Reconstruction:
        key = tuple(sorted(settings.items()))
        if key not in self.fitters:
            self.fitters[key] = EosFitter(**settings)
        t = time.perf_counter()
        v = self.fitters[key].fit(frames.ibug68(), frames.image_size).mean(0)
        dt = time.perf_counter() - t
        return Reconstruction.from_vertices(self.sfm, v, dt, len(frames))


class MeanFace(Method):
    """The model's mean face, whatever the frames show (no fitting, 0 s)."""

    name = "mean-face"

    def reconstruct(self, frames: Frames, settings: dict) -> Reconstruction:
        return Reconstruction.from_vertices(self.model, self.model.mean.astype(np.float64), 0.0,
                                            len(frames))


class ScanFit(Method):
    """A reference, not a reconstruction from the frames: the model fitted to the scan itself,
    once per scan in :meth:`prepare` (it is the same in every condition); its time is in
    ``info`` (``<name>_seconds``), not per frame."""

    def fit_scan(self, model, scan: Scan):
        """-> (identity, expression) coefficients of ``model`` fitted to ``scan``."""
        raise NotImplementedError

    def prepare(self, model, scan: Scan | None = None) -> None:
        super().prepare(model, scan)
        if scan is None:
            raise InputError(f"method {self.name}: needs the scan")
        t = time.perf_counter()
        alpha, beta = self.fit_scan(model, scan)
        self.vertices = model.vertices(identity=alpha, expression=beta)
        self.seconds = time.perf_counter() - t

    def reconstruct(self, frames: Frames, settings: dict) -> Reconstruction:
        return Reconstruction.from_vertices(
            self.model, self.vertices, 0.0, len(frames),
            {f"{self.name.replace('-', '_')}_seconds": round(self.seconds, 3)})


class SurfaceFit(ScanFit):
    """The model fitted to the scan's surface (identity, expressions and a rigid pose,
    :func:`morphable.fitting.fit_surface`): the error no method using this model can go
    below."""

    name = "surface-fit"

    def fit_scan(self, model, scan: Scan):
        return fit_surface(model, scan.vertices, scan.triangles, scan.landmarks, n_iterations=15,
                           expression=True, pose="joint", name=scan.source)


class Landmarks3D(ScanFit):
    """The model fitted to the scan's own 3D landmarks
    (:func:`morphable.fitting.fit_landmarks_3d`): what the landmarks tell about the face's
    shape under the model, without images."""

    name = "landmarks-3d"

    def fit_scan(self, model, scan: Scan):
        return fit_landmarks_3d(model, scan.landmarks, name=scan.source)


def gar_refiner():
    """:func:`morphable.refinement.refine_frames`, or a one-line InputError when the neural
    plugin (the gar renderer) is not installed (callers check before a long run)."""
    try:
        import neural.gar.renderer  # noqa: F401
    except ImportError as e:
        raise InputError(f"method gar: the neural plugin is not installed ({e}); "
                         "pip install -e '.[neural]'") from None
    from morphable.refinement import refine_frames

    return refine_frames


class Gar(Method):
    """Each frame's landmark fit (the one :class:`OursIndependent` makes of it: the same
    points, the face mesh's 478 when it detected them, with the camera and noise defaults of
    :class:`Ours`) refined by inverting the GAR renderer on the frame itself
    (:func:`morphable.refinement.refine_frames`), then averaged. ``settings``:
    ``steps`` (refinement steps, default 100), ``region`` (the renderer's
    ``photometric_region``, default "crop"), ``weights`` (overrides of the refinement's
    :data:`~morphable.refinement.DEFAULT_WEIGHTS`). The renderer is loaded once per run."""

    name = "gar"
    needs_images = True

    def __init__(self):
        self.refine_frames = gar_refiner()     # made before the run's videos: fails early
        self.renderer = None

    def prepare(self, model, scan: Scan | None = None) -> None:
        super().prepare(model, scan)
        if self.renderer is None:          # outside the timed fits (as eos' model)
            import torch

            from morphable.renderer_plugins import get_renderer

            self.renderer = get_renderer("gar")
            # torch's first optimizer imports its compiler (about 1 s): not part of a fit
            torch.optim.Adam([torch.zeros(1, requires_grad=True)])

    def reconstruct(self, frames: Frames, settings: dict) -> Reconstruction:
        if frames.images is None:
            raise InputError("method gar: needs the video frames (synthetic videos render them)")
        t = time.perf_counter()
        # the region only picks the pixel mask: one loaded generator serves either
        self.renderer.photometric_region = settings.get("region", "crop")
        verts, reports = self.refine_frames(
            self.model, np.asarray(frames.images), frames.landmarks, self.renderer,
            steps=int(settings.get("steps", 100)), weights=settings.get("weights"),
            fit_options=_video_fit_options({}, frames))
        dt = time.perf_counter() - t
        return Reconstruction.from_vertices(self.model, verts.mean(0), dt, len(frames), {
            "photometric_loss_first_last": [[r["photometric_loss"][0], r["photometric_loss"][-1]]
                                            for r in reports],
            "latent_init": reports[0]["latent_init"], "generator": reports[0]["renderer_weights"]})


METHODS: dict[str, type[Method]] = {cls.name: cls for cls in (
    Ours, OursIndependent, OursPhotometric, OursPhotometricGar, Eos, MeanFace, SurfaceFit,
    Landmarks3D, Gar)}
"""The methods by name (``--methods``)."""


def prepare_methods(names, model, scan: Scan | None = None) -> dict[str, Method]:
    """One instance of each named method (:data:`METHODS`), prepared for ``scan`` with
    ``model`` -> ``{name: method}``; an InputError for an unknown name."""
    for m in names:
        if m not in METHODS:
            raise InputError(f"unknown method {m!r}; choose from {', '.join(METHODS)}")
    made = {m: METHODS[m]() for m in names}
    for method in made.values():
        method.prepare(model, scan)
    return made


def reconstruct_video(method: Method, frames: Frames, settings: dict | None = None) -> Reconstruction:
    """``method`` on one video -> Reconstruction (the average of the per-frame meshes).

    A frame with fewer than :data:`MIN_LANDMARKS` landmarks is a detector failure: the video
    goes on without it (FitError when none is left). ``settings``: the method's own (see its
    class), e.g. ``n_iterations`` of ours, ``num_iterations`` of eos, ``steps`` of gar.
    """
    lm = np.asarray(frames.landmarks, dtype=np.float64)
    if lm.ndim != 3 or lm.shape[1] not in (68, 478) or lm.shape[2] != 2:
        raise InputError(f"{method.name}: expected (N, 68, 2) or (N, 478, 2) landmarks, got {lm.shape}")
    usable = np.isfinite(lm).all(-1).sum(-1) >= MIN_LANDMARKS
    if not usable.any():
        raise FitError(f"{method.name}: no frame has {MIN_LANDMARKS} landmarks")
    kept = Frames(lm[usable], frames.image_size,
                  None if frames.images is None else np.asarray(frames.images)[usable],
                  frames.focal_px,
                  None if frames.detected is None else np.asarray(frames.detected, dtype=bool)[usable],
                  None if frames.landmark_std_px is None else np.asarray(frames.landmark_std_px)[usable])
    return method.reconstruct(kept, dict(settings or {}))
