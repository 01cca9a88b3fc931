"""The Florence protocol: videos of a scan, each method's reconstruction of them, compared.

For each condition a video of the scan is made (synthetic: :mod:`evaluation.videos`; or
real frames in a Florence-layout folder), frames are sampled uniformly, each method
(:mod:`evaluation.florence.methods`) reconstructs the face from them, and the reconstruction
is compared with the scan (:func:`evaluate`). :func:`run_protocol` does this for one scan and
one draw of the videos, :func:`run_videos` for several draws, :func:`run_model_scans` for
subjects sampled from a model; :func:`format_table` prints the result.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from morphable.errors import FitError, InputError
from morphable.metrics import CROP_RADIUS_MM, compare_to_scan

from ..scans import Scan, model_scan
from ..videos import CONDITIONS, sample_frames, synthetic_video
from .methods import Frames, Reconstruction, ibug68_points, prepare_methods, reconstruct_video

__all__ = ["RENDERERS", "frame_renderer", "ErrorMap", "evaluate", "frames_from_video",
           "video_landmarks", "detector_error", "run_protocol",
           "run_model_scans", "run_videos", "format_table", "save_error_maps", "save_heatmap"]

METRIC = ("point-to-plane distance (mm) from each reconstructed vertex within {r:g} mm of the "
          "nose tip to the tangent plane of the nearest scan vertex, after alignment")


@dataclass
class ErrorMap:
    """One method's per-vertex error in one condition, with the mesh it was measured on.

    Attributes
    ----------
    method, condition : names, as in the report
    errors : (n_model_vertices,) mm, the point-to-plane error per model vertex, NaN outside
        the crop or the skin
    vertex_ids : (V,) int, the model vertex of each row of ``vertices``
    vertices : (V, 3) mm, the evaluated reconstruction aligned to the scan (scan frame)
    triangles : (F, 3) int, on ``vertices``
    """

    method: str
    condition: str
    errors: np.ndarray
    vertex_ids: np.ndarray
    vertices: np.ndarray
    triangles: np.ndarray

    @property
    def mesh_errors(self) -> np.ndarray:
        """(V,) mm, the errors at the rows of ``vertices``."""
        return self.errors[self.vertex_ids]


def save_error_maps(path, maps) -> None:
    """Write error maps to one compressed ``.npz`` (atomically), four arrays each:
    ``"method/condition"`` (the per-model-vertex ``errors``), ``"method/condition/vertex_ids"``,
    ``".../vertices"`` and ``".../triangles"``."""
    from morphable.io.atomic import atomic_path

    arrays = {}
    for m in maps:
        key = f"{m.method}/{m.condition}"
        arrays.update({key: m.errors, key + "/vertex_ids": m.vertex_ids,
                       key + "/vertices": m.vertices, key + "/triangles": m.triangles})
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)


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


def _frames_from_folder(folder: Path, condition: str, k: int, with_frames: bool = False,
                        detector=("auto", "auto")) -> Frames:
    """The ``k`` sampled real frames of ``folder/<condition>/`` -> :class:`Frames`: each
    frame's ``.pts`` landmarks, or where it has none its landmarks (and σ) detected with
    ``detector`` = (landmark detector, face detector) of :func:`morphable.detection.detect`;
    the frames themselves when ``with_frames``."""
    from PIL import Image

    from morphable.detection import landmark_count
    from morphable.io.landmark_files import read_pts

    from ..videos import detect_frames

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
    annotated = {i: read_pts(p.with_suffix(".pts")) for i, p in enumerate(chosen) if not detected[i]}
    # .pts files (68 points) and detections of 478 are fitted as one set of 68
    n = landmark_count(*detector) if detected.all() else 68
    images = [np.asarray(Image.open(p).convert("RGB")) if with_frames or found else None
              for p, found in zip(chosen, detected)]
    _, lm, sigma = detect_frames([im if ok else None for im, ok in zip(images, detected)], detector, n)
    for i, pts in annotated.items():
        lm[i] = pts
    return Frames(lm, sizes.pop(), np.stack(images) / 255.0 if with_frames else None,
                  detected=detected, landmark_std_px=sigma)


def frames_from_video(path, k: int = 5, with_frames: bool = False, detector=("auto", "auto")):
    """The Florence protocol's frames of a real video: ``k`` frames spread uniformly
    (:func:`morphable.video.sample_frames`, all of a shorter video), their landmarks (and σ)
    detected (:func:`evaluation.videos.detect_frames`, ``detector`` = (landmark detector, face
    detector)) -> (:class:`Frames`: NaN rows for frames without a face, the frames themselves
    when ``with_frames``; description for the report).

    InputError naming the file when it is no readable video or no sampled frame shows a face.
    """
    from morphable.detection import describe
    from morphable.video import sample_frames

    from ..videos import detect_frames

    frames = sample_frames(path, k)
    detections, lm, sigma = detect_frames([f.image for f in frames], detector)
    found = np.isfinite(lm).all(-1).any(-1)
    if not found.any():
        raise InputError(f"{path}: no face found in any of the {len(frames)} sampled frames")
    desc = {"source": str(path), "frames": [f.index for f in frames],
            "times_s": [round(f.time_s, 4) for f in frames], "image_size": list(frames[0].size),
            "landmarks": f"{describe(*detector)} on video frames",
            "frame_detectors": [d and d.detector for d in detections],
            "frames_without_face": [f.index for f, ok in zip(frames, found) if not ok],
            "detected": [True] * len(frames), "n_landmarks": np.isfinite(lm[..., 0]).sum(1).tolist()}
    images = np.stack([f.image for f in frames]) / 255.0 if with_frames else None
    return Frames(lm, frames[0].size, images, detected=np.ones(len(frames), dtype=bool),
                  landmark_std_px=sigma), desc


def video_landmarks(scan: Scan, model, condition: str, n_sampled: int, n_frames: int, seed: int,
                    detect=None, frames_dir=None, with_frames: bool = False,
                    video=None, renderer: str = "raster") -> tuple[Frames, dict]:
    """The sampled frames of one video -> (:class:`Frames`, description for the report).

    The frames' landmarks: 68, or the 478 of the face mesh or the landmark network when they
    detected them, with the network's σ; ``Frames.images`` (k, H, W, 3) float in [0, 1] —
    rendered from the scan, or read from ``frames_dir`` or ``video`` — when ``with_frames``.
    ``detect``: None (projected scan landmarks) or (landmark detector, face detector) run on
    the rendered frames (and on the frames of ``frames_dir`` that have no ``.pts``, and always
    on those of ``video``, a real video file: :func:`frames_from_video`). ``renderer``: how
    synthetic frames are rendered, ``"raster"`` (:func:`evaluation.videos.render_frames`, the
    shading our fitters assume) or ``"pbr"`` (:func:`evaluation.pbr.render_frames`, a
    physically based rendering that shares nothing with them)."""
    if video is not None:
        return frames_from_video(video, n_sampled, with_frames, detect or ("auto", "auto"))
    if frames_dir is not None:
        frames = _frames_from_folder(Path(frames_dir), condition, n_sampled, with_frames,
                                     detect or ("auto", "auto"))
        return frames, {"source": str(Path(frames_dir) / condition),
                        "detected": frames.detected.tolist()}
    video = synthetic_video(scan, condition, model.landmark_positions(), n_frames=n_frames,
                            n_sampled=n_sampled, seed=seed)
    lm, sigma = video.sampled_landmarks(), None
    desc = {"source": "synthetic", "poses_deg": video.poses_deg[video.sampled].round(2).tolist(),
            "frames": video.sampled.tolist(), "image_size": list(video.image_size),
            "focal_px": float(video.cameras[0].focal)}
    images = None
    if detect or with_frames:
        images = frame_renderer(renderer)(scan, video, seed=seed)
        desc["renderer"] = renderer
    if detect:
        from morphable.detection import describe

        from ..videos import detect_frames, frontal_frame, project_landmarks

        found, lm, sigma = detect_frames(images, detect)
        desc["landmarks"] = f"{describe(*detect)} on rendered frames"
        desc["frame_detectors"] = [d and d.detector for d in found]
        # how far the detector is from the scan's own landmarks, projected without noise
        truth = project_landmarks(scan, video.sampled_cameras(),
                                  frontal_frame(scan.landmarks, model.landmark_positions()))
        desc["detector_error_px"] = detector_error(ibug68_points(lm), truth)
    else:
        desc["landmarks"] = "projected scan landmarks + noise"
    desc["detected"] = [bool(detect)] * len(lm)
    desc["n_landmarks"] = np.isfinite(lm[..., 0]).sum(1).tolist()
    return Frames(lm, video.image_size, images if with_frames else None, desc["focal_px"],
                  np.array(desc["detected"]), sigma), desc


RENDERERS = ("raster", "pbr")
"""Renderers of synthetic frames: ``raster`` (``morphable.raster``, the default), ``pbr``."""


def frame_renderer(name: str):
    """The ``render_frames(scan, video, seed=...)`` function of a renderer in :data:`RENDERERS`."""
    if name == "pbr":
        from ..pbr import render_frames
    elif name == "raster":
        from ..videos import render_frames
    else:
        raise InputError(f"unknown renderer {name!r}; choose from {', '.join(RENDERERS)}")
    return render_frames


def _detect_setting(detect):
    """The report's ``detect`` setting: the detectors as run (e.g. "facemesh auto"), or None."""
    from morphable.detection import describe

    return describe(*detect) if detect else None


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
                 seed: int = 0, detect=None, frames_dir=None, efforts: dict | None = None,
                 radius: float = CROP_RADIUS_MM, icp: bool = True, icp_scale: bool = False,
                 landmark_scale: bool = True, log=None, progress: bool = False, focal_px=None,
                 prepared: dict | None = None, videos: dict | None = None,
                 renderer: str = "raster"):
    """Run every method on every condition (``methods``: names in
    :data:`~evaluation.florence.methods.METHODS`; ``efforts``: {name: the method's settings};
    ``log``: a callable taking one line per cell; ``progress``: a tqdm bar on stderr;
    ``focal_px``: the camera's focal length for real frames, if known — synthetic videos know
    theirs; ``prepared``: the methods made and prepared for this scan and model by
    :func:`~evaluation.florence.methods.prepare_methods`, to share their per-scan work — surface
    fits, loaded fitters — between runs on the same scan; default: prepared here; ``videos``:
    {condition: path} real videos, their sampled frames' landmarks detected with ``detect``
    (default "auto"), instead of synthetic ones: the conditions are then its keys;
    ``renderer``: of synthetic frames, :data:`RENDERERS`).

    Returns
    -------
    report : dict shaped ``{"methods": {m: {c: cell}}, "metric", "alignment", "videos", ...}``
    errors : list of :class:`ErrorMap`, one per cell that succeeded, condition by condition
    """
    efforts = efforts or {}
    frame_renderer(renderer)     # an unknown one fails before any work
    if videos is not None:
        conditions, detect = list(videos), detect or ("auto", "auto")
    for c in conditions:
        if c not in CONDITIONS:
            raise InputError(f"unknown condition {c!r}; choose from {', '.join(CONDITIONS)}")
    made = prepared if prepared is not None else prepare_methods(methods, model, scan)
    report = {"methods": {m: {} for m in methods}, "videos": {}}
    errors = []
    alignment = None
    with_frames = any(made[m].needs_images for m in methods)
    # real videos are read and detected first: a bad one stops the run before any fit
    read = {c: video_landmarks(scan, model, c, n_sampled, n_frames, seed, detect,
                               with_frames=with_frames, video=path)
            for c, path in (videos or {}).items()}
    bar = tqdm(total=len(conditions) * len(methods), disable=not progress, desc="florence",
               unit="cell")
    for c in conditions:
        bar.set_postfix_str(f"{c} video", refresh=False)
        frames, desc = read.pop(c, None) or video_landmarks(
            scan, model, c, n_sampled, n_frames, seed, detect, frames_dir, with_frames=with_frames,
            renderer=renderer)
        if frames.focal_px is None:
            frames = dataclasses.replace(frames, focal_px=focal_px)
        report["videos"][c] = desc
        for m in methods:
            bar.set_postfix_str(f"{m}, {c}", refresh=False)
            try:
                rec = reconstruct_video(made[m], frames, efforts.get(m))
                cell, cmp = evaluate(rec, scan, radius, icp, icp_scale, landmark_scale)
            except FitError as e:
                cell, cmp = {"error": str(e)}, None
            report["methods"][m][c] = cell
            if cmp is not None:
                # per model vertex (NaN outside the crop), with the evaluated mesh for plotting
                per = np.full(rec.n_model_vertices, np.nan)
                per[rec.vertex_ids] = cmp.per_vertex("point_to_plane")
                errors.append(ErrorMap(m, c, per, rec.vertex_ids, cmp.aligned_vertices,
                                       rec.triangles))
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
    report["settings"] = {"model": model.name, "frames": n_sampled,
                          "video_frames": None if videos is not None else n_frames,
                          "seed": seed, "detect": _detect_setting(detect), "efforts": efforts,
                          "renderer": renderer}
    return report, errors


AVERAGED = ("mean_mm", "median_mm", "s_per_frame", "point_to_surface_mm", "scan_to_recon_mm",
            "symmetric_mm")


def run_model_scans(scan_model, model, methods, conditions, n_scans: int = 8, seed: int = 0,
                    scan_seed: int = 100, log=None, progress: bool = False,
                    definition_mm: float = 0.0, expression_std: float = 0.0, appearances=(),
                    n_videos: int = 1, **kwargs):
    """:func:`run_protocol` on ``n_scans`` subjects sampled from ``scan_model``
    (:func:`evaluation.scans.model_scan` with seeds ``scan_seed``, ``scan_seed + 1``...,
    ``definition_mm`` of landmark definition error added to their landmarks, expressions of
    ``expression_std`` — 0: neutral); ``appearances``:
    (name, (V, 3) vertex colours) pairs, :func:`evaluation.scans.photo_colors`, worn in turn
    by the subjects in rendered frames); ``n_videos`` draws of each subject's videos
    (:func:`run_videos`, seeds ``seed``...; 1: one video per condition).

    Returns
    -------
    report : the :func:`run_protocol` shape; each cell holds the means over the subjects of
        ``mean_mm``, ``median_mm``, ``s_per_frame`` and the other metrics (with ``n_videos`` > 1
        each subject's value is its mean over the draws), ``std_mm`` the standard deviation of
        ``mean_mm`` across subjects, ``per_scan_mm`` the list, ``n_failed`` (subjects whose
        every draw failed) and, with draws, ``draw_std_mm`` (the mean over subjects of the
        standard deviation across a subject's draws) and ``per_video_mm`` (a list per subject);
        ``scan`` describes the sampled set
    """
    if n_scans < 1:
        raise InputError(f"--n-scans: need at least 1 subject, got {n_scans}")
    if n_videos < 1:
        raise InputError(f"--n-videos: need at least 1 video, got {n_videos}")
    appearances = list(appearances)
    scans = (model_scan(scan_model, scan_seed + i, definition_mm=definition_mm,
                        expression_std=expression_std,
                        colors=appearances[i % len(appearances)][1] if appearances else None)
             for i in range(n_scans))
    runs = (run_protocol(scan, model, methods, conditions, seed=seed, **kwargs)[0]
            if n_videos == 1 else
            run_videos(scan, model, methods, conditions, n_videos, seed, **kwargs)[0]
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
    if n_videos > 1:
        report["videos_drawn"] = {
            "n_videos": n_videos, "seeds": [seed + i for i in range(n_videos)],
            "draw_std_mm": "mean over subjects of the standard deviation across their draws"}
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
    errors : the error maps of the first draw (see :func:`run_protocol`)
    """
    if n_videos < 1:
        raise InputError(f"--n-videos: need at least 1 video, got {n_videos}")
    first = {}
    prepared = prepare_methods(methods, model, scan)   # eos, the surface fit: same every draw

    def runs():
        for i in range(n_videos):
            rep, errors = run_protocol(scan, model, methods, conditions, seed=seed + i,
                                       prepared=prepared, **kwargs)
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
            if all("per_video_mm" in x for x in ok):
                # the runs averaged draws themselves (subjects of run_videos): keep their spread
                cell["draw_std_mm"] = float(np.mean([x["std_mm"] for x in ok]))
                cell["per_video_mm"] = [x["per_video_mm"] for x in ok]
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
    drawn = report.get("videos_drawn", {}).get("n_videos")
    over = ("subjects" + (f", each the mean of {drawn} video draws" if drawn else "")
            if "n_scans" in report.get("scan", {})
            else "videos" if drawn else "vertices")
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
