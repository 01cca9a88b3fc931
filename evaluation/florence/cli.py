"""The Florence evaluation protocol on any scan: reconstruct from video frames, compare.

The command ``python -m evaluation.florence`` (see :mod:`evaluation.florence` for the protocol
and examples): prints the table of :func:`~evaluation.florence.protocol.format_table`, writes
the JSON report, the per-vertex errors (``.npz``,
:func:`~evaluation.florence.protocol.save_error_maps`) and optionally heat maps and a bar chart.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np

from morphable.cli.common import add_detector_arguments, add_loss_weight_argument
from morphable.detection import resolve_detectors
from morphable.errors import FitError, InputError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity
from morphable.metrics import CROP_RADIUS_MM
from morphable.refinement import parse_loss_weights

from ..scans import UNITS, load_scan, photo_colors
from ..videos import CONDITIONS
from .methods import METHODS
from .protocol import (RENDERERS, format_table, run_model_scans, run_protocol, run_videos, save_error_maps,
                       save_heatmap)

__all__ = ["main"]


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
                        "detected) whose colours the subjects wear in turn in rendered frames "
                        "(--detect, gar); default untextured")
    p.add_argument("--definition-noise", type=float, default=0.0, metavar="MM",
                   help="--synthetic-scan: landmark definition error added to the subjects' "
                        "landmarks, mm per coordinate (jaw points: twice that along the jaw)")
    p.add_argument("--expression-std", type=float, default=0.0, metavar="S",
                   help="--synthetic-scan: subjects with an expression: blendshape weights "
                        "|N(0, S)| clipped to 1, or PCA coefficients N(0, S); default neutral")
    p.add_argument("--scan-units", default="auto", choices=[*UNITS, "auto"])
    p.add_argument("--methods", nargs="+", default=["ours", "eos", "mean-face"],
                   help=f"of {', '.join(METHODS)}")
    p.add_argument("--conditions", nargs="+", default=list(CONDITIONS))
    p.add_argument("--frames", type=int, default=5, help="frames sampled per video")
    p.add_argument("--video-frames", type=int, default=30, help="length of a synthetic video")
    p.add_argument("--model", default="sfm", help="model for ours/mean-face (sfm, ict or a path)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-videos", type=int, default=1,
                   help="draws of each synthetic video (seeds --seed, --seed + 1...); with "
                        "--scan the table then gives mean ± std over the draws (per-vertex "
                        "errors and heat maps: the first draw), with --synthetic-scan each "
                        "subject's mean over its draws (draw_std_mm in the report: the spread)")
    p.add_argument("--detect", action="store_true",
                   help="landmarks detected on rendered frames (--landmark-detector, --face-detector) "
                        "instead of projected scan landmarks")
    add_detector_arguments(p)
    p.add_argument("--renderer", choices=RENDERERS, default="raster",
                   help="how synthetic frames are rendered (--detect, gar): raster (morphable."
                        "raster, the shading our fitters assume) or pbr (evaluation.pbr: "
                        "physically based, photo backgrounds, defocus, noise, JPEG)")
    p.add_argument("--frames-dir", help="real frames: DIR/<condition>/*.png with optional .pts")
    p.add_argument("--videos", nargs="+", metavar="COND=PATH",
                   help="real videos, one per condition (e.g. indoor=clip.mp4): --frames frames "
                        "spread uniformly over each, their landmarks detected "
                        "(--landmark-detector, --face-detector); the conditions are these")
    p.add_argument("--n-iterations", type=int,
                   help="nonlinear iterations of ours (default: the fitter's)")
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
    p.add_argument("--photometric-steps", type=int,
                   help="ours-photometric(-gar): refinement Adam steps (default 100)")
    p.add_argument("--photometric-resolution", type=int,
                   help="ours-photometric(-gar): face crop size, px (default the refinement's)")
    add_loss_weight_argument(p, "--photometric-loss-weight", "ours-photometric(-gar): refinement")
    p.add_argument("--gar-steps", type=int,
                   help="gar: refinement steps per frame (default 100)")
    p.add_argument("--gar-region", choices=("crop", "face"),
                   help="gar: pixels its photometric terms compare, the whole crop (default) "
                        "or the fitted face")
    add_loss_weight_argument(p, "--gar-loss-weight", "gar: refinement")
    p.add_argument("--radius", type=float, default=CROP_RADIUS_MM, help="crop radius, mm")
    p.add_argument("--icp-scale", action="store_true", help="let ICP change the scale too")
    p.add_argument("--no-icp", action="store_true", help="landmark alignment only")
    p.add_argument("--rigid", action="store_true", help="rigid landmark alignment (no scale)")
    p.add_argument("--report", required=True, help="JSON report to write")
    p.add_argument("--errors", help="per-vertex errors .npz (default: beside the report)")
    p.add_argument("--heatmaps", help="folder for frontal error heat maps (method_condition.png)")
    p.add_argument("--plot", help="per-condition bar chart of the errors (.png, .pdf, .svg)")
    add_verbosity_arguments(p)
    return p


def parse_videos(items) -> dict:
    """``["indoor=clip.mp4", ...]`` -> {condition: path}; InputError for an item without
    ``=``, a condition not in :data:`evaluation.videos.CONDITIONS`, or one given twice."""
    out = {}
    for item in items:
        cond, sep, path = item.partition("=")
        if not sep or not path:
            raise InputError(f"--videos {item}: expected CONDITION=PATH")
        if cond not in CONDITIONS:
            raise InputError(f"--videos {item}: unknown condition {cond!r}; choose from "
                             f"{', '.join(CONDITIONS)}")
        if cond in out:
            raise InputError(f"--videos {item}: condition {cond} given twice")
        out[cond] = path
    return out


def _write_outputs(report: dict, errors: list, report_path: Path, errors_path: Path):
    from morphable.io.atomic import atomic_path

    if errors:
        save_error_maps(errors_path, errors)
    with atomic_path(report_path) as tmp:
        tmp.write_text(json.dumps(report, indent=1))


@one_line_errors("evaluation.florence")
def main(argv=None) -> int:
    from tqdm.contrib.logging import logging_redirect_tqdm

    args = _parser().parse_args(argv)
    configure(verbosity(args))
    report_path = Path(args.report)
    errors_path = Path(args.errors) if args.errors else report_path.with_name(report_path.stem + "_errors.npz")
    for p in (report_path, errors_path):
        if not p.parent.is_dir() and str(p.parent):
            raise InputError(f"{p}: output folder {p.parent} does not exist")
    if args.frames < 1 or (args.video_frames < args.frames and not args.videos):
        raise InputError(f"--frames {args.frames}: need 1 <= frames <= --video-frames "
                         f"({args.video_frames})")
    from morphable import load_model

    if (args.synthetic_scan is None) == (args.scan is None):
        raise InputError("give either --scan with --scan-landmarks, or --synthetic-scan")
    if args.scan is not None and args.scan_landmarks is None:
        raise InputError(f"--scan {args.scan}: --scan-landmarks is required")
    resolve_detectors(args.landmark_detector, args.face_detector)  # a bad choice fails first
    detect = (args.landmark_detector, args.face_detector) if args.detect else None
    model = load_model(args.model)
    if args.synthetic_scan:
        scan_model = load_model(args.synthetic_scan)
        if not (np.isfinite(args.definition_noise) and args.definition_noise >= 0):
            raise InputError(f"--definition-noise {args.definition_noise}: must be >= 0")
        if not (np.isfinite(args.expression_std) and args.expression_std >= 0):
            raise InputError(f"--expression-std {args.expression_std}: must be >= 0")
        for bad in ("frames_dir", "heatmaps", "videos"):
            if getattr(args, bad):
                raise InputError(f"--{bad.replace('_', '-')} does not apply to --synthetic-scan")
        if args.appearance and not (args.detect or "gar" in args.methods):
            raise InputError("--appearance colours rendered frames: use it with --detect or "
                             "the gar method")
    elif args.appearance:
        raise InputError("--appearance applies to --synthetic-scan (a scan has its own texture)")
    elif args.expression_std:
        raise InputError("--expression-std applies to --synthetic-scan")
    else:
        scan = load_scan(args.scan, args.scan_landmarks, args.scan_units)
    ours = {k: v for k, v in (("n_iterations", args.n_iterations),
                              ("definition_std_mm", args.definition_std),
                              ("model_std_mm", args.model_std),
                              ("expression_weight", args.expression_weight),
                              ("camera", None if args.camera == "auto" else args.camera))
            if v is not None}
    if args.focal_px is not None and not (np.isfinite(args.focal_px) and args.focal_px > 0):
        raise InputError(f"--focal-px {args.focal_px}: must be a positive number")
    if args.focal_px is not None and not (args.frames_dir or args.videos):
        raise InputError("--focal-px applies to --frames-dir and --videos (synthetic videos know "
                         "their focal)")
    videos = parse_videos(args.videos) if args.videos else None
    if videos and args.frames_dir:
        raise InputError("give --videos or --frames-dir, not both")
    if videos:
        detect = (args.landmark_detector, args.face_detector)   # a video's frames are detected
        from morphable.video import probe

        for path in videos.values():     # not a video, no frames: before any fit
            probe(path)
    efforts = {"ours": ours, "ours-independent": dict(ours)} if ours else {}
    photometric = {k: v for k, v in (("steps", args.photometric_steps),
                                     ("resolution", args.photometric_resolution)) if v is not None}
    if any(v < 1 for v in photometric.values()):
        raise InputError(f"--photometric-steps/--photometric-resolution: must be at least 1, "
                         f"got {photometric}")
    if args.photometric_loss_weight:
        photometric["weights"] = parse_loss_weights(args.photometric_loss_weight,
                                                    "--photometric-loss-weight")
    if ours or photometric:
        efforts.update({m: {**ours, **photometric}
                        for m in ("ours-photometric", "ours-photometric-gar")})
    if args.gar_steps is not None:
        if args.gar_steps < 1:
            raise InputError(f"--gar-steps {args.gar_steps}: must be at least 1")
        efforts["gar"] = {"steps": args.gar_steps}
    if args.gar_region is not None:
        efforts.setdefault("gar", {})["region"] = args.gar_region
    if args.gar_loss_weight:
        efforts.setdefault("gar", {})["weights"] = parse_loss_weights(args.gar_loss_weight,
                                                                      "--gar-loss-weight")
    if args.plot:
        from evaluation.plots import check_plot_path

        check_plot_path(args.plot)
    common = dict(efforts=efforts, radius=args.radius, icp=not args.no_icp,
                  icp_scale=args.icp_scale, landmark_scale=not args.rigid,
                  log=logging.getLogger("evaluation.florence").info, progress=not args.quiet,
                  renderer=args.renderer)
    with logging_redirect_tqdm():
        if args.synthetic_scan:
            errors = []
            looks = [(Path(p).name, photo_colors(scan_model, p)) for p in args.appearance or ()]
            report = run_model_scans(scan_model, model, args.methods, args.conditions,
                                     args.n_scans, args.seed, definition_mm=args.definition_noise,
                                     expression_std=args.expression_std,
                                     appearances=looks, n_sampled=args.frames, detect=detect,
                                     n_frames=args.video_frames, n_videos=args.n_videos,
                                     **common)
        elif args.n_videos != 1:
            if args.frames_dir or videos:
                raise InputError("--n-videos draws synthetic videos; --frames-dir and --videos "
                                 "have one")
            report, errors = run_videos(scan, model, args.methods, args.conditions,
                                        args.n_videos, args.seed, n_sampled=args.frames,
                                        n_frames=args.video_frames, detect=detect, **common)
        else:
            report, errors = run_protocol(scan, model, args.methods, args.conditions,
                                          args.frames, args.video_frames, args.seed,
                                          detect=detect, frames_dir=args.frames_dir,
                                          focal_px=args.focal_px, videos=videos, **common)
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
        from ..videos import frontal_frame

        frame = frontal_frame(scan.landmarks, model.landmark_positions())
        for m in errors:
            save_heatmap(Path(args.heatmaps) / f"{m.method}_{m.condition}.png", m.vertices,
                         m.triangles, m.mesh_errors, frame)
    return 0
