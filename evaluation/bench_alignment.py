"""68-point alignment on real photos: AFLW2000-3D (by ``|yaw|`` bin, with head pose) and 300-W.

Methods, each run on every photo of a set:

- ``dlib``: dlib's HOG face detector and 68-point shape predictor;
- ``facemesh``: mediapipe's 478-point face mesh, mapped to iBUG-68 by
  :data:`morphable.detection.facemesh.FACEMESH_TO_IBUG68`;
- ``ours+photometric``, ``ours-dlib+gar``, ``ours-facemesh+classical``, ...: that fit refined
  as ``morphable fit --refine photometric`` (``classical`` is the same) or ``--refine gar``
  refines it (:func:`morphable.pipeline.refine.refine_fit`, ``--steps`` Adam steps, the
  default loss weights unless ``--loss-weight``; the GAR's weights from ``--gar-weights`` or
  the committed ones), scored the same way — whether photometric refinement moves the 68
  points towards or away from the ground truth;
- ``network``: the landmark network's own 68 rows (``landmark_detector="network"``, its
  weights from ``$MORPHABLE_LANDMARK_WEIGHTS`` or the committed ones; by name only);
- ``fused``: the network's and the face mesh's points fused by their uncertainty
  (``landmark_detector="fused"``, :func:`morphable.detection.fusion.fuse`), its 68 rows;
- ``ours``: our fit with the default detector (``landmark_detector="auto"``: "fused" where
  both can run), as ``morphable fit IMAGE`` runs;
- ``3ddfa-v2``: a peer, 3DDFA-V2's released MobileNet-0.5 (ECCV 2020) run from its released
  files by our own loader (:mod:`evaluation.peers_3ddfa`; the files read from ``--3ddfa-dir``
  or ``$MORPHABLE_3DDFA_DIR``, research use; skipped with one printed line when absent), its 68
  points from the crop of the face box: the given box, else the default detector's face box
  (:func:`morphable.detection.detect_faces`, the same boxes our ``network`` reads);
- ``ours-dlib``, ``ours-facemesh``, ``ours-network``, ``ours-fused``: our fit (SFM, one frame) to the detector's points,
  made as ``morphable fit`` makes it (:func:`morphable.fitting.options.detection_settings`:
  the face mesh's and the network's 478 points in the 3D convention, the network's σ); its
  projected iBUG-68 landmarks (``FitResult.landmarks_68_px``) are what is scored, so that the
  fit must place the 68 points itself: AFLW2000-3D's ground truth is projected 3D landmarks
  (a hidden jaw point is where the jaw is, behind the cheek), so there the fit's jaw points stay
  on its jaw line (``convention="3d"``); 300-W's annotators put them on the visible outline
  (``"2d"``, the silhouette).

**AFLW2000-3D** (``../shared/data/aflw2000``, the shared even half, research use only), the
standard protocol of 3DDFA: ground truth ``pts68_3d`` x, y (0-based px); NME = mean point
distance / sqrt(w h) of the ground-truth points' box; mean per ``|yaw|`` bin [0, 30], (30, 60],
(60, 90+] degrees (the bins of 3DDFA's benchmark code) and the mean of the three. Head pose
(fits only): mean absolute error of yaw, pitch, roll against the dataset's ``pose`` (degrees,
our angles mapped to its sign convention, see :func:`aflw_angles`). A photo where a method
finds no face counts as a failure in its bin, never silently dropped: the NME figures are over
the photos it found, and the failures are listed beside them.

**300-W** (``../shared/data/images/300w``: afw and helen test, research use only): NME by the
outer-eye-corner distance (points 37 and 46), for all methods, on the annotated face: the
detected face that overlaps the box of its ground-truth points most (AFW photos with several
faces are stored once per annotated face, so "the largest face" would score another face).
dlib's shape predictor was
trained on 300-W's training images, which include AFW: its figure there is optimistic.

Times are wall ms per photo (detection, plus the fit for ``ours`` and ``ours-*``), median over the photos,
with torch on ``--threads`` threads (default: torch's own choice).

    python -m evaluation.bench_alignment --set aflw2000 300w --report reports/bench_alignment.json
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from morphable.cli.common import add_loss_weight_argument
from morphable.errors import FitError, InputError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity

from .bench_report import write_report
from .peers_3ddfa import add_dir_argument, unavailable

__all__ = ["METHODS", "NETWORK_METHODS", "PEER_METHODS", "REFINED", "REFINEMENTS", "YAW_BINS", "data_root", "refiner",
           "refined_methods", "add_refine_arguments", "refine_options", "load_aflw2000", "load_300w",
           "box_size", "eye_distance", "nme", "yaw_bins", "yaw_table", "dataset_boxes", "aflw_angles",
           "run_method", "main"]

METHODS = ("dlib", "facemesh", "ours-dlib", "ours-facemesh", "ours")
"""The methods run by default; the landmark network's are :data:`NETWORK_METHODS`."""
NETWORK_METHODS = ("network", "ours-network", "fused", "ours-fused")
"""The landmark network's own 68 points and our fit to its 478 (the neural plugin's detector,
:mod:`neural.landmarks.detector`), the same fused with the face mesh's; chosen by name, not run
by default."""
PEER_METHODS = ("3ddfa-v2",)
"""Peers run from their released files (:mod:`evaluation.peers_3ddfa`), by default when the
files are there."""


def _fitted(method: str) -> bool:
    """Whether ``method`` is one of our fits, refined or not (scored by its projected points),
    or a detector."""
    return method.partition("+")[0] == "ours" or method.startswith("ours-")


REFINEMENTS = ("photometric", "classical", "gar")
"""The refinements a fitted method may be followed by (``ours+photometric``): the names of
``morphable fit --refine`` (:func:`morphable.pipeline.refine.refine_fit`; ``classical`` is
``photometric``)."""


def refined_methods(methods) -> tuple:
    """``ours`` and ``ours-*`` methods of ``methods`` followed by ``+photometric`` /
    ``+classical`` / ``+gar``: those fits refined as ``morphable fit --refine`` refines them
    (not run by default: seconds per photo)."""
    return tuple(f"{m}+{r}" for m in methods if _fitted(m) for r in REFINEMENTS)


REFINED = refined_methods(METHODS + NETWORK_METHODS)
"""The refined fits of :data:`METHODS` and :data:`NETWORK_METHODS`."""
YAW_BINS = ((0.0, 30.0), (30.0, 60.0), (60.0, np.inf))
"""``|yaw|`` bins, degrees: [0, 30], (30, 60], (60, ...) (3DDFA's benchmark code puts the few
photos beyond 90 degrees into the last bin)."""


def data_root() -> Path:
    """The shared data folder: the first of ``$MORPHABLE_DATA`` holding ``aflw2000``, else
    ``../shared/data`` beside the repository."""
    for p in os.environ.get("MORPHABLE_DATA", "").split(os.pathsep):
        if p and (Path(p) / "aflw2000").is_dir():
            return Path(p)
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"


def load_aflw2000(root: Path, n: int | None = None) -> dict:
    """The AFLW2000-3D photos under ``root/aflw2000``: ``paths`` (N,), ``gt`` (N, 68, 2) px
    (``pts68_3d`` x, y, 0-based), ``yaw_deg`` (N,), ``pose_deg`` (N, 3) pitch, yaw, roll; the
    first ``n`` photos when given."""
    folder = Path(root) / "aflw2000"
    f = folder / "landmarks.npz"
    if not f.is_file():
        raise InputError(f"{f}: AFLW2000-3D landmarks not found")
    z = np.load(f)
    sl = slice(None) if n is None else slice(0, n)
    return {"paths": [folder / str(s) for s in z["names"][sl]],
            "gt": z["pts68_3d"][sl, :, :2].astype(np.float64),
            "yaw_deg": z["yaw_deg"][sl].astype(np.float64),
            "pose_deg": np.degrees(z["pose"][sl].astype(np.float64))}


def load_300w(root: Path, n: int | None = None) -> dict:
    """The 300-W afw and helen test photos under ``root/images/300w``: ``paths``, ``gt``
    (N, 68, 2) px, ``subset`` (N,) ``"afw"`` / ``"helen"``; every k-th photo so that ``n`` are
    taken evenly from both when given."""
    from morphable.io.landmark_files import read_pts

    folder = Path(root) / "images" / "300w"
    items = [(p, "afw") for p in sorted((folder / "afw").glob("*.jpg"))]
    items += [(p, "helen") for p in sorted((folder / "helen" / "testset").glob("*.jpg"))]
    if not items:
        raise InputError(f"{folder}: no 300-W photos found")
    if n is not None and n < len(items):
        items = [items[i] for i in np.linspace(0, len(items) - 1, n).round().astype(int)]
    return {"paths": [p for p, _ in items], "subset": np.array([s for _, s in items]),
            "gt": np.stack([read_pts(p.with_suffix(".pts")) for p, _ in items])}


def box_size(gt) -> np.ndarray:
    """(N,) sqrt(w h) of the box of each ground truth (N, 68, 2), px."""
    wh = gt.max(1) - gt.min(1)
    return np.sqrt(wh[:, 0] * wh[:, 1])


def eye_distance(gt) -> np.ndarray:
    """(N,) distance of the outer eye corners (iBUG points 37 and 46), px."""
    return np.linalg.norm(gt[:, 36] - gt[:, 45], axis=1)


def nme(pred, gt, norm) -> np.ndarray:
    """(N,) mean point-to-point distance of ``pred`` and ``gt`` (N, 68, 2) px divided by
    ``norm`` (N,), in percent, over the points ``pred`` gives (the SFM has no vertices for the
    inner mouth corners, iBUG 61 and 65: a fit with it is scored on 66); NaN where ``pred`` is
    all NaN (a failure)."""
    d = np.linalg.norm(pred - gt, axis=-1)
    given = np.isfinite(d)
    with np.errstate(invalid="ignore"):
        mean = np.where(given, d, 0.0).sum(1) / given.sum(1)
    return np.where(given.sum(1) >= 60, 100.0 * mean / norm, np.nan)


def yaw_bins(yaw_deg) -> list:
    """The :data:`YAW_BINS` of (N,) yaw angles (degrees) -> [(lo, hi, (N,) bool), ...]: ``|yaw|`` in
    (lo, hi], the first bin with 0 itself."""
    a = np.abs(np.asarray(yaw_deg))
    return [(lo, hi, (a <= hi) & ((a > lo) if lo > 0 else True)) for lo, hi in YAW_BINS]


def yaw_table(errors, yaw_deg) -> dict:
    """Per ``|yaw|`` bin: photos, failures (NaN errors) and the mean NME over the rest; and the mean
    of the bins' means."""
    bins = []
    for lo, hi, sel in yaw_bins(yaw_deg):
        e = errors[sel]
        ok = np.isfinite(e)
        bins.append({"bin": f"{lo:.0f}-{hi:.0f}" if np.isfinite(hi) else f">{lo:.0f}",
                     "photos": int(sel.sum()), "failures": int((~ok).sum()),
                     "nme_percent": float(e[ok].mean()) if ok.any() else None})
    means = [b["nme_percent"] for b in bins if b["nme_percent"] is not None]
    return {"bins": bins, "mean_percent": float(np.mean(means)) if len(means) == 3 else None}


def aflw_angles(euler_deg) -> np.ndarray:
    """Our (yaw, pitch, roll) (N, 3) degrees -> AFLW2000-3D's (pitch, yaw, roll) (N, 3).

    All three turn the other way in the dataset's convention (its rotation acts on a model
    whose y axis points down the image): on the first 40 photos our fits' angles correlate with
    the dataset's by -0.98 (yaw), -0.81 (roll) and -0.38 (pitch) — a sign check, nothing is
    fitted. The two decompose in different orders (ours Rz Rx Ry, the dataset Rx Ry Rz), which
    agree to first order; and the SFM's frame is not the BFM's: a constant pitch offset between
    the two models' "straight ahead" is not corrected (it cannot be measured here without
    the BFM or poses outside the test set), so pitch errors include it."""
    e = np.asarray(euler_deg, dtype=np.float64)
    return np.stack([-e[:, 1], -e[:, 0], -e[:, 2]], -1)


def refiner(renderer: str, steps: int = 100, renderer_options: dict | None = None,
            loss_weights: dict | None = None):
    """``fit -> refined fit`` for the photo ``img``: a callable ``(img, fit) -> fit`` that
    refines the fit as ``morphable fit --refine renderer`` does
    (:func:`morphable.pipeline.refine.refine_fit`; ``renderer`` "" for none: the fit
    unchanged) for ``steps`` Adam steps, the renderer made with ``renderer_options[name]``
    (e.g. ``{"gar": {"weights": path}}``), the refinement's loss weights overridden by
    ``loss_weights`` (:data:`morphable.refinement.DEFAULT_WEIGHTS`)."""
    if not renderer:
        return lambda img, fit: fit
    from morphable.pipeline.inputs import Picture
    from morphable.pipeline.refine import refine_fit, renderer_of

    options = (renderer_options or {}).get(renderer_of(renderer))

    def refined(img, fit):
        picture = Picture("photo", img, (img.shape[1], img.shape[0]))
        return refine_fit(fit, [picture], renderer, steps=steps, weights=loss_weights,
                          renderer_options=options)[0]
    return refined


def add_refine_arguments(p) -> None:
    """``--steps``, ``--loss-weight``, ``--gar-weights`` and ``--gar-region`` of the refined
    methods, on the parser ``p``."""
    p.add_argument("--steps", type=int, default=100, help="Adam steps of the refined methods")
    add_loss_weight_argument(p)
    p.add_argument("--gar-weights", help="generator.pt of the gar renderer (default: the committed one)")
    p.add_argument("--gar-region", choices=("crop", "face"), default="crop",
                   help="pixels gar's photometric terms compare: the whole crop (default) or "
                        "the fitted face")


def refine_options(args) -> dict:
    """``steps``, ``renderer_options`` and ``loss_weights`` (:func:`refiner`'s keywords) from
    the parsed :func:`add_refine_arguments`; a one-line InputError when the weights file is
    missing or a loss weight is not one (:func:`morphable.refinement.parse_loss_weights`)."""
    from morphable.refinement import parse_loss_weights

    if args.gar_weights and not Path(args.gar_weights).is_file():
        raise InputError(f"{args.gar_weights}: --gar-weights file not found")
    gar = {"weights": args.gar_weights} if args.gar_weights else {}
    if args.gar_region != "crop":
        gar["photometric_region"] = args.gar_region
    return {"steps": args.steps, "renderer_options": {"gar": gar} if gar else None,
            "loss_weights": parse_loss_weights(args.loss_weight, "--loss-weight") or None}


def run_method(method: str, paths, model=None, convention: str = "2d", boxes=None,
               steps: int = 100, renderer_options: dict | None = None,
               loss_weights: dict | None = None, given_boxes=None, peer_dir=None) -> dict:
    """Run ``method`` (:data:`METHODS`, :data:`REFINED`: ``steps`` Adam steps of the
    renderer made with ``renderer_options[name]``, e.g. ``{"gar": {"weights": path}}``) on every photo
    (``paths``: photo paths or (H, W, 3) uint8 arrays): ``pred`` (N, 68, 2) px (NaN rows: no face),
    ``ms`` (N,) wall ms (NaN for failures), ``euler_deg`` (N, 3) for fits (NaN otherwise),
    ``errors`` {photo: one-line reason}. With annotation ``boxes`` (N, 4) px, the face is the
    detector's face that overlaps the annotated one most (IoU >= 0.3, else a failure), each
    detector with its own face detector's box (dlib's shape predictor expects its detector's
    framing); otherwise the largest face found. ``given_boxes`` (N, 4) px: no face detection,
    each photo's landmarks detected in its given box (the dataset's box protocol). ``3ddfa-v2``
    (:data:`PEER_METHODS`) reads its files from ``peer_dir`` (default ``$MORPHABLE_3DDFA_DIR``)
    and takes the default detector's face boxes."""
    from morphable.detection import detect, detect_faces, detect_ibug68, detect_landmarks
    from morphable.detection.boxes import iou
    from morphable.detection.images import as_image
    from morphable.fitting import fit_landmarks
    from morphable.fitting.options import detection_settings

    method, _, renderer = method.partition("+")
    fitted = _fitted(method)
    peer = None
    if method in PEER_METHODS:
        from .peers_3ddfa import ThreeDDFA

        peer = ThreeDDFA(peer_dir)
    detector = "auto" if method == "ours" or peer else method.removeprefix("ours-")
    refined = refiner(renderer, steps, renderer_options, loss_weights)
    N = len(paths)
    pred = np.full((N, 68, 2), np.nan)
    ms = np.full(N, np.nan)
    euler = np.full((N, 3), np.nan)
    errors = {}
    try:
        first = as_image(paths[0])[0]
        detect_landmarks(first, landmark_detector=detector)  # warm-up (model load)
        if peer:
            peer.ibug68(first, (0, 0, first.shape[1], first.shape[0]))
    except FitError:
        pass
    for i, p in enumerate(paths):
        img, name = as_image(p)
        name = name if isinstance(p, (str, Path)) else f"image {i}"
        t = time.perf_counter()
        try:
            box = None if given_boxes is None else given_boxes[i]
            if boxes is not None and given_boxes is None:
                faces = detect_faces(img, landmark_detector=detector)
                overlap = iou(faces, boxes[i]) if len(faces) else np.zeros(0)
                if not len(faces) or overlap.max() < 0.3:
                    raise FitError(f"{name}: no detected face on the annotated one")
                box = faces[int(np.argmax(overlap))]
            if peer and box is None:
                faces = detect_faces(img, landmark_detector=detector)
                if not len(faces):
                    raise FitError(f"{name}: no face found")
                box = faces[0]                          # the largest
            if fitted:
                found = detect(img, landmark_detector=detector, box=box)
                res = fit_landmarks(model, found.points, (img.shape[1], img.shape[0]),
                                    **detection_settings([found], len(found.points)))
                res = refined(img, res)
                pred[i] = res.landmarks_68_px(convention)[0]
                euler[i] = res.euler_deg[0]
            elif peer:
                pred[i] = peer.ibug68(img, box)
            else:
                pred[i] = detect_ibug68(img, landmark_detector=detector, box=box)
        except (FitError, InputError) as e:
            errors[name] = str(e)
            continue
        ms[i] = (time.perf_counter() - t) * 1e3
    return {"pred": pred, "ms": ms, "euler_deg": euler, "errors": errors}


def dataset_boxes(gt) -> np.ndarray:
    """``--boxes dataset``: the box of each photo's ground-truth points (N, 68, 2) -> (N, 4)
    ``(left, top, right, bottom)`` px, as peers given the annotation's box are scored."""
    return np.concatenate([np.nanmin(gt, 1), np.nanmax(gt, 1)], 1)


def _aflw2000(methods, root, n, model, box_source="detect", peer_dir=None, **refine) -> dict:
    d = load_aflw2000(root, n)
    norm = box_size(d["gt"])
    out = {"photos": len(d["paths"]), "methods": {}, "boxes": box_source}
    given = dataset_boxes(d["gt"]) if box_source == "dataset" else None
    for m in methods:
        r = run_method(m, d["paths"], model, convention="3d", given_boxes=given, peer_dir=peer_dir,
                       **refine)
        e = nme(r["pred"], d["gt"], norm)
        row = yaw_table(e, d["yaw_deg"])
        row["median_ms"] = float(np.nanmedian(r["ms"])) if np.isfinite(r["ms"]).any() else None
        row["failures"] = int(np.isnan(e).sum())
        if _fitted(m):
            ok = np.isfinite(r["euler_deg"][:, 0])
            err = np.abs(aflw_angles(r["euler_deg"][ok]) - d["pose_deg"][ok])
            err = np.minimum(err, 360.0 - err)          # a few dataset angles are unwrapped
            row["pose_mae_deg"] = dict(zip(("pitch", "yaw", "roll"), (float(x) for x in err.mean(0))))
        out["methods"][m] = row
    return out


def _300w(methods, root, n, model, box_source="detect", peer_dir=None, **refine) -> dict:
    d = load_300w(root, n)
    norm = eye_distance(d["gt"])
    out = {"photos": len(d["paths"]), "methods": {}, "boxes": box_source,
           "face": "the detected face overlapping the ground-truth points' box most"
           if box_source == "detect" else "the ground-truth points' box"}
    # AFW photos with several faces are stored once per annotated face: each method takes the
    # detected face on the annotated one
    boxes = dataset_boxes(d["gt"])
    for m in methods:
        r = run_method(m, d["paths"], model, boxes=boxes, given_boxes=boxes
                       if box_source == "dataset" else None, peer_dir=peer_dir, **refine)
        e = nme(r["pred"], d["gt"], norm)
        row = {"failures": int(np.isnan(e).sum()),
               "median_ms": float(np.nanmedian(r["ms"])) if np.isfinite(r["ms"]).any() else None}
        for s in ("afw", "helen"):
            es = e[d["subset"] == s]
            row[f"{s}_nme_percent"] = float(np.nanmean(es)) if np.isfinite(es).any() else None
        row["nme_percent"] = float(np.nanmean(e)) if np.isfinite(e).any() else None
        out["methods"][m] = row
    return out


def format_tables(report: dict) -> str:
    """Markdown tables of a report."""
    lines = []
    if "aflw2000" in report:
        a = report["aflw2000"]
        lines += [f"AFLW2000-3D, {a['photos']} photos (NME % by sqrt(w h); failures in brackets)", "",
                  "| method | [0, 30] | (30, 60] | > 60 | mean | yaw / pitch / roll MAE (deg) | ms |",
                  "|---|---|---|---|---|---|---|"]
        for m, r in a["methods"].items():
            cells = [f"{b['nme_percent']:.2f} ({b['failures']})" if b["nme_percent"] is not None
                     else f"- ({b['failures']})" for b in r["bins"]]
            mean = f"{r['mean_percent']:.2f}" if r["mean_percent"] is not None else "-"
            pose = ("{yaw:.1f} / {pitch:.1f} / {roll:.1f}".format(**r["pose_mae_deg"])
                    if "pose_mae_deg" in r else "")
            ms = f"{r['median_ms']:.0f}" if r["median_ms"] is not None else "-"
            lines.append(f"| {m} | {' | '.join(cells)} | {mean} | {pose} | {ms} |")
        lines.append("")
    if "300w" in report:
        a = report["300w"]
        lines += [f"300-W afw + helen test, {a['photos']} photos (NME % by outer-eye-corner distance)", "",
                  "| method | afw | helen | all | failures | ms |", "|---|---|---|---|---|---|"]
        f = lambda x: f"{x:.2f}" if x is not None else "-"            # noqa: E731
        for m, r in a["methods"].items():
            lines.append(f"| {m} | {f(r['afw_nme_percent'])} | {f(r['helen_nme_percent'])} | "
                         f"{f(r['nme_percent'])} | {r['failures']} | {f(r['median_ms'])} |")
    return "\n".join(lines)


@one_line_errors("evaluation.bench_alignment")
def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--set", nargs="+", choices=("aflw2000", "300w"), default=["aflw2000"])
    p.add_argument("--methods", nargs="+", choices=METHODS + NETWORK_METHODS + PEER_METHODS + REFINED,
                   default=list(METHODS + PEER_METHODS))
    add_refine_arguments(p)
    p.add_argument("--n", type=int, default=None, help="photos per set (default all)")
    p.add_argument("--boxes", choices=("detect", "dataset"), default="detect",
                   help="detect: each method finds the face itself; dataset: every method gets "
                        "the box of the ground-truth points (no face detection)")
    add_dir_argument(p)
    p.add_argument("--threads", type=int, default=None, help="torch's threads (default: its own choice)")
    p.add_argument("--model", default="sfm")
    p.add_argument("--data", type=Path, default=None, help="shared data folder (default: $MORPHABLE_DATA "
                   "or ../shared/data)")
    p.add_argument("--report", type=Path, default=Path("reports/bench_alignment.json"))
    add_verbosity_arguments(p)
    a = p.parse_args(argv)
    configure(verbosity(a))
    from morphable import load_model

    for m in PEER_METHODS:
        why = unavailable(a.ddfa_dir) if m in a.methods else None
        if why:
            print(f"{m}: skipped, {why}")
            a.methods.remove(m)
    if a.threads:
        import torch

        torch.set_num_threads(a.threads)
    root = a.data or data_root()
    model = load_model(a.model) if any(_fitted(m) for m in a.methods) else None
    report = {"n": a.n, "model": a.model, "threads": a.threads}
    if any(m in PEER_METHODS for m in a.methods):
        from .peers_3ddfa import peer_dir

        report["3ddfa_dir"] = str(peer_dir(a.ddfa_dir))
    refine = refine_options(a)
    if any("+" in m for m in a.methods):
        report.update(steps=a.steps, gar_weights=a.gar_weights, loss_weights=refine["loss_weights"])
    if "aflw2000" in a.set:
        report["aflw2000"] = _aflw2000(a.methods, root, a.n, model, a.boxes, a.ddfa_dir, **refine)
    if "300w" in a.set:
        report["300w"] = _300w(a.methods, root, a.n, model, a.boxes, a.ddfa_dir, **refine)
    write_report(a.report, report, format_tables(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
