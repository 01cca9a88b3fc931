"""Landmark packs (format ``landmarks-1``, docs/landmark_packs.md): read them, draw a grid of
their crops with labels, and write a compact copy that travels to a GPU machine.

``python -m neural.faces.packs grid PACK --out grid.png [--n 24] [--seed 0]``
``python -m neural.faces.packs mapping --data ../shared/data --out mapping.png``
``python -m neural.faces.packs compact PACK --out FILE.npz [--split train,validation]
[--sources london] [--resolution 128] [--jpeg-quality 85] [--max-mib 20]``

A compact copy is one ``.npz``: the crops as JPEG (one byte string per face, ``jpeg``
(total,) uint8 with ``jpeg_offsets`` (n + 1,)), the labels as in the pack (points float16 in
crop px, ``labelled``/``visible`` bit-packed), the per-face fields, ``sources`` (JSON text);
:func:`load_pack` reads either form into the same arrays.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors

__all__ = ["load_pack", "grid", "compact", "mapping_picture", "main"]


def load_pack(path, splits=None) -> dict:
    """A landmark pack folder (or its compact ``.npz``) -> dict of arrays concatenated over
    its shards (keys of the format; ``sources`` the list of pack.json's sources), the faces of
    ``splits`` (None: all; e.g. ``(0, 1)``). InputError when ``path`` holds no pack."""
    from .shards import shard_paths

    path = Path(path)
    if path.is_file():
        return _load_compact(path, splits)
    shards = shard_paths(path)
    if not (path / "pack.json").is_file() or not shards:
        raise InputError(f"{path}: no landmark pack (pack.json and shard_*.npz)")
    manifest = json.loads((path / "pack.json").read_text())
    parts = []
    for p in shards:
        with np.load(p, allow_pickle=False) as z:
            keep = np.ones(len(z["split"]), bool) if splits is None else np.isin(z["split"], splits)
            parts.append({k: z[k][keep] for k in z.files if not k.startswith("failed_")})
    out = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    out["sources"] = [s["name"] for s in manifest["sources"]]
    return out


def _load_compact(path: Path, splits) -> dict:
    import io

    from PIL import Image

    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: not a compact landmark pack ({e})") from None
    n = len(d["split"])
    keep = np.ones(n, bool) if splits is None else np.isin(d["split"], splits)
    off = d.pop("jpeg_offsets")
    jpeg = d.pop("jpeg")
    P = d.pop("n_points")
    images = [np.asarray(Image.open(io.BytesIO(jpeg[off[i]:off[i + 1]].tobytes())).convert("RGB"))
              for i in np.flatnonzero(keep)]
    d["image"] = np.stack(images) if images else np.zeros((0, 1, 1, 3), np.uint8)
    for k in ("labelled", "visible"):
        d[k] = np.unpackbits(d[k], axis=1, count=int(P)).astype(bool)
    d["points"] = d["points"].astype(np.float32)
    sources = json.loads(str(d.pop("sources")))
    out = {k: v[keep] for k, v in d.items() if k != "image"}
    out["image"] = d["image"]
    out["sources"] = sources
    return out


def grid(pack, out, n: int = 24, seed: int = 0, columns: int = 8, cell: int = 160,
         splits=None) -> Path:
    """A PNG of ``n`` random faces of ``pack`` (folder or compact file), ``columns`` per row,
    each crop at ``cell`` px: visible labels green, labelled hidden ones red, the face box
    blue. Returns ``out``."""
    from PIL import Image, ImageDraw

    from morphable.io.atomic import atomic_path

    d = load_pack(pack, splits)
    if not len(d["split"]):
        raise InputError(f"{pack}: no faces to draw")
    pick = np.sort(np.random.default_rng(seed).choice(len(d["split"]), min(n, len(d["split"])),
                                                      replace=False))
    rows = -(-len(pick) // columns)
    sheet = Image.new("RGB", (columns * cell, rows * cell))
    for j, i in enumerate(pick):
        R = d["image"].shape[1]
        s = cell / R
        im = Image.fromarray(d["image"][i]).resize((cell, cell), Image.Resampling.BILINEAR)
        dr = ImageDraw.Draw(im)
        b = (d["box"][i] + 0.5) * s - 0.5
        dr.rectangle(list(b), outline=(60, 120, 255))
        for (x, y), lab, vis in zip(d["points"][i], d["labelled"][i], d["visible"][i]):
            if lab:
                x, y = (x + 0.5) * s - 0.5, (y + 0.5) * s - 0.5
                dr.ellipse([x - 1, y - 1, x + 1, y + 1], fill=(0, 255, 0) if vis else (255, 0, 0))
        sheet.paste(im, ((j % columns) * cell, (j // columns) * cell))
    out = Path(out)
    with atomic_path(out) as tmp:
        sheet.save(tmp, format="PNG")
    return out


def compact(pack, out, splits=None, sources=None, resolution: int | None = None,
            jpeg_quality: int = 85, max_mib: float | None = None, seed: int = 0) -> dict:
    """Write a compact copy of ``pack`` (faces of ``splits``, of the named ``sources``), crops
    resized to ``resolution`` (labels scaled with them) and JPEG-encoded; with ``max_mib``, a
    random subset (fixed by ``seed``) that fits. Returns {faces, mib, faces_in_pack}."""
    import io

    from PIL import Image

    from morphable.io.atomic import atomic_path

    d = load_pack(pack, splits)
    keep = np.ones(len(d["split"]), bool)
    if sources:
        idx = [d["sources"].index(s) for s in sources if s in d["sources"]]
        keep &= np.isin(d["source"], idx)
    order = np.random.default_rng(seed).permutation(np.flatnonzero(keep))
    R0 = d["image"].shape[1]
    R = int(resolution or R0)
    s = R / R0
    taken, total = {}, 0
    budget = None if max_mib is None else max_mib * 2 ** 20
    for i in order:
        im = Image.fromarray(d["image"][i])
        if R != R0:
            im = im.resize((R, R), Image.Resampling.BILINEAR)
        buf = io.BytesIO()
        im.save(buf, format="JPEG", quality=int(jpeg_quality))
        b = np.frombuffer(buf.getvalue(), np.uint8)
        # labels take ~ 546 * 4.25 bytes a face before compression
        if budget is not None and total + len(b) + 2400 > budget:
            break
        taken[int(i)] = b
        total += len(b) + 2400
    sel = np.array(sorted(taken), dtype=np.int64)
    blobs = [taken[i] for i in sel]
    arrays = {k: d[k][sel] for k in ("box", "convention", "person", "split", "source", "yaw_deg",
                                      "name", "residual_px")}
    arrays["box"] = ((arrays["box"] + 0.5) * s - 0.5).astype(np.float32)
    arrays["points"] = ((d["points"][sel] + 0.5) * s - 0.5).astype(np.float16)
    arrays["labelled"] = np.packbits(d["labelled"][sel], axis=1)
    arrays["visible"] = np.packbits(d["visible"][sel], axis=1)
    arrays["n_points"] = np.int64(d["labelled"].shape[1])
    arrays["jpeg"] = np.concatenate(blobs) if blobs else np.zeros(0, np.uint8)
    arrays["jpeg_offsets"] = np.concatenate([[0], np.cumsum([len(b) for b in blobs])]).astype(np.int64)
    arrays["sources"] = np.array(json.dumps(d["sources"]))
    out = Path(out)
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    return {"faces": int(len(sel)), "faces_in_pack": int(keep.sum()),
            "mib": round(out.stat().st_size / 2 ** 20, 2)}


def mapping_picture(data, out, aflw_index: int = 0, london_index: int = 0, cell: int = 480) -> Path:
    """The left/right check of the mappings (:mod:`neural.faces.annotations`): an AFLW crop and a
    London photo side by side, each annotated point drawn in the colour of its row's side on
    SFM's mean face (blue: the image's left, red: its right, white: the midline within 2 mm)
    and named by its row (``36`` iBUG, ``m468`` face mesh). Returns ``out``."""
    from PIL import Image, ImageDraw

    import morphable
    from morphable.detection.images import read_image
    from morphable.io.atomic import atomic_path

    from .annotations import crop_face, model_points, set_items, to_crop
    from .points import IBUG_START

    x = model_points(morphable.load_model("sfm"), morphable.load_model("sfm").mean)[:, 0]
    panels = []
    for name, index in (("aflw", aflw_index), ("london", london_index)):
        item = set_items(data, name)[index]
        # the points' bounding square grown by 1.6, drawn at ``cell`` px
        P = item["points"][np.isfinite(item["points"]).all(1)]
        c, half = (P.min(0) + P.max(0)) / 2, 0.8 * np.ptp(P, axis=0).max()
        crop, tr = crop_face(read_image(item["path"]), np.r_[c - half, c + half], cell, scale=1.0)
        img = Image.fromarray(crop)
        dr = ImageDraw.Draw(img)
        for row, (px, py) in zip(item["rows"], item["points"]):
            if not np.isfinite([px, py]).all():
                continue
            # SFM's model x grows to the subject's left, the image's right
            col = (255, 255, 255) if abs(x[row]) < 2 else (80, 140, 255) if x[row] < 0 else (255, 70, 70)
            u, v = to_crop([px, py], tr)
            dr.ellipse([u - 3, v - 3, u + 3, v + 3], fill=col)
            label = str(row - IBUG_START) if row >= IBUG_START else f"m{row}"
            dr.text((u + 4, v - 5), label, fill=col)
        panels.append(img)
    sheet = Image.new("RGB", (sum(p.width for p in panels), max(p.height for p in panels)))
    for i, p in enumerate(panels):
        sheet.paste(p, (sum(q.width for q in panels[:i]), 0))
    out = Path(out)
    with atomic_path(out) as tmp:
        sheet.save(tmp, format="PNG")
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m neural.faces.packs", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    g = sub.add_parser("grid", help="a PNG of random crops with their labels")
    g.add_argument("pack")
    g.add_argument("--out", required=True)
    g.add_argument("--n", type=int, default=24)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--columns", type=int, default=8)
    m = sub.add_parser("mapping", help="the left/right check of the AFLW and London mappings")
    m.add_argument("--data", default="../shared/data")
    m.add_argument("--out", required=True)
    m.add_argument("--aflw-index", type=int, default=0)
    m.add_argument("--london-index", type=int, default=0)
    c = sub.add_parser("compact", help="a JPEG-compressed copy (or subset) for a GPU machine")
    c.add_argument("pack")
    c.add_argument("--out", required=True)
    c.add_argument("--split", default=None, help="e.g. train,validation (default: all)")
    c.add_argument("--sources", default=None, help="e.g. london,aflw (default: all)")
    c.add_argument("--resolution", type=int, default=None)
    c.add_argument("--jpeg-quality", type=int, default=85)
    c.add_argument("--max-mib", type=float, default=None)
    return p


_SPLITS = {"train": 0, "validation": 1, "test": 2}


@one_line_errors("neural.faces.packs")
def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "grid":
        print(grid(args.pack, args.out, args.n, args.seed, args.columns))
        return 0
    if args.command == "mapping":
        print(mapping_picture(args.data, args.out, args.aflw_index, args.london_index))
        return 0
    splits = None
    if args.split:
        try:
            splits = [_SPLITS[s.strip()] for s in args.split.split(",")]
        except KeyError:
            raise InputError(f"--split: expected train, validation or test, got {args.split!r}") from None
    sources = args.sources.split(",") if args.sources else None
    print(json.dumps(compact(args.pack, args.out, splits, sources, args.resolution,
                             args.jpeg_quality, args.max_mib)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
