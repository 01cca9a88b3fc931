"""How well a photo texture reproduces its photo: the textured fit rendered with its own camera
and no light (``render --light none``) against the photo, over the face pixels the rendering
covers (the textured triangles seen from the camera). PSNR (dB, colours in [0, 1]) and mean
absolute error (0-255 grey levels), and the extraction's run time per texture.

Sets: ``image_0010`` (its 68 ground-truth points), the first ``--n`` London neutral front photos
(CC BY 4.0) and the first ``--n`` AFLW2000-3D photos (research use only), these two with
landmarks detected by the face mesh; ``london-pairs``: the neutral and the smiling photo of each
of the first ``--n`` London people fitted together (shared identity), the neutral photo
rendered with the texture of both frames blended, of the neutral frame alone and of the smiling
frame alone; ``sizes``: image_0010 at several texture sizes (error against run time). Command::

    python -m evaluation.texture_check --n 20 --report reports/texture_check.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from morphable.errors import MorphableError, one_line_errors

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SETS = ("image_0010", "london", "aflw2000", "london-pairs", "sizes")


def compare(result, frame: int, texture, photo):
    """(PSNR dB, MAE grey levels, face pixels) of ``texture`` drawn on ``frame`` of the fit with
    its camera, unlit, against ``photo`` (H, W, 3) float in [0, 1]."""
    from morphable.raster import render, visibility

    m, cam = result.model, result.cameras[frame]
    v = result.vertices(frame, dtype=np.float64)
    vis = visibility(v, m.triangles, cam)
    _, _, textured = texture_layout_of(m, texture)
    face = np.zeros(vis.shape, dtype=bool)
    face.ravel()[vis.pixels] = textured[np.take(vis.triangle_id.ravel(), vis.pixels)]
    image = render(v, m.triangles, cam, texture=(texture.uv, texture.triangle_uv, texture.image),
                   light=np.eye(9)[0], vis=vis)
    d = (image - photo)[face]
    mse = float((d ** 2).mean())
    return 10 * np.log10(1.0 / mse), 255 * float(np.abs(d).mean()), int(face.sum())


def texture_layout_of(model, texture):
    from morphable.texture import texture_layout

    return texture_layout(model, texture.image.shape[0])


def one_photo(path, landmarks=None, size=512, model="sfm"):
    """Fit, texture and compare one photo -> a row dict."""
    from morphable.detection import read_image
    from morphable.pipeline import fit_images
    from morphable.texture import extract_texture

    res = fit_images(path, landmarks, model=model, landmark_detector="facemesh").fit
    extract_texture(res, [path], size=size)            # warm-up: the layout tables are cached
    tex = extract_texture(res, [path], size=size)
    photo = read_image(path).astype(np.float64) / 255
    psnr, mae, n = compare(res, 0, tex, photo)
    return {"image": Path(path).name, "psnr_db": psnr, "mae": mae, "face_px": n,
            "ms": tex.runtime_ms, "observed": float(tex.observed[tex.layout].mean())}


def pair(neutral, smiling, size=512, model="sfm"):
    """London neutral + smiling photos of one person fitted together; the neutral frame drawn
    with the blended texture and with each frame's own."""
    from morphable.detection import read_image
    from morphable.pipeline import fit_images
    from morphable.texture import texture_from_views

    res = fit_images([neutral, smiling], model=model, landmark_detector="facemesh").fit
    photo = read_image(neutral).astype(np.float64) / 255
    verts = res.vertices(dtype=np.float64)
    row = {"person": Path(neutral).stem.split("_")[0]}
    for name, frames in (("blended", [0, 1]), ("neutral only", [0]), ("smiling only", [1])):
        tex = texture_from_views(res.model, verts[frames], [res.cameras[i] for i in frames],
                                 [[neutral, smiling][i] for i in frames], size=size)
        psnr, mae, _ = compare(res, 0, tex, photo)
        row[name] = {"psnr_db": psnr, "mae": mae, "ms": tex.runtime_ms,
                     "observed": float(tex.observed[tex.layout].mean())}
    return row


def summary(rows, key=None):
    get = (lambda r: r) if key is None else (lambda r: r[key])
    out = {}
    for k in ("psnr_db", "mae", "ms", "observed"):
        vals = np.array([get(r)[k] for r in rows])
        out[k] = {"mean": float(vals.mean()), "median": float(np.median(vals))}
    return out


@one_line_errors("python -m evaluation.texture_check")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--set", nargs="+", choices=SETS, default=list(SETS))
    p.add_argument("--n", type=int, default=20, help="photos per set (London, AFLW2000-3D)")
    p.add_argument("--size", type=int, default=512, help="texels per side (default 512)")
    p.add_argument("--model", default="sfm")
    p.add_argument("--report", help="output JSON")
    args = p.parse_args(argv)
    report = {"size": args.size, "model": args.model, "sets": {}}
    images = DATA / "images"
    london = sorted((DATA / "faces/frl_london/neutral_front").glob("*.jpg"))[:args.n]
    for s in args.set:
        t = time.time()
        if s == "image_0010":
            rows = [one_photo(images / "image_0010.png", images / "image_0010.pts", args.size,
                              args.model)]
        elif s == "london":
            rows = [one_photo(p, None, args.size, args.model) for p in london]
        elif s == "aflw2000":
            rows, failed = [], []
            for p in sorted((DATA / "aflw2000").glob("image*.jpg"))[:args.n]:
                try:
                    rows.append(one_photo(p, None, args.size, args.model))
                except MorphableError as e:  # no face found: counted, not measured
                    failed.append(f"{p.name}: {e}")
        elif s == "london-pairs":
            rows = []
            for p in london:
                smiling = DATA / "faces/frl_london/smiling_front" / f"{p.stem.split('_')[0]}_08.jpg"
                if smiling.is_file():
                    rows.append(pair(p, smiling, args.size, args.model))
        else:
            rows = [dict(one_photo(images / "image_0010.png", images / "image_0010.pts", size,
                                   args.model), size=size) for size in (128, 256, 512, 1024)]
        entry = {"rows": rows, "seconds": time.time() - t}
        if s == "aflw2000":
            entry["failed"] = failed
        if s == "london-pairs":
            entry["summary"] = {k: summary(rows, k) for k in ("blended", "neutral only", "smiling only")}
        elif s != "sizes":
            entry["summary"] = summary(rows)
        report["sets"][s] = entry
        print(s, json.dumps(entry.get("summary", rows), indent=1), file=sys.stderr)
    if args.report:
        from morphable.io.atomic import atomic_path

        with atomic_path(args.report) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
