"""Build a synthetic training pack: labelled faces of :class:`neural.faces.synthetic.SyntheticEngine`.

``python -m neural.faces.build_synthetic --out DIR --n N --resolution R --seed S [--model sfm|ict]
[--workers W] [--data ../shared/data] [--shard-size 64] [--textures 16] [--backgrounds 300w|none]``

The pack is a folder:

- ``pack.json``: the settings (a rerun with other settings is refused), the material's
  sources and licences, and after each run the counts, failures and times;
- ``shard_00000.npz`` ...: ``--shard-size`` faces each (the last may hold fewer), written
  atomically: ``image`` (n, R, R, 3) uint8; ``points68`` (n, 68, 2), ``points478`` (n, 478, 2)
  float32 px (3D convention); ``visible68``, ``visible478``, ``occluded68``, ``occluded478``
  bool; ``defined68`` (68,) bool; ``identity`` (n, K), ``expression`` (n, E); ``pose`` (n, 3)
  yaw, pitch, roll degrees; ``rotation`` (n, 3, 3), ``translation`` (n, 3) mm, ``focal`` (n,)
  px, ``principal`` (n, 2) px, ``distance_mm`` (n,); ``light`` (n,) index into
  :data:`neural.faces.synthetic.LIGHTS`; ``texture`` (n,) index into the pack's texture list (-1:
  procedural albedo); ``background`` (n,) (-1: procedural); ``seed`` (n,) each face's seed;
  ``failed`` the number of faces that failed to render;
- ``textures_<model>_<size>.npz``: the UV textures extracted from London photos (the cache of
  :func:`neural.faces.synthetic.texture_bank`).

Face ``k`` of the pack is drawn from ``numpy.random.default_rng([seed, k])``: a shard's faces
do not depend on the worker count or on which shards were built before. A rerun skips the
shards already written, so a killed build loses only the shards in progress.

Material: textures from the London set's neutral photos (CC BY 4.0); backgrounds cut from
300-W photos away from their annotated face (**research use only**; ``--backgrounds none``
for procedural backgrounds).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors

__all__ = ["build", "load_pack", "shard_faces", "main"]

log = logging.getLogger("neural.faces.build_synthetic")

_FORMAT = 1
_ENGINE = {}  # per worker process: the engine of the pack being built


def _settings(n, resolution, seed, model, shard_size, textures, texture_size, backgrounds) -> dict:
    return {"format": _FORMAT, "n": int(n), "resolution": int(resolution), "seed": int(seed),
            "model": str(model), "shard_size": int(shard_size), "textures": int(textures),
            "texture_size": int(texture_size), "backgrounds": str(backgrounds)}


def _check(data: Path, out: Path, settings: dict) -> None:
    """Everything that can fail before anything is written."""
    from .shards import check_out
    from .synthetic import london_photos, w300_photos

    s = settings
    if s["n"] < 1:
        raise InputError(f"--n must be at least 1, got {s['n']}")
    if s["resolution"] < 16:
        raise InputError(f"--resolution must be at least 16, got {s['resolution']}")
    if s["shard_size"] < 1:
        raise InputError(f"--shard-size must be at least 1, got {s['shard_size']}")
    if s["backgrounds"] not in ("300w", "none"):
        raise InputError(f"--backgrounds: expected 300w or none, got {s['backgrounds']!r}")
    if s["textures"] or s["backgrounds"] != "none":
        if not data.is_dir():
            raise InputError(f"{data}: data folder not found")
        if s["textures"] and not london_photos(data):
            raise InputError(f"{data}: no London photos under it (faces/frl_london/neutral_front)")
        if s["backgrounds"] == "300w" and not w300_photos(data):
            raise InputError(f"{data}: no 300-W photos with .pts under it (images/300w)")
    check_out(out, settings)


def _init_worker(model, resolution, tex_path, backgrounds):
    from .synthetic import SyntheticEngine

    textures = ()
    if tex_path is not None:
        with np.load(tex_path, allow_pickle=False) as z:
            textures = z["textures"]
    _ENGINE["engine"] = SyntheticEngine(model, resolution, textures=textures, backgrounds=backgrounds)


def shard_faces(engine, seed: int, first: int, count: int) -> dict:
    """Faces ``first`` .. ``first + count - 1`` of a pack of seed ``seed`` -> the shard's
    arrays (see the module's docstring)."""
    from morphable.errors import FitError

    from .synthetic import LIGHTS

    keys = ("image", "points68", "points478", "visible68", "visible478", "occluded68",
            "occluded478", "identity", "expression", "pose", "rotation", "translation", "focal",
            "principal", "distance_mm", "light", "texture", "background", "seed")
    rows = {k: [] for k in keys}
    failed = 0
    for k in range(first, first + count):
        try:
            f = engine.sample(np.random.default_rng([seed, k]))
        except (FitError, InputError) as e:
            log.warning("face %d: %s", k, str(e).splitlines()[0])
            failed += 1
            continue
        p, cam = f["params"], f["camera"]
        vals = {"identity": p["identity"], "expression": p["expression"], "pose": p["pose"],
                "rotation": cam.rotation, "translation": cam.translation, "focal": cam.focal,
                "principal": cam.principal, "distance_mm": p["distance_mm"],
                "light": LIGHTS.index(p["light"]), "texture": p["texture"],
                "background": p["background_id"], "seed": k}
        for key in keys:
            rows[key].append(f[key] if key in f else vals[key])
    R = engine.resolution
    shapes = {"image": (R, R, 3), "points68": (68, 2), "points478": (478, 2)}
    out = {}
    for key in keys:
        if rows[key]:
            out[key] = np.stack(rows[key])
        else:
            out[key] = np.zeros((0,) + shapes.get(key, ()))
    for key in ("identity", "expression", "pose", "rotation", "translation", "focal",
                "principal", "distance_mm"):
        out[key] = out[key].astype(np.float32)
    out["defined68"] = engine.schemes["68"].defined
    out["failed"] = np.int64(failed)
    return out


def _build_shard(job):
    from .shards import write_shard

    path, seed, first, count = job
    arrays = shard_faces(_ENGINE["engine"], seed, first, count)
    write_shard(path, arrays)
    return int(len(arrays["image"])), int(arrays["failed"])


def build(out, n: int, resolution: int = 128, seed: int = 0, model: str = "sfm", workers: int = 1,
          data="../shared/data", shard_size: int = 64, textures: int = 16, texture_size: int = 256,
          backgrounds: str = "300w") -> dict:
    """Build (or finish) the pack at ``out``; returns the report written to ``pack.json``
    (``report``: faces, failures, shards built now and skipped, seconds)."""
    from .shards import pending_shards, run_shards, shard_paths, write_manifest
    from .synthetic import background_bank, london_photos, texture_bank, w300_photos

    out, data = Path(out), Path(data)
    settings = _settings(n, resolution, seed, model, shard_size, textures, texture_size, backgrounds)
    _check(data, out, settings)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    manifest = {"settings": settings,
                "material": {"textures": "London set neutral front photos, CC BY 4.0 "
                             "(faces/frl_london)" if textures else "procedural albedo only",
                             "backgrounds": "300-W photos, research use only (images/300w)"
                             if backgrounds == "300w" else "procedural"}}
    tex_path = None
    if textures:
        tex_path = out / f"textures_{model}_{texture_size}.npz"
        tex, names, tex_failures = texture_bank(london_photos(data)[:textures], model, texture_size,
                                                cache=tex_path)
        manifest["texture_names"] = [str(x) for x in names]
        manifest["texture_failures"] = tex_failures
        if not len(tex):
            tex_path = None
    t_tex = time.perf_counter() - t0
    bgs = (background_bank(w300_photos(data), side=resolution, per_photo=1, seed=seed)
           if backgrounds == "300w" else ())
    write_manifest(out, manifest)
    pending, skipped = pending_shards(out, n, shard_size)
    jobs = [(path, seed, first, count) for path, first, count in pending]
    t1 = time.perf_counter()
    done, failed = 0, 0
    results = run_shards(jobs, _build_shard, workers, _init_worker,
                         (model, resolution, tex_path, bgs))
    for k, ((count, fail), sec) in enumerate(results):
        done, failed = done + count, failed + fail
        log.info("shard %d / %d: %d faces, %d failed, %.1f s", k + 1, len(jobs), count, fail, sec)
    t_render = time.perf_counter() - t1
    total = sum(int(np.load(p)["image"].shape[0]) for p in shard_paths(out))
    manifest["report"] = {"faces": total, "faces_built_now": done, "failed_now": failed,
                          "shards_built_now": len(jobs), "shards_skipped": skipped,
                          "texture_seconds": round(t_tex, 1), "render_seconds": round(t_render, 1),
                          "faces_per_second": round(done / t_render, 2) if done and t_render else None,
                          "workers": int(workers)}
    write_manifest(out, manifest)
    return manifest


def load_pack(path) -> dict:
    """All shards of a pack folder, concatenated -> dict of arrays (see the module's
    docstring); ``defined68`` (68,) once. InputError when the folder has no pack."""
    from .shards import shard_paths

    path = Path(path)
    shards = shard_paths(path)
    if not (path / "pack.json").is_file() or not shards:
        raise InputError(f"{path}: no synthetic pack (pack.json and shard_*.npz)")
    parts = [dict(np.load(p, allow_pickle=False)) for p in shards]
    out = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]
           if k not in ("defined68", "failed")}
    out["defined68"] = parts[0]["defined68"]
    out["failed"] = int(sum(int(q["failed"]) for q in parts))
    return out


def build_parser() -> argparse.ArgumentParser:
    from morphable.logs import add_verbosity_arguments

    p = argparse.ArgumentParser(prog="python -m neural.faces.build_synthetic",
                                description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="the pack folder (made; a rerun finishes it)")
    p.add_argument("--n", type=int, required=True, help="number of faces")
    p.add_argument("--resolution", type=int, default=128, help="image side, px")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--model", default="sfm", help="sfm or ict (or a model path)")
    p.add_argument("--workers", type=int, default=1, help="processes rendering shards")
    p.add_argument("--data", default="../shared/data", help="the shared data folder")
    p.add_argument("--shard-size", type=int, default=64, help="faces per shard file")
    p.add_argument("--textures", type=int, default=16,
                   help="photo textures from the first N London photos (0: procedural albedo)")
    p.add_argument("--texture-size", type=int, default=256, help="texels per side")
    p.add_argument("--backgrounds", default="300w", help="300w (research use only) or none")
    add_verbosity_arguments(p)
    return p


@one_line_errors("neural.faces.build_synthetic")
def main(argv=None) -> int:
    from morphable.logs import configure, verbosity

    args = build_parser().parse_args(argv)
    configure(verbosity(args))
    m = build(args.out, args.n, args.resolution, args.seed, args.model, args.workers, args.data,
              args.shard_size, args.textures, args.texture_size, args.backgrounds)
    print(json.dumps(m["report"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
