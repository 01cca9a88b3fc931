"""The photometric fit on hard photos (issue 54, "Stability"): real London photos (a beard) and
hard-case variants of a neutral one (grey, 16-bit, saturated, a hard shadow, a hand, sunglasses),
each fitted as ``morphable fit PHOTO --refine photometric`` fits it; a contact sheet of the
mask over each photo and a JSON report of the figures. Command::

    python -m evaluation.photometric_stability --out docs/img/photometric_stability.jpg \\
        --report reports/photometric_stability.json

The London set (``../shared/data/faces/frl_london``): L. DeBruine & B. Jones (2017), *Face
Research Lab London Set*, CC BY 4.0. No photo of the set wears glasses, so the glasses are drawn
(:func:`sunglasses`).

Every variant is fitted from the landmarks detected on the neutral photo (written as a ``.pts``
and given with ``--landmarks``), so that the cases differ only in their pixels; the real photos
are fitted from their own detected landmarks. The occluders are placed from those 68 points,
never by hand.

Examples
--------
>>> photo = np.full((4, 4, 3), (200, 120, 80), np.uint8)
>>> grey(photo)[0, 0].tolist(), saturated(photo)[0, 0].tolist()
([139, 139, 139], [255, 255, 240])
"""
from __future__ import annotations

import argparse
import json
import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np

from morphable.errors import FitError, InputError, one_line_errors
from morphable.io.atomic import write_json
from morphable.logs import add_verbosity_arguments, configure, verbosity

from .bench_alignment import data_root

LONDON = Path("faces") / "frl_london" / "neutral_front"
BASE = "018_03.jpg"
"""The neutral photo the variants are made from: clean-shaven, even studio light, no hair over
the face."""
PHOTOS = {BASE: "clean-shaven, even light: the photo the variants below are made from",
          "037_03.jpg": "a full beard and moustache (the set's clearest beard)"}
"""The real photos fitted, with why (looked at by eye: no photo of the set wears glasses)."""
SEED = 54
"""The hand's noise."""
SHADOW_GAIN = 0.3
"""The cast shadow's darkening (x0.3)."""
OVEREXPOSURE = 3.0
"""The saturated variant's gain (x3, clipped at 255)."""


def grey(image) -> np.ndarray:
    """(H, W, 3) uint8 -> the same photo grey: each pixel's Rec. 601 luma in all three channels."""
    luma = np.asarray(image, np.float64) @ np.array([0.299, 0.587, 0.114])
    return np.repeat(np.clip(np.round(luma), 0, 255).astype(np.uint8)[..., None], 3, -1)


def saturated(image) -> np.ndarray:
    """(H, W, 3) uint8 -> over-exposed: x :data:`OVEREXPOSURE`, clipped at 255."""
    return np.clip(np.asarray(image, np.float64) * OVEREXPOSURE, 0, 255).astype(np.uint8)


def shadow_region(points, shape) -> np.ndarray:
    """(H, W) bool: the image-left half plane of the line through the nose bridge (iBUG 27)
    and the nose's bottom (33) of ``points`` (68, 2) px: a shadow cast on half the face."""
    (x0, y0), (x1, y1) = points[27], points[33]
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]] + 0.5
    return (xs - x0) * (y1 - y0) - (ys - y0) * (x1 - x0) < 0


def hard_shadow(image, points) -> np.ndarray:
    """A sharp-edged shadow over the image-left half of the face (:func:`shadow_region`),
    x :data:`SHADOW_GAIN`."""
    out = np.asarray(image, np.float64)
    out[shadow_region(points, out.shape[:2])] *= SHADOW_GAIN
    return np.round(out).astype(np.uint8)


def _ellipse(shape, centre, axes) -> np.ndarray:
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]] + 0.5
    return ((xs - centre[0]) / axes[0]) ** 2 + ((ys - centre[1]) / axes[1]) ** 2 <= 1


def hand_region(points, shape) -> np.ndarray:
    """(H, W) bool: an ellipse over the mouth and the image-right cheek, centred on the
    mouth's image-right corner (iBUG 54), 0.9 x 0.6 times the distance between the eyes' outer
    corners (36, 45); the inner points only, which every detector and model has."""
    width = np.linalg.norm(points[45] - points[36])
    return _ellipse(shape, points[54], (0.45 * width, 0.3 * width))


def skin_colour(image, points) -> np.ndarray:
    """(3,) the median colour of the cheeks and nose: the photo's pixels between the eyes'
    lower lids and the mouth, and between the eyes' outer corners (iBUG 36, 45)."""
    H, W = image.shape[:2]
    top, bottom = points[[40, 41, 46, 47], 1].max(), points[48:60, 1].min()
    left, right = points[36, 0], points[45, 0]
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    cheeks = (ys > top) & (ys < bottom) & (xs > left) & (xs < right)
    return np.median(np.asarray(image)[cheeks], 0)


def hand(image, points, seed: int = SEED) -> np.ndarray:
    """A hand over the mouth and cheek (:func:`hand_region`) coloured with the photo's own skin
    (:func:`skin_colour`), so that the mask's colour test cannot tell it from the face: a
    vertical shading ramp (0.85-1.05) and a seeded noise of 3 grey levels."""
    out = np.asarray(image, np.float64).copy()
    region = hand_region(points, out.shape[:2])
    ys = np.nonzero(region)[0]
    ramp = 0.85 + 0.2 * (ys - ys.min()) / max(np.ptp(ys), 1)
    noise = np.random.default_rng(seed).normal(0, 3.0, (len(ys), 3))
    out[region] = skin_colour(image, points) * ramp[:, None] + noise
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def glasses_region(points, shape) -> np.ndarray:
    """(H, W) bool: two ellipses over the eyes (iBUG 36-41 and 42-47), each 1.5 eye widths
    wide and one high."""
    region = np.zeros(shape, bool)
    for eye in (points[36:42], points[42:48]):
        w = np.linalg.norm(eye[3] - eye[0])
        region |= _ellipse(shape, eye.mean(0), (0.75 * w, 0.5 * w))
    return region


def sunglasses(image, points) -> np.ndarray:
    """Dark lenses over the eyes (:func:`glasses_region`), RGB (25, 25, 30): darker than any
    skin but above the mask's black clip (:data:`morphable.refinement.mask.CLIP_LOW`)."""
    out = np.asarray(image).copy()
    out[glasses_region(points, out.shape[:2])] = (25, 25, 30)
    return out


def write_png16(path, image) -> Path:
    """Write (H, W, 3) uint8 as a 16-bit RGB PNG (each value x 257, so that 0-255 maps onto
    0-65535; PIL writes no 16-bit colour PNG)."""
    a = np.asarray(image, np.uint16) * 257
    H, W = a.shape[:2]
    rows = b"".join(b"\0" + row.astype(">u2").tobytes() for row in a)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", W, H, 16, 2, 0, 0, 0)       # 16 bits, RGB
    Path(path).write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
                           + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
    return Path(path)


VARIANTS = {
    "as is": (lambda im, pts: im, "the photo itself as a PNG: the variants' reference"),
    "grey": (lambda im, pts: grey(im), "RGB equal channels, the photo's luma"),
    "16-bit PNG": (lambda im, pts: im, "the photo as a 16-bit RGB PNG (x 257), read back by fit"),
    "saturated x3": (lambda im, pts: saturated(im), "over-exposed: x3, clipped at 255"),
    "hard shadow x0.3": (hard_shadow, "a sharp-edged shadow over the image-left half, x0.3"),
    "hand (skin colour)": (hand, "an ellipse of the photo's own skin colour over mouth and cheek"),
    "sunglasses": (sunglasses, "dark ellipses, RGB (25, 25, 30), over the eyes"),
}
"""Hard-case makers, each with its one-line description: (photo (H, W, 3) uint8, its 68
points) -> (H, W, 3) uint8. The 16-bit variant is the photo itself, written by
:func:`write_png16`."""
PAIR = "saturated x3, 2nd of 2 frames"
"""The case of several frames, one of which the mask leaves nearly empty."""
REGIONS = {"hard shadow x0.3": shadow_region, "hand (skin colour)": hand_region,
           "sunglasses": glasses_region}
"""The variants that hide part of the face, and the pixels they change."""


def _finite(value) -> bool:
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return all(_finite(v) for v in value)
    return not isinstance(value, float) or bool(np.isfinite(value))


def fit_case(photos, pts, steps: int, folder: Path, region=None) -> tuple:
    """Fit ``photos`` (paths) as ``morphable fit PHOTOS [--landmarks PTS...] --refine
    photometric --steps STEPS --out-mesh ... --overlay ... --overlay-mask`` does
    (:func:`morphable.fit_images`, :meth:`~morphable.pipeline.ImageFit.write`), one identity for
    all; the figures are the last photo's.

    Returns
    -------
    (figures, picture): the case's figures (mask coverage, fallback, landmark RMSE before and
    after (px), photometric residual, refinement time (s), NaN in the outputs, written mesh
    finite; ``occluder_left_out``: the share of the face pixels in ``region`` (H, W) that the
    mask weighs under 0.5) and the photo crop with the mask drawn over it ((h, w, 3) uint8),
    or ({"error": one line}, None) when the fit stops.
    """
    from morphable import fit_images
    from morphable.io.mesh import read_mesh
    from morphable.overlay import draw_overlay
    from morphable.pipeline.outputs import mask_in_photo, paint_mask

    try:
        result = fit_images([str(p) for p in photos], pts and [str(p) for p in pts],
                            refine="photometric", refine_options={"steps": steps})
    except (InputError, FitError) as e:
        return {"error": str(e).replace(f"{folder}/", "")}, None
    run, fit, state = result.report["refine"][-1], result.fit, result.refinements[-1]
    mesh = folder / "fit.obj"
    result.write(mesh=mesh, report=folder / "fit.json")
    try:
        mesh_finite = bool(np.isfinite(read_mesh(mesh).vertices).all())
    except InputError:           # read_mesh refuses NaN vertices
        mesh_finite = False
    arrays = [fit.identity, fit.expression, state.mask, state.rendered] + [c.rotation for c in fit.cameras]
    figures = {"mask_coverage": run["mask_coverage"], "fallback": run["fallback"],
               "landmark_rmse_px_before": round(run["landmark_rmse_px_before"], 3),
               "landmark_rmse_px_after": round(run["landmark_rmse_px_after"], 3),
               "photometric_residual": round(run["photometric_residual"], 4),
               "refine_s": run["runtime_s"],
               "nan": not (_finite(run) and all(np.isfinite(np.asarray(a, np.float64)).all() for a in arrays)),
               "mesh_finite": mesh_finite}
    image = result.images()[-1]
    if region is not None:
        face, kept = mask_in_photo(state, region.shape)
        on = (face > 0) & region
        figures["occluder_left_out"] = round(float((kept[on] < 0.5).mean()), 3) if on.any() else None
    return figures, draw_overlay(paint_mask(image, state), fit, fit.n_frames - 1, mesh=None,
                                 landmarks=False, crop=0.1)


def face_crop(image, points, margin: float = 0.3) -> np.ndarray:
    """(h, w, 3): ``image`` cut to the box of ``points`` (N, 2) px widened by ``margin`` of its
    size (the tile of a case whose fit stopped)."""
    lo, hi = points.min(0), points.max(0)
    x0, y0 = np.maximum(np.floor(lo - margin * (hi - lo)), 0).astype(int)
    x1, y1 = np.ceil(hi + margin * (hi - lo)).astype(int)
    return np.asarray(image)[y0:y1, x0:x1]


def contact_sheet(tiles, labels, path, height: int = 260, columns: int = 5) -> Path:
    """The tiles ((h, w, 3) uint8) scaled to ``height`` px, each labelled, ``columns`` to a
    row, written as JPEG."""
    from PIL import Image

    from morphable.overlay import label_faces

    scaled = []
    for tile in tiles:
        im = Image.fromarray(tile)
        scaled.append(np.asarray(im.resize((round(im.width * height / im.height), height), Image.LANCZOS)))
    width = max(t.shape[1] for t in scaled)
    rows = -(-len(scaled) // columns)
    sheet = np.full((rows * height, columns * width, 3), 255, np.uint8)
    for k, (tile, text) in enumerate(zip(scaled, labels)):
        r, c = divmod(k, columns)
        tile = label_faces(tile, [[4, 18, tile.shape[1], height]], [text])
        sheet[r * height:(r + 1) * height, c * width:c * width + tile.shape[1]] = tile
    Image.fromarray(sheet).save(path, format="JPEG", quality=85)
    return Path(path)


def evaluate(steps: int = 100, root: Path | None = None) -> tuple[dict, list, list]:
    """Fit every case: the real :data:`PHOTOS`, then the :data:`VARIANTS` of :data:`BASE` ->
    (report, tiles, labels)."""
    from PIL import Image

    from morphable.detection import detect
    from morphable.detection.images import read_image
    from morphable.io.landmark_files import write_pts

    folder = (root or data_root()) / LONDON
    if not (folder / BASE).is_file():
        raise InputError(f"{folder / BASE}: the London set is not there (see docs/photometric_results.md)")
    cases, tiles = {}, []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in PHOTOS:
            figures, tile = fit_case([folder / name], None, steps, tmp)
            cases[name] = {"why": PHOTOS[name], **figures}
            tiles.append(read_image(folder / name) if tile is None else tile)
        base = read_image(folder / BASE)
        points = detect(base).ibug68
        pts = tmp / "base.pts"
        write_pts(pts, points)
        for name, (make, why) in VARIANTS.items():
            photo = tmp / f"{name.split()[0]}.png"
            image = make(base, points)
            if name == "16-bit PNG":
                write_png16(photo, image)
            else:
                Image.fromarray(image).save(photo)
            region = REGIONS[name](points, base.shape[:2]) if name in REGIONS else None
            figures, tile = fit_case([photo], [pts], steps, tmp, region)
            cases[name] = {"why": why, **figures}
            tiles.append(face_crop(image, points) if tile is None else tile)
        # several frames: the one the mask leaves nearly empty keeps its landmark fit
        figures, tile = fit_case([tmp / "as.png", tmp / "saturated.png"], [pts, pts], steps, tmp)
        cases[PAIR] = {"why": "the saturated photo fitted together with the photo as is", **figures}
        tiles.append(face_crop(saturated(base), points) if tile is None else tile)
    labels = [f"{name}\n" + ("stopped: mask under 5 %" if "error" in c else
                             f"mask {100 * c['mask_coverage']:.0f} %, res {c['photometric_residual']:.3f}")
              for name, c in cases.items()]
    return {"steps": steps, "base": BASE, "cases": cases}, tiles, labels


@one_line_errors("evaluation.photometric_stability")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=Path("docs/img/photometric_stability.jpg"),
                   help="the contact sheet (.jpg)")
    p.add_argument("--report", type=Path, default=Path("reports/photometric_stability.json"))
    p.add_argument("--steps", type=int, default=100, help="refinement steps (default 100, as fit's)")
    p.add_argument("--data", type=Path, default=None,
                   help="shared data folder (default: $MORPHABLE_DATA or ../shared/data)")
    add_verbosity_arguments(p)
    a = p.parse_args(argv)
    configure(verbosity(a))
    for path in (a.out, a.report):
        if not path.resolve().parent.is_dir():
            raise InputError(f"{path}: folder {path.resolve().parent} does not exist")
    report, tiles, labels = evaluate(a.steps, a.data)
    contact_sheet(tiles, labels, a.out)
    write_json(a.report, report, indent=2)
    for name, c in report["cases"].items():
        print(name, json.dumps({k: v for k, v in c.items() if k != "why"}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
