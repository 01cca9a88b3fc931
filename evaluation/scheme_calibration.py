"""Calibrate a model's facemesh478 scheme with the detector itself: where does the face mesh put
each point on a face whose geometry is known, and how far does it stray?

The registration of :mod:`morphable.fitting.scheme_build` places mediapipe's *canonical* mesh
on the model; the detector's points are defined by its training data, not by that mesh (its
brow points sit on the brow's edge, its oval on the visible outline...). So: model subjects
(random identities, neutral) wearing the colours of real photos
(:func:`evaluation.scans.photo_colors`) are rendered over a range of yaws and pitches; the
detector runs on each render; every detected fixed point is cast back onto the subject's
surface (the rasteriser's triangle and barycentric weights at that pixel), which names a point
of the model's surface. Per point, the mean of those surface points (on the mean shape) becomes
its new position, and the per-coordinate RMS distance of the hits from it (on each subject's
own surface) its ``definition_std_mm``. A point is used in a render only where the model point
is visible there (a hidden point's hit lands on whatever is in front of it). A point and its mirror
image are averaged (the detector and the model are left-right symmetric). The sliding oval
points and the chin that ends them keep their registration (they are defined by the outline)
and their definition error.

The photos only lend skin, brows and lips: the geometry is the model's. By default the first 20
people of the London set (CC BY 4.0; neutral front photos) are used, so that the calibrated
files carry no research-only data, and the London identity benchmark reports the other 82
people apart. ::

    python -m evaluation.scheme_calibration --model sfm --out morphable/data/facemesh478_sfm.npz
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from morphable.errors import FitError, InputError, one_line_errors
from morphable.io.atomic import atomic_path
from morphable.logs import add_verbosity_arguments, configure, verbosity

__all__ = ["VIEWS", "STD_RANGE_MM", "render_subject", "back_project", "calibrate", "collect_hits",
           "london_photos", "main"]

VIEWS = tuple((y, 0.0) for y in (-60, -45, -30, -15, 0, 15, 30, 45, 60)) + ((0.0, -15.0), (0.0, 15.0))
"""(yaw, pitch) degrees of the calibration renders."""

IMAGE = 512

STD_RANGE_MM = (1.0, 8.0)
"""Calibrated definition errors are clipped to this range, mm per coordinate."""


def render_subject(vertices, triangles, colors, yaw, pitch, image_size=IMAGE):
    """A soft-lit render of a coloured mesh -> (H, W, 3) uint8, its camera and its
    :class:`~morphable.raster.Visibility`."""
    from morphable.raster import DirectionalLight, frame_mesh, render, visibility

    cam = frame_mesh(vertices, (image_size, image_size), yaw=yaw, pitch=pitch, margin=0.15)
    vis = visibility(vertices, triangles, cam)
    img = render(vertices, triangles, cam, colors=colors, vis=vis,
                 light=DirectionalLight(direction=(0.2, 0.3, 1.0), color=0.6))
    return (np.clip(img[..., :3], 0, 1) * 255).round().astype(np.uint8), cam, vis


def back_project(points_px, vis):
    """Detected points (L, 2) px -> the triangle (L,) (-1: background or outside the image)
    and barycentric weights (L, 3) of the surface each one's pixel shows."""
    (i, j), inside = _pixels(points_px, vis)
    tri = np.where(inside, vis.triangle_id[i, j], -1)
    return tri, vis.barycentric[i, j].astype(np.float64)


def _pixels(points_px, vis):
    """Nearest pixel rows and columns of points (L, 2) px (0 where outside the image) and
    (L,) bool: inside (NaN points are outside)."""
    H, W = vis.triangle_id.shape
    ij = np.round(np.nan_to_num(np.asarray(points_px, np.float64)[:, ::-1], nan=-1.0)).astype(np.int64)
    inside = (ij >= 0).all(1) & (ij[:, 0] < H) & (ij[:, 1] < W)
    ij = np.where(inside[:, None], ij, 0)
    return (ij[:, 0], ij[:, 1]), inside


def _visible(points, cam, vis, tol_mm: float = 3.0):
    """(L,) bool: model points (L, 3) mm in view and not behind the surface (depth test)."""
    (i, j), inside = _pixels(cam.project(points), vis)
    depth = -cam.to_camera(points)[:, 2]
    return inside & np.isfinite(points).all(1) & (depth <= vis.depth[i, j] + tol_mm)


def calibrate(model, scheme, looks, n_subjects: int = 20, seed: int = 0, views=VIEWS,
              detect=None) -> tuple:
    """Calibrate ``scheme`` (facemesh478 of ``model``) on renders -> (calibrated scheme, report).

    ``looks``: vertex colours (V, 3) in [0, 1] the subjects wear in turn
    (:func:`evaluation.scans.photo_colors` of photos); ``detect``: (H, W, 3) uint8 image ->
    (L, 2) px, FitError when it finds no face (default the face mesh). The report holds per
    point the shift of its position (mm, on the mean shape), its new definition error and how
    many renders saw it."""
    t0 = time.perf_counter()
    subjects, hits_mean, hits_subj, subj_of, failures = collect_hits(
        model, scheme, looks, n_subjects, seed, views, detect)
    count = np.isfinite(hits_mean[..., 0]).sum(0)
    fixed = ~scheme.sliding & scheme.defined
    if scheme.chin >= 0:
        fixed[scheme.chin] = False          # it ends the outline: defined by it, like the oval
    use = fixed & (count >= 5)
    use &= use[scheme.mirror]
    calibrated = _calibrated(model, scheme, use, subjects, hits_mean, hits_subj, subj_of)
    mean = np.asarray(model.mean, np.float64)
    shift = np.linalg.norm(calibrated.points(mean) - scheme.points(mean), axis=1)
    std = calibrated.definition_std_mm
    report = {"model": model.name, "subjects": n_subjects, "views": [list(v) for v in views],
              "renders": len(hits_mean), "no_face": failures,
              "seconds": time.perf_counter() - t0, "calibrated_points": int(use.sum()),
              "shift_mm": {"median": float(np.median(shift[use])),
                           "p90": float(np.percentile(shift[use], 90)), "max": float(shift[use].max())},
              "definition_std_mm": {"median": float(np.median(std[use])),
                                    "p10": float(np.percentile(std[use], 10)),
                                    "p90": float(np.percentile(std[use], 90))},
              "per_point": {"shift_mm": shift.round(3).tolist(), "std_mm": std.round(3).tolist(),
                            "renders_seen": count.tolist()}}
    return calibrated, report


def collect_hits(model, scheme, looks, n_subjects, seed, views, detect=None):
    """Render the subjects, detect, cast the detected points back -> (subjects' vertices
    (S, V, 3) mm, hits on the mean shape and on the subject (R, L, 3) mm, NaN where a point was
    not found or its model point hidden, the subject of each render (R,), renders without a
    face). FitError when no render had a face."""
    if detect is None:
        from morphable.detection import detect_landmarks

        def detect(img):
            return detect_landmarks(img, landmark_detector="facemesh")
    rng = np.random.default_rng(seed)
    tri_all = np.asarray(model.triangles)
    mean = np.asarray(model.mean, np.float64)
    subjects, hits_mean, hits_subj, subj_of, failures = [], [], [], [], 0
    for s in range(n_subjects):
        verts = model.vertices(rng.standard_normal(model.n_identity)).astype(np.float64)
        subjects.append(verts)
        for yaw, pitch in views:
            img, cam, vis = render_subject(verts, tri_all, looks[s % len(looks)], yaw, pitch)
            try:
                pts = detect(img)
            except FitError:
                failures += 1
                continue
            tri, bary = back_project(pts, vis)
            ok = (tri >= 0) & _visible(scheme.points(verts), cam, vis)
            corners = tri_all[np.maximum(tri, 0)]
            for out, X in ((hits_mean, mean), (hits_subj, verts)):
                out.append(np.where(ok[:, None], np.einsum("lkc,lk->lc", X[corners], bary), np.nan))
            subj_of.append(s)
    if not hits_mean:
        raise FitError("calibration: the detector found no face in any render")
    return np.stack(subjects), np.stack(hits_mean), np.stack(hits_subj), np.array(subj_of), failures


def _calibrated(model, scheme, use, subjects, hits_mean, hits_subj, subj_of):
    """The scheme with the points ``use`` (L,) bool moved to their hits' mean and given their
    spread as definition error."""
    from morphable.fitting.scheme_build import project_to_surface

    # the detector and the model are left-right symmetric: a point and its mirror image
    # (x reflected) are two estimates of one definition
    centre = np.full((scheme.n, 3), np.nan)
    centre[use] = np.nanmean(hits_mean[:, use], axis=0)
    centre = 0.5 * (centre + centre[scheme.mirror] * [-1.0, 1.0, 1.0])
    vertices, barycentric = scheme.vertices.copy(), scheme.barycentric.copy()
    vertices[use], barycentric[use], _ = project_to_surface(centre[use], model)
    # spread: each hit against the new point on the same subject's surface
    new_pts = np.einsum("slkc,lk->slc", subjects[:, vertices[use]], barycentric[use])
    d = hits_subj[:, use] - new_pts[subj_of]
    ms = np.full(scheme.n, np.nan)
    ms[use] = np.nanmean((d ** 2).sum(-1), axis=0) / 3.0
    ms = 0.5 * (ms + ms[scheme.mirror])
    # rounded to 0.5 mm (about the estimate's own noise over ~200 renders): a fit groups the
    # points of one definition error, so a few distinct values keep it fast
    std = scheme.definition_std_mm.copy()
    std[use] = np.clip(np.round(2.0 * np.sqrt(ms[use])) / 2.0, STD_RANGE_MM[0], STD_RANGE_MM[1])
    return type(scheme)(
        name=scheme.name, model_name=scheme.model_name, vertices=vertices, barycentric=barycentric,
        outline_right=scheme.outline_right, outline_left=scheme.outline_left, chin=scheme.chin,
        definition_std_mm=std, mirror=scheme.mirror, ibug68=scheme.ibug68)


def london_photos(root: Path, n: int) -> list:
    """The first ``n`` neutral front photos of the London set under ``root/faces``."""
    photos = sorted((Path(root) / "faces" / "frl_london" / "neutral_front").glob("*_03.jpg"))[:n]
    if not photos:
        raise InputError(f"{root}/faces/frl_london/neutral_front: no photos found")
    return photos


@one_line_errors("python -m evaluation.scheme_calibration")
def main(argv=None):
    from morphable import load_model
    from morphable.fitting.schemes import load_scheme, save_scheme

    from .bench_alignment import data_root

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--model", default="sfm")
    p.add_argument("--scheme", type=Path, default=None,
                   help="the registered scheme to start from (default the model's sidecar)")
    p.add_argument("--photos", nargs="+", type=Path, default=None,
                   help="photos lending colours (default the first --n-photos London people)")
    p.add_argument("--n-photos", type=int, default=20)
    p.add_argument("--n-subjects", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data", type=Path, default=None)
    p.add_argument("--out", type=Path, required=True, help="calibrated sidecar (.npz)")
    p.add_argument("--report", type=Path, default=None, help="JSON report (default beside --out)")
    add_verbosity_arguments(p)
    a = p.parse_args(argv)
    configure(verbosity(a))
    if not a.out.parent.is_dir():
        raise InputError(f"{a.out}: output folder {a.out.parent} does not exist")
    model = load_model(a.model)
    scheme = load_scheme(model, "facemesh478", a.scheme)
    from .scans import photo_colors

    photos = a.photos or london_photos(a.data or data_root(), a.n_photos)
    calibrated, report = calibrate(model, scheme, [photo_colors(model, p) for p in photos],
                                   n_subjects=a.n_subjects, seed=a.seed)
    report["photos"] = [str(p) for p in photos]
    save_scheme(calibrated, a.out, model)
    rep = a.report or a.out.with_suffix(".calibration.json")
    with atomic_path(rep) as tmp:
        tmp.write_text(json.dumps(report, indent=1))
    print(f"{model.name}: {report['calibrated_points']} points calibrated on {report['renders']} renders "
          f"({report['no_face']} without a face); shift median {report['shift_mm']['median']:.2f} mm, "
          f"90 % {report['shift_mm']['p90']:.2f} mm; definition std median "
          f"{report['definition_std_mm']['median']:.2f} mm; wrote {a.out} and {rep}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
