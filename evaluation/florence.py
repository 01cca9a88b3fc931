"""The Florence evaluation protocol on any scan: reconstruct from video frames, compare.

For each condition a video of the scan is made (synthetic: :mod:`evaluation.videos`; or
real frames in a Florence-layout folder), ``--frames`` frames are sampled uniformly, each
method reconstructs the face from their landmarks, the per-frame meshes are averaged, and the
average is compared with the scan (:func:`morphable.metrics.compare_to_scan`: landmark
similarity, crop of 95 mm around the nose tip, ICP, point-to-plane error per vertex).

Command::

    python -m evaluation.florence --scan ../shared/data/scans/james/james.obj \\
        --scan-landmarks ../shared/data/scans/james/james.ljson \\
        --methods ours eos mean-face --report reports/florence_james.json

prints a table (method x condition, mean ± std of the point-to-plane error in mm, seconds per
frame) and writes the JSON report plus the per-vertex errors (``.npz`` beside the report).
One synthetic video per condition is one draw of a head-pose trajectory and of landmark noise;
``--n-videos 5`` runs five draws (seeds ``--seed`` to ``--seed + 4``) and gives the mean and
standard deviation over them. Methods ``surface-fit`` and ``landmarks-3d`` are no
reconstructions from the frames but the model fitted to the scan itself: to its surface (the
error no method with that model can go below), or to its own 3D landmarks (what the
landmarks say about the face's shape under the model, without images).

A validation set that is not a real scan (for choosing settings without touching the held-out
scans): ``--synthetic-scan ict --n-scans 8`` samples subjects from another model
(:func:`evaluation.scans.model_scan`, its own landmark vertices as the scan landmarks) and
reports, per method and condition, the mean over the subjects::

    python -m evaluation.florence --synthetic-scan ict --n-scans 8 \
        --methods ours ours-independent eos mean-face --report reports/florence_ict.json

or subjects of the fitted model itself with a landmark definition error added
(``--synthetic-scan sfm --definition-noise 2.5``); ``--expression-std`` gives them
expressions. With ``--detect`` their frames are rendered and dlib finds the landmarks;
``--appearance PHOTO ...`` dresses the subjects in the colours of photos of faces
(:func:`evaluation.scans.photo_colors`), without which a detector sees clay.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from morphable.errors import FitError, InputError, one_line_errors
from morphable.metrics import CROP_RADIUS_MM, compare_to_scan, submesh

from .scans import UNITS, Scan, load_scan, model_scan, outer_skin, photo_colors
from .videos import CONDITIONS, sample_frames, synthetic_video

__all__ = ["METHODS", "Reconstruction", "reconstruct", "evaluate", "detector_error",
           "run_protocol", "run_model_scans", "run_videos", "format_table", "save_heatmap", "main"]

MIN_LANDMARKS = 10
"""Frames with fewer landmarks are dropped before reconstruction."""
METHODS = ("ours", "ours-independent", "eos", "mean-face", "surface-fit", "landmarks-3d", "gar")
METRIC = ("point-to-plane distance (mm) from each reconstructed vertex within {r:g} mm of the "
          "nose tip to the tangent plane of the nearest scan vertex, after alignment")


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


def _reconstruction(model, vertices, seconds, n_frames, info=None) -> Reconstruction:
    """Package a model-frame mesh: landmarks from the model's ids, its outer skin only
    (:func:`evaluation.scans.outer_skin`: a scan has no eyeballs, teeth or nostrils' insides)."""
    lm = np.full((68, 3), np.nan)
    ok = model.landmark_ids >= 0
    lm[ok] = vertices[model.landmark_ids[ok]]
    tri = model.triangles
    ids = np.arange(model.n_vertices)
    keep = outer_skin(model)
    if not keep.all():
        ids, tri = submesh(tri, keep)
    return Reconstruction(vertices[ids], tri, lm, seconds, n_frames, dict(info or {}), ids,
                          model.n_vertices)


def _video_fit_options(effort: dict, focal_px, detected=None) -> dict:
    """Landmark-fit settings for a video's frames: a pinhole camera with the video's focal
    length when it is known (unless ``effort["camera"]`` says otherwise), the landmark
    noise estimated (a video's is unknown: detector, resolution, blur) unless set, and the
    detector's model error for frames whose landmarks were detected ((N,) bool ``detected``;
    :data:`morphable.fitting.noise.DETECTED_MODEL_STD_MM`) unless set."""
    from morphable.fitting.noise import frame_model_std

    out = dict(effort)
    out.setdefault("camera", "perspective" if focal_px is not None else "affine")
    if out["camera"] == "perspective" and focal_px is not None:
        out.setdefault("focal_px", focal_px)
    out.setdefault("landmark_std_px", "auto")
    if detected is not None and np.any(detected):
        out.setdefault("model_std_mm", frame_model_std(detected))
    return out


def gar_refiner():
    """:func:`morphable.refinement.refine_frames`, or a one-line InputError when the neural
    plugin (the gar renderer) is not installed (callers check before a long run)."""
    try:
        import neural.renderer  # noqa: F401
    except ImportError as e:
        raise InputError(f"method gar: the neural plugin is not installed ({e}); "
                         "pip install -e '.[neural]'") from None
    from morphable.refinement import refine_frames

    return refine_frames


def reconstruct(method: str, model, landmarks, image_size, effort: dict | None = None,
                peers: dict | None = None, images=None, focal_px=None,
                scan: Scan | None = None, detected=None) -> Reconstruction:
    """Reconstruct one face from the landmarks of several frames.

    Parameters
    ----------
    method : one of :data:`METHODS`
    model : MorphableModel (``eos`` always uses the SFM it ships with)
    landmarks : (N, 68, 2) px, NaN where missing
    image_size : (W, H) px
    effort : method settings: ``n_iterations``/``n_identity`` for ours, ``num_iterations``
        for eos, ``steps`` (refinement steps, default 100) for gar
    peers : cache of loaded peer fitters and of surface fits (reused between calls)
    images : (N, H, W, 3) the frames themselves (gar: the per-frame landmark fit of
        ours-independent refined by inverting the GAR,
        :func:`morphable.refinement.refine_frames`, then averaged)
    focal_px : the video camera's focal length (px) when known: ours and ours-independent
        then fit a pinhole camera with it (unless ``effort["camera"]`` says "affine"), and so
        do gar's starting fits (always); None = an affine camera. eos always fits its affine
        camera. Ours and ours-independent estimate the landmark noise
        (``landmark_std_px="auto"``) unless ``effort`` sets it; gar's starting fits always do.
    scan : the scan itself, for ``surface-fit`` and ``landmarks-3d``, which are not
        reconstructions from the frames but references: the model fitted to the scan's surface
        (identity, expressions and a rigid pose,
        :func:`evaluation.landmark_definitions.fit_surface`) — the error no method using this
        model can go below — or to the scan's own 3D landmarks
        (:func:`evaluation.landmark_definitions.fit_landmarks_3d`) — what the landmarks tell
        without images; their time is reported in ``info``, not per frame
    detected : (N,) bool or None, the frames whose landmarks a detector found: ours and
        ours-independent fit them with the detector's model error
        (:data:`morphable.fitting.noise.DETECTED_MODEL_STD_MM`) unless ``effort`` sets
        ``model_std_mm``

    Returns
    -------
    Reconstruction (average of the per-frame meshes; frames with fewer than
    :data:`MIN_LANDMARKS` landmarks are left out).
    """
    effort = dict(effort or {})
    peers = peers if peers is not None else {}
    lm = np.asarray(landmarks, dtype=np.float64)
    if lm.ndim != 3 or lm.shape[1:] != (68, 2):
        raise InputError(f"{method}: expected (N, 68, 2) landmarks, got {lm.shape}")
    # a frame with (almost) no landmarks is a detector failure: the video goes on without it
    usable = np.isfinite(lm).all(-1).sum(-1) >= MIN_LANDMARKS
    lm = lm[usable]
    detected = None if detected is None else np.asarray(detected, dtype=bool)[usable]
    if len(lm) == 0:
        raise FitError(f"{method}: no frame has {MIN_LANDMARKS} landmarks")
    if method == "mean-face":
        return _reconstruction(model, model.mean.astype(np.float64), 0.0, len(lm))
    if method in ("surface-fit", "landmarks-3d"):
        if scan is None:
            raise InputError(f"method {method}: needs the scan")
        key = (method, id(model), id(scan))
        if key not in peers:      # the same in every condition: fitted once
            from .landmark_definitions import fit_landmarks_3d, fit_surface

            t = time.perf_counter()
            alpha, beta = (fit_surface(model, scan, iterations=15, expression=True, pose="joint")
                           if method == "surface-fit" else fit_landmarks_3d(model, scan))
            peers[key] = (model.vertices(identity=alpha, expression=beta), time.perf_counter() - t)
        v, dt = peers[key]
        return _reconstruction(model, v, 0.0, len(lm),
                               {f"{method.replace('-', '_')}_seconds": round(dt, 3)})
    if method in ("ours", "ours-independent"):
        try:
            from morphable.fitting import fit_landmarks
        except ImportError as e:
            raise InputError(f"method {method}: morphable.fitting is not available ({e})") from None
        effort = _video_fit_options(effort, focal_px, detected)
        t = time.perf_counter()
        res = fit_landmarks(model, lm, image_size, shared_identity=method == "ours", **effort)
        v = res.vertices().mean(0)
        dt = time.perf_counter() - t
        return _reconstruction(model, v, dt, len(lm),
                               {"landmark_rmse_px": float(np.mean(res.landmark_rmse_px)),
                                "landmark_std_px": float(np.mean(res.landmark_std_px)),
                                "camera": effort["camera"]})
    if method == "eos":
        from morphable import load_model

        from .peers import EosFitter

        key = ("eos", tuple(sorted(effort.items())))
        if key not in peers:
            peers[key] = EosFitter(**effort)
        sfm = load_model("sfm")
        t = time.perf_counter()
        v = peers[key].fit(lm, image_size).mean(0)
        dt = time.perf_counter() - t
        return _reconstruction(sfm, v, dt, len(lm))
    if method == "gar":
        if images is None:
            raise InputError("method gar: needs the video frames (synthetic videos render them)")
        refine_frames = gar_refiner()
        if "gar" not in peers:          # loaded once, outside the timed fits (as eos' model)
            import torch

            from morphable.renderers import get_renderer

            peers["gar"] = get_renderer("gar")
            # torch's first optimizer imports its compiler (about 1 s): not part of a fit
            torch.optim.Adam([torch.zeros(1, requires_grad=True)])
        t = time.perf_counter()
        # each frame starts from the landmark fit ours-independent makes of it
        verts, reports = refine_frames(model, np.asarray(images)[usable], lm, peers["gar"],
                                       steps=int(effort.get("steps", 100)),
                                       fit_options=_video_fit_options({}, focal_px, detected))
        dt = time.perf_counter() - t
        return _reconstruction(model, verts.mean(0), dt, len(lm), {
            "photometric_loss_first_last": [[r["photometric_loss"][0], r["photometric_loss"][-1]]
                                            for r in reports],
            "latent_init": reports[0]["latent_init"], "generator": reports[0]["renderer_weights"]})
    raise InputError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")


def evaluate(rec: Reconstruction, scan: Scan, radius: float = CROP_RADIUS_MM, icp: bool = True,
             icp_scale: bool = False, landmark_scale: bool = True):
    """Compare a reconstruction with the scan -> (cell dict for the report, Comparison)."""
    cmp = compare_to_scan(rec.vertices, rec.triangles, scan.vertices, scan.triangles,
                          rec.landmarks, scan.landmarks, radius=radius, icp=icp,
                          icp_scale=icp_scale, landmark_scale=landmark_scale)
    s = cmp.summary()
    p = s["point_to_plane"]
    cell = {"mean_mm": p["mean_mm"], "std_mm": p["std_mm"], "median_mm": p["median_mm"],
            "s_per_frame": rec.seconds / max(rec.n_frames, 1),
            "point_to_surface_mm": s["point_to_surface"]["mean_mm"],
            "scan_to_recon_mm": s["scan_to_recon"]["mean_mm"],
            "symmetric_mm": s["symmetric"]["mean_mm"],
            "n_vertices": p["n"], "n_frames": rec.n_frames,
            "landmark_alignment_rmse_mm": cmp.alignment["landmarks"]["rmse_mm"],
            "icp_fitness": (cmp.alignment["icp"] or {}).get("fitness"),
            **rec.info}
    return cell, cmp


def save_heatmap(path, vertices, triangles, errors, frame, max_mm: float = 4.0, size: int = 384):
    """Render a frontal heat map of per-vertex errors to a PNG (atomically).

    Parameters
    ----------
    vertices : (V, 3) mm, the aligned reconstruction (scan frame); triangles : (F, 3)
    errors : (V,) mm, NaN where not evaluated (drawn grey)
    frame : Similarity, scan frame -> frontal head frame (:func:`evaluation.videos.frontal_frame`)
    max_mm : error at the top of the colour scale
    """
    import matplotlib

    from morphable.io.atomic import atomic_path
    from morphable.raster import frame_mesh, render, save_image_png

    e = np.asarray(errors, dtype=np.float64)
    colors = np.asarray(matplotlib.colormaps["viridis"](np.clip(np.nan_to_num(e) / max_mm, 0, 1)))[:, :3]
    colors[~np.isfinite(e)] = 0.6
    front = frame.apply(vertices)
    cam = frame_mesh(front, (size, size))
    # the camera sees the frontal frame: give it the scan -> frontal rotation as well
    cam.translation = cam.rotation @ frame.translation + cam.translation
    cam.rotation = cam.rotation @ frame.rotation
    img = render(vertices, triangles, cam, colors=colors, background=(1.0, 1.0, 1.0), ambient=0.5)
    with atomic_path(path) as tmp:
        save_image_png(tmp, img)


def _frames_from_folder(folder: Path, condition: str, k: int, with_frames: bool = False):
    """Sampled landmarks of real frames in ``folder/<condition>/`` -> ((k, 68, 2), (W, H),
    the frames (k, H, W, 3) float in [0, 1] when ``with_frames``, else None, (k,) bool: the
    frames without a ``.pts`` whose landmarks dlib detected)."""
    from PIL import Image

    from morphable.io.landmarks import read_pts

    d = folder / condition
    frames = sorted(p for p in d.glob("*") if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".ppm", ".bmp"))
    if not frames:
        raise InputError(f"{d}: no frames (.png .jpg .ppm) for condition {condition}")
    if k > len(frames):
        raise InputError(f"{d}: {len(frames)} frames, cannot sample {k}")
    chosen = [frames[i] for i in sample_frames(len(frames), k)]
    sizes = {Image.open(p).size for p in chosen}
    if len(sizes) != 1:
        raise InputError(f"{d}: frames have different sizes {sorted(sizes)}")
    detected = np.array([not p.with_suffix(".pts").is_file() for p in chosen])
    out, images = [], []
    for p, found in zip(chosen, detected):
        image = np.asarray(Image.open(p).convert("RGB")) if with_frames or found else None
        if found:
            from .videos import detect_landmarks

            out.append(detect_landmarks(image))
        else:
            out.append(read_pts(p.with_suffix(".pts")))
        images.append(image)
    return (np.stack(out), sizes.pop(), np.stack(images) / 255.0 if with_frames else None,
            detected)


def video_landmarks(scan: Scan, model, condition: str, n_sampled: int, n_frames: int, seed: int,
                    detect: bool = False, frames_dir=None, with_frames: bool = False):
    """Landmarks of the sampled frames of one video -> ((k, 68, 2) px, (W, H), description,
    frames): ``frames`` (k, H, W, 3) float in [0, 1] — rendered from the scan, or read from
    ``frames_dir`` — when ``with_frames``, else None."""
    if frames_dir is not None:
        lm, size, frames, detected = _frames_from_folder(Path(frames_dir), condition, n_sampled,
                                                         with_frames)
        return lm, size, {"source": str(Path(frames_dir) / condition),
                          "detected": detected.tolist()}, frames
    video = synthetic_video(scan, condition, model.landmark_positions(), n_frames=n_frames,
                            n_sampled=n_sampled, seed=seed)
    lm = video.sampled_landmarks()
    desc = {"source": "synthetic", "poses_deg": video.poses_deg[video.sampled].round(2).tolist(),
            "frames": video.sampled.tolist(), "image_size": list(video.image_size),
            "focal_px": float(video.cameras[0].focal)}
    frames = None
    if detect or with_frames:
        from .videos import render_frames

        frames = render_frames(scan, video, seed=seed)
    if detect:
        from .videos import detect_landmarks, frontal_frame, project_landmarks

        lm = np.stack([detect_landmarks(im) for im in frames])
        desc["landmarks"] = "dlib on rendered frames"
        # how far the detector is from the scan's own landmarks, projected without noise
        truth = project_landmarks(scan, video.sampled_cameras(),
                                  frontal_frame(scan.landmarks, model.landmark_positions()))
        desc["detector_error_px"] = detector_error(lm, truth)
    else:
        desc["landmarks"] = "projected scan landmarks + noise"
    desc["detected"] = [bool(detect)] * len(lm)
    desc["n_landmarks"] = np.isfinite(lm[..., 0]).sum(1).tolist()
    return lm, video.image_size, desc, frames if with_frames else None


def detector_error(detected, truth) -> dict:
    """RMS distance (px) of detected landmarks (N, 68, 2) from the true ones, over the points
    both have: the jaw outline (iBUG 1-17) and the inner points apart, and how many frames
    had a face found."""
    d = np.linalg.norm(np.asarray(detected) - np.asarray(truth), axis=-1)       # (N, 68)
    out = {}
    for name, part in (("jaw", d[:, :17]), ("inner", d[:, 17:])):
        e = part[np.isfinite(part)]
        out[name + "_rms"] = round(float(np.sqrt(np.mean(e ** 2))), 2) if e.size else None
    out["frames_detected"] = int(np.isfinite(np.asarray(detected)).all(-1).any(-1).sum())
    return out


def run_protocol(scan: Scan, model, methods, conditions, n_sampled: int = 5, n_frames: int = 30,
                 seed: int = 0, detect: bool = False, frames_dir=None, efforts: dict | None = None,
                 radius: float = CROP_RADIUS_MM, icp: bool = True, icp_scale: bool = False,
                 landmark_scale: bool = True, log=None, progress: bool = False, focal_px=None,
                 peers: dict | None = None):
    """Run every method on every condition (``log``: a callable taking one line per cell;
    ``progress``: a tqdm bar on stderr; ``focal_px``: the camera's focal length for real
    frames, if known — synthetic videos know theirs; ``peers``: :func:`reconstruct`'s cache,
    to share it between runs on the same scan).

    Returns
    -------
    report : dict shaped ``{"methods": {m: {c: cell}}, "metric", "alignment", "videos", ...}``
    errors : dict ``"method/condition"`` -> (V,) point-to-plane error per model vertex (NaN
        outside the crop or the skin), plus ``".../vertex_ids"``, ``".../vertices"`` and
        ``".../triangles"`` of the evaluated, aligned meshes
    """
    efforts = efforts or {}
    for m in methods:
        if m not in METHODS:
            raise InputError(f"unknown method {m!r}; choose from {', '.join(METHODS)}")
    for c in conditions:
        if c not in CONDITIONS:
            raise InputError(f"unknown condition {c!r}; choose from {', '.join(CONDITIONS)}")
    if "gar" in methods:
        gar_refiner()
    report = {"methods": {m: {} for m in methods}, "videos": {}}
    errors = {}
    peers = peers if peers is not None else {}
    alignment = None
    bar = tqdm(total=len(conditions) * len(methods), disable=not progress, desc="florence",
               unit="cell")
    for c in conditions:
        bar.set_postfix_str(f"{c} video", refresh=False)
        lm, size, desc, images = video_landmarks(scan, model, c, n_sampled, n_frames, seed, detect,
                                                 frames_dir, with_frames="gar" in methods)
        report["videos"][c] = desc
        for m in methods:
            bar.set_postfix_str(f"{m}, {c}", refresh=False)
            try:
                rec = reconstruct(m, model, lm, size, efforts.get(m), peers, images,
                                  desc.get("focal_px", focal_px), scan, desc.get("detected"))
                cell, cmp = evaluate(rec, scan, radius, icp, icp_scale, landmark_scale)
            except FitError as e:
                cell, cmp = {"error": str(e)}, None
            report["methods"][m][c] = cell
            if cmp is not None:
                # per model vertex (NaN outside the crop), with the evaluated mesh for plotting
                per = np.full(rec.n_model_vertices, np.nan)
                per[rec.vertex_ids] = cmp.per_vertex("point_to_plane")
                errors[f"{m}/{c}"] = per
                errors[f"{m}/{c}/vertex_ids"] = rec.vertex_ids
                errors[f"{m}/{c}/vertices"] = cmp.aligned_vertices
                errors[f"{m}/{c}/triangles"] = rec.triangles
                alignment = alignment or {k: v for k, v in cmp.alignment.items() if k != "transform"}
            if log:
                log(f"{m:>17s} {c:<12s} " + (f"{cell['mean_mm']:.3f} mm, {cell['s_per_frame']:.3f} s/frame"
                                            if "mean_mm" in cell else cell["error"]))
            bar.update()
    bar.close()
    report["metric"] = METRIC.format(r=radius)
    report["alignment"] = {
        "landmarks": "similarity (Umeyama, with scale)" if landmark_scale else "rigid (Umeyama)",
        "icp": ("open3d point-to-point ICP with scale, then point-to-plane ICP (rigid)" if icp_scale
                else "open3d point-to-plane ICP (rigid)") if icp else "none",
        "crop": f"sphere of {radius:g} mm around the nose tip (iBUG 31) on scan and reconstruction",
        "example": alignment}
    report["scan"] = {"path": scan.source, "units": scan.units,
                      "interocular_mm": round(scan.interocular_mm, 2),
                      "n_landmarks": int(np.isfinite(scan.landmarks).all(1).sum())}
    report["settings"] = {"model": model.name, "frames": n_sampled, "video_frames": n_frames,
                          "seed": seed, "detect": detect, "efforts": efforts}
    return report, errors


AVERAGED = ("mean_mm", "median_mm", "s_per_frame", "point_to_surface_mm", "scan_to_recon_mm",
            "symmetric_mm")


def run_model_scans(scan_model, model, methods, conditions, n_scans: int = 8, seed: int = 0,
                    scan_seed: int = 100, log=None, progress: bool = False,
                    definition_mm: float = 0.0, expression_std: float = 0.0, appearances=(),
                    **kwargs):
    """:func:`run_protocol` on ``n_scans`` subjects sampled from ``scan_model``
    (:func:`evaluation.scans.model_scan` with seeds ``scan_seed``, ``scan_seed + 1``...,
    ``definition_mm`` of landmark definition error added to their landmarks, expressions of
    ``expression_std`` — 0: neutral); ``appearances``:
    (name, (V, 3) vertex colours) pairs, :func:`evaluation.scans.photo_colors`, worn in turn
    by the subjects in rendered frames).

    Returns
    -------
    report : the :func:`run_protocol` shape; each cell holds the means over the subjects of
        ``mean_mm``, ``median_mm``, ``s_per_frame`` and the other metrics, ``std_mm`` the
        standard deviation of ``mean_mm`` across subjects, ``per_scan_mm`` the list, and
        ``n_failed``; ``scan`` describes the sampled set
    """
    if n_scans < 1:
        raise InputError(f"--n-scans: need at least 1 subject, got {n_scans}")
    appearances = list(appearances)
    scans = (model_scan(scan_model, scan_seed + i, definition_mm=definition_mm,
                        expression_std=expression_std,
                        colors=appearances[i % len(appearances)][1] if appearances else None)
             for i in range(n_scans))
    runs = (run_protocol(scan, model, methods, conditions, seed=seed, **kwargs)[0]
            for scan in scans)
    report = _average_runs(runs, n_scans, "per_scan_mm", "subject", log, progress)
    report["scan"] = {"model": scan_model.name, "n_scans": n_scans,
                      "seeds": [scan_seed + i for i in range(n_scans)],
                      "landmarks": f"the {scan_model.name} landmark vertices"
                      + (f" with {definition_mm:g} mm of definition error" if definition_mm else ""),
                      "expression_std": expression_std,
                      "appearance": ([f"vertex colours of {name}" for name, _ in appearances]
                                     or "untextured (shaded grey)"),
                      "std_mm": "standard deviation of the per-subject means"}
    return report


def run_videos(scan: Scan, model, methods, conditions, n_videos: int = 5, seed: int = 0,
               log=None, progress: bool = False, **kwargs):
    """:func:`run_protocol` on ``n_videos`` draws of each condition's synthetic video (seeds
    ``seed``, ``seed + 1``...: other head-pose trajectories and landmark noise), to show how
    much one draw decides.

    Returns
    -------
    report : the :func:`run_protocol` shape; each cell holds the means over the videos,
        ``std_mm`` the standard deviation of ``mean_mm`` across them, ``per_video_mm`` the list
        and ``n_failed``
    errors : the per-vertex errors of the first draw (see :func:`run_protocol`)
    """
    if n_videos < 1:
        raise InputError(f"--n-videos: need at least 1 video, got {n_videos}")
    first, peers = {}, {}     # eos and the surface fit are the same for every draw

    def runs():
        for i in range(n_videos):
            rep, errors = run_protocol(scan, model, methods, conditions, seed=seed + i,
                                       peers=peers, **kwargs)
            first.setdefault("errors", errors)
            yield rep

    report = _average_runs(runs(), n_videos, "per_video_mm", "video", log, progress)
    report["videos_drawn"] = {"n_videos": n_videos, "seeds": [seed + i for i in range(n_videos)],
                              "std_mm": "standard deviation of the per-video means"}
    return report, first["errors"]


def _average_runs(reports, n: int, key: str, unit: str, log=None, progress: bool = False) -> dict:
    """Average the cells of ``n`` :func:`run_protocol` reports (an iterable, run lazily): the
    metrics in ``AVERAGED`` are means over the runs that succeeded, ``std_mm`` the standard
    deviation of their ``mean_mm``, ``key`` the list of them, ``n_failed`` the others."""
    per, report, detector = {}, None, {}
    bar = tqdm(reports, total=n, disable=not progress, desc=unit + "s", unit=unit)
    for i, rep in enumerate(bar):
        report = report or rep
        for m, cells in rep["methods"].items():
            for c, cell in cells.items():
                per.setdefault(m, {}).setdefault(c, []).append(cell)
        for c, desc in rep["videos"].items():
            if "detector_error_px" in desc:
                detector.setdefault(c, []).append(desc["detector_error_px"])
        if log:
            log(f"{unit} {i + 1}/{n}: " + ", ".join(
                f"{m} {np.mean([cs[-1].get('mean_mm', np.nan) for cs in per[m].values()]):.3f}"
                for m in per))
    for m, cells in per.items():
        for c, runs in cells.items():
            ok = [cell for cell in runs if "mean_mm" in cell]
            if not ok:
                report["methods"][m][c] = {"error": runs[0]["error"]}
                continue
            cell = {k: float(np.mean([x[k] for x in ok])) for k in AVERAGED}
            cell["std_mm"] = float(np.std([x["mean_mm"] for x in ok]))
            cell[key] = [round(x["mean_mm"], 4) for x in ok]
            cell["n_failed"] = len(runs) - len(ok)
            report["methods"][m][c] = cell
    for c, errs in detector.items():
        # the other video entries describe the first run; the detector's error is over all
        mean = {}
        for k in ("jaw_rms", "inner_rms"):
            found = [e[k] for e in errs if e[k] is not None]
            mean[k] = round(float(np.mean(found)), 2) if found else None
        report["videos"][c]["detector_error_px"] = {
            **mean, "frames_detected": [e["frames_detected"] for e in errs],
            "over": f"mean over {len(errs)} {unit}s"}
    return report


def format_table(report: dict) -> str:
    """The paper-shaped table: method x condition, mean ± std (mm), seconds per frame; then
    the same reconstructions under the other metrics."""
    methods = list(report["methods"])
    conds = list(next(iter(report["methods"].values()), {}))
    w = 16
    head = f"{'method':<18}" + "".join(f"{c:>{w}}" for c in conds) + f"{'s/frame':>10}"
    over = ("subjects" if "n_scans" in report.get("scan", {})
            else "videos" if "videos_drawn" in report else "vertices")
    lines = [f"point-to-plane error, mm (mean ± std over {over}); {report['settings']['frames']} "
             f"frames per video, model {report['settings']['model']}", head, "-" * len(head)]
    for m in methods:
        row, secs = f"{m:<18}", []
        for c in conds:
            cell = report["methods"][m][c]
            if "mean_mm" in cell:
                row += f"{cell['mean_mm']:>{w - 7}.3f} ± {cell['std_mm']:.3f}"
                secs.append(cell["s_per_frame"])
            else:
                row += f"{'failed':>{w}}"
        row += f"{np.mean(secs):>10.3f}" if secs else f"{'-':>10}"
        lines.append(row)
    lines += ["", "same reconstructions, other metrics (mean mm): point-to-surface / "
              "scan->reconstruction / symmetric"]
    for m in methods:
        row = f"{m:<18}"
        for c in conds:
            cell = report["methods"][m][c]
            row += (f"  {cell['point_to_surface_mm']:.2f}/{cell['scan_to_recon_mm']:.2f}/"
                    f"{cell['symmetric_mm']:.2f}" if "mean_mm" in cell else "  failed")
        lines.append(row)
    return "\n".join(lines)


def _parser():
    p = argparse.ArgumentParser(prog="python -m evaluation.florence", description=__doc__.split("\n")[0])
    p.add_argument("--scan", help="scan mesh (OBJ, PLY, STL...)")
    p.add_argument("--scan-landmarks",
                   help="68 or 51 (inner) 3D landmarks: .ljson, .npy, .txt (N x 3) or .pts")
    p.add_argument("--synthetic-scan", metavar="MODEL",
                   help="instead of --scan: subjects sampled from this model (e.g. ict), its "
                        "landmark vertices as scan landmarks")
    p.add_argument("--n-scans", type=int, default=8, help="subjects for --synthetic-scan")
    p.add_argument("--appearance", nargs="+", metavar="PHOTO",
                   help="--synthetic-scan: photos of faces (landmarks in the .pts beside, else "
                        "dlib's) whose colours the subjects wear in turn in rendered frames "
                        "(--detect, gar); default untextured")
    p.add_argument("--definition-noise", type=float, default=0.0, metavar="MM",
                   help="--synthetic-scan: landmark definition error added to the subjects' "
                        "landmarks, mm per coordinate (jaw points: twice that along the jaw)")
    p.add_argument("--expression-std", type=float, default=0.0, metavar="S",
                   help="--synthetic-scan: subjects with an expression: blendshape weights "
                        "|N(0, S)| clipped to 1, or PCA coefficients N(0, S); default neutral")
    p.add_argument("--scan-units", default="auto", choices=[*UNITS, "auto"])
    p.add_argument("--methods", nargs="+", default=["ours", "eos", "mean-face"])
    p.add_argument("--conditions", nargs="+", default=list(CONDITIONS))
    p.add_argument("--frames", type=int, default=5, help="frames sampled per video")
    p.add_argument("--video-frames", type=int, default=30, help="length of a synthetic video")
    p.add_argument("--model", default="sfm", help="model for ours/mean-face (sfm, ict or a path)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-videos", type=int, default=1,
                   help="--scan: draws of each synthetic video (seeds --seed, --seed + 1...); "
                        "the table then gives mean ± std over the draws (per-vertex errors "
                        "and heat maps: the first draw)")
    p.add_argument("--detect", action="store_true",
                   help="landmarks from dlib on rendered frames instead of projected scan landmarks")
    p.add_argument("--frames-dir", help="real frames: DIR/<condition>/*.png with optional .pts")
    p.add_argument("--iterations", type=int, help="iterations of ours (default: the fitter's)")
    p.add_argument("--definition-std", type=float,
                   help="ours: landmark definition error, mm, for every landmark (default: the "
                        "fitter's per-landmark profile)")
    p.add_argument("--camera", choices=["auto", "affine", "perspective"], default="auto",
                   help="ours: camera model; auto = pinhole where the focal length is known "
                        "(synthetic videos, --focal-px), else affine")
    p.add_argument("--focal-px", type=float,
                   help="focal length of the camera of --frames-dir, px (default: unknown)")
    p.add_argument("--model-std", type=float,
                   help="ours: per-frame model landmark error, mm (default: the fitter's)")
    p.add_argument("--expression-weight", type=float,
                   help="ours: weight of the expression prior (default 1: the fitter's, "
                        "morphable.fitting.noise.expression_precision)")
    p.add_argument("--radius", type=float, default=CROP_RADIUS_MM, help="crop radius, mm")
    p.add_argument("--icp-scale", action="store_true", help="let ICP change the scale too")
    p.add_argument("--no-icp", action="store_true", help="landmark alignment only")
    p.add_argument("--rigid", action="store_true", help="rigid landmark alignment (no scale)")
    p.add_argument("--report", required=True, help="JSON report to write")
    p.add_argument("--errors", help="per-vertex errors .npz (default: beside the report)")
    p.add_argument("--heatmaps", help="folder for frontal error heat maps (method_condition.png)")
    p.add_argument("--plot", help="per-condition bar chart of the errors (.png, .pdf, .svg)")
    p.add_argument("--quiet", action="store_true", help="no progress bar, warnings only")
    return p


def _write_outputs(report: dict, errors: dict, report_path: Path, errors_path: Path):
    from morphable.io.atomic import atomic_path

    if errors:
        with atomic_path(errors_path) as tmp:
            with open(tmp, "wb") as f:
                np.savez_compressed(f, **errors)
    with atomic_path(report_path) as tmp:
        tmp.write_text(json.dumps(report, indent=1))


@one_line_errors("evaluation.florence")
def main(argv=None) -> int:
    from tqdm.contrib.logging import logging_redirect_tqdm

    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO,
                        format="%(levelname)s: %(message)s")
    report_path = Path(args.report)
    errors_path = Path(args.errors) if args.errors else report_path.with_name(report_path.stem + "_errors.npz")
    for p in (report_path, errors_path):
        if not p.parent.is_dir() and str(p.parent):
            raise InputError(f"{p}: output folder {p.parent} does not exist")
    if args.frames < 1 or args.video_frames < args.frames:
        raise InputError(f"--frames {args.frames}: need 1 <= frames <= --video-frames "
                         f"({args.video_frames})")
    from morphable import load_model

    if (args.synthetic_scan is None) == (args.scan is None):
        raise InputError("give either --scan with --scan-landmarks, or --synthetic-scan")
    if args.scan is not None and args.scan_landmarks is None:
        raise InputError(f"--scan {args.scan}: --scan-landmarks is required")
    model = load_model(args.model)
    if args.synthetic_scan:
        scan_model = load_model(args.synthetic_scan)
        if not (np.isfinite(args.definition_noise) and args.definition_noise >= 0):
            raise InputError(f"--definition-noise {args.definition_noise}: must be >= 0")
        if not (np.isfinite(args.expression_std) and args.expression_std >= 0):
            raise InputError(f"--expression-std {args.expression_std}: must be >= 0")
        for bad in ("frames_dir", "heatmaps"):
            if getattr(args, bad):
                raise InputError(f"--{bad.replace('_', '-')} does not apply to --synthetic-scan")
        if args.n_videos != 1:
            raise InputError("--n-videos applies to --scan "
                             "(--synthetic-scan: one video per subject)")
        if args.appearance and not (args.detect or "gar" in args.methods):
            raise InputError("--appearance colours rendered frames: use it with --detect or "
                             "the gar method")
    elif args.appearance:
        raise InputError("--appearance applies to --synthetic-scan (a scan has its own texture)")
    elif args.expression_std:
        raise InputError("--expression-std applies to --synthetic-scan")
    else:
        scan = load_scan(args.scan, args.scan_landmarks, args.scan_units)
    ours = {k: v for k, v in (("n_iterations", args.iterations),
                              ("definition_std_mm", args.definition_std),
                              ("model_std_mm", args.model_std),
                              ("expression_weight", args.expression_weight),
                              ("camera", None if args.camera == "auto" else args.camera))
            if v is not None}
    if args.focal_px is not None and not (np.isfinite(args.focal_px) and args.focal_px > 0):
        raise InputError(f"--focal-px {args.focal_px}: must be a positive number")
    if args.focal_px is not None and not args.frames_dir:
        raise InputError("--focal-px applies to --frames-dir (synthetic videos know their focal)")
    efforts = {"ours": ours, "ours-independent": dict(ours)} if ours else {}
    if args.plot:
        from evaluation.plots import check_plot_path

        check_plot_path(args.plot)
    common = dict(efforts=efforts, radius=args.radius, icp=not args.no_icp,
                  icp_scale=args.icp_scale, landmark_scale=not args.rigid,
                  log=logging.getLogger("evaluation.florence").info, progress=not args.quiet)
    with logging_redirect_tqdm():
        if args.synthetic_scan:
            errors = {}
            looks = [(Path(p).name, photo_colors(scan_model, p)) for p in args.appearance or ()]
            report = run_model_scans(scan_model, model, args.methods, args.conditions,
                                     args.n_scans, args.seed, definition_mm=args.definition_noise,
                                     expression_std=args.expression_std,
                                     appearances=looks, n_sampled=args.frames, detect=args.detect,
                                     n_frames=args.video_frames, **common)
        elif args.n_videos != 1:
            if args.frames_dir:
                raise InputError("--n-videos draws synthetic videos; --frames-dir has one")
            report, errors = run_videos(scan, model, args.methods, args.conditions,
                                        args.n_videos, args.seed, n_sampled=args.frames,
                                        n_frames=args.video_frames, detect=args.detect, **common)
        else:
            report, errors = run_protocol(scan, model, args.methods, args.conditions,
                                          args.frames, args.video_frames, args.seed,
                                          detect=args.detect, frames_dir=args.frames_dir,
                                          focal_px=args.focal_px, **common)
    cells = [cell for per in report["methods"].values() for cell in per.values()]
    if cells and all("error" in cell for cell in cells):
        raise FitError(f"every reconstruction failed; first: {cells[0]['error']}")
    report["command"] = "python -m evaluation.florence " + " ".join(
        sys.argv[1:] if argv is None else argv)
    if args.heatmaps and not Path(args.heatmaps).is_dir():
        raise InputError(f"{args.heatmaps}: heat-map folder does not exist")
    print(format_table(report))
    _write_outputs(report, errors, report_path, errors_path)
    if args.plot:
        from evaluation.plots import condition_bars

        condition_bars(report, args.plot)
    if args.heatmaps:
        from .videos import frontal_frame

        frame = frontal_frame(scan.landmarks, model.landmark_positions())
        for key in [k for k in errors if k.count("/") == 1]:
            ids = errors[key + "/vertex_ids"]
            save_heatmap(Path(args.heatmaps) / (key.replace("/", "_") + ".png"),
                         errors[key + "/vertices"], errors[key + "/triangles"],
                         errors[key][ids], frame)
    return 0


if __name__ == "__main__":
    sys.exit(main())
