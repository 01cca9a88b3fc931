"""The auxiliary networks N, P, L, R on real faces:
``python -m evaluation.aux_real --data gar_data/real64.npz --report reports/aux_real.json``.

- **Held-out crops of the pack** (:func:`neural.gar.auxnets.metrics.real_metrics`): N's mean angle
  (degrees) to the fits' normal maps on face pixels, P's IoU with the fits' masks, L's error
  (px at the pack's resolution, and NME by the outer-eye-corner distance) against the pack's
  landmarks, separately for ground-truth (300-W) and detected landmarks. The fits' labels are
  not ground truth (a smooth 3DMM face without hair, eyes or mouth interior).
- **AFLW2000-3D** (``--root``/aflw2000, research use only, an evaluation set: never trained
  on): each photo aligned from its ground-truth 68 points (``pts68_3d``;
  :func:`neural.gar.data.align_image`), L's landmarks mapped back to the photo, 68-point NME by
  the ground-truth box sqrt(w h) per ``|yaw|`` bin and their mean (the dataset README's
  protocol, :mod:`evaluation.bench_alignment`); also over the landmarks the SFM defines (the
  ones synthetic training labels). Aligning from the ground truth makes this a test of L on a
  well-framed crop, not of a detector.
- **Synthetic held-out renders** (:func:`neural.gar.auxnets.metrics.synthetic_metrics`, the
  committed networks' validation: identities from the pool of 200 of their run for N, P, L).
- **R on the London set** (CC BY 4.0): same/different-person verification AUC over the
  people whose neutral and smiling photos are both in the pack (aligned crops), for all of
  them and for the held-out ones; the reference is dlib's 128-D face descriptor on the
  original photos (its detector, 5-point chip; ``photos``) and on the pack's crops
  (:func:`evaluation.face_descriptor.aligned_descriptors`, ``crops``). dlib's network was
  not trained on this set, ours may be (fine-tuning uses the pack's train split).

Results that use AFLW, AFLW2000-3D or 300-W are research-only.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from morphable.errors import InputError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity

__all__ = ["aflw2000_landmarks", "london_identity", "evaluate", "main"]


@torch.no_grad()
def aflw2000_landmarks(L, root, resolution: int = 64, n: int | None = None, model: str = "sfm") -> dict:
    """L on AFLW2000-3D (see the module docstring): ``nme68`` and ``nme_defined``, each the
    :func:`evaluation.bench_alignment.yaw_table` of per-photo NME (percent of sqrt(w h)), and
    ``photos``."""
    from PIL import Image

    from morphable import load_model
    from neural.gar.data import alignment, align_image

    from .bench_alignment import box_size, load_aflw2000, nme, yaw_table

    data = load_aflw2000(root, n)
    gt = data["gt"]
    pred = np.full_like(gt, np.nan)
    for i, path in enumerate(data["paths"]):
        img = Image.open(path).convert("RGB")
        A = alignment(gt[i], resolution, model)
        crop = align_image(img, gt[i], resolution, model)
        x = torch.as_tensor(crop.transpose(2, 0, 1)[None].astype(np.float32) / 127.5 - 1)
        lm = L.landmarks(x)[0].double().numpy()
        pred[i] = np.linalg.solve(A[:, :2], (lm - A[:, 2]).T).T
    norm = box_size(gt)
    defined = load_model(model).landmark_ids >= 0
    d = np.linalg.norm(pred - gt, axis=-1)[:, defined]
    return {"photos": len(gt),
            "nme68": yaw_table(nme(pred, gt, norm), data["yaw_deg"]),
            "nme_defined": yaw_table(100 * d.mean(1) / norm, data["yaw_deg"])}


def london_identity(R, pack, root, dlib: bool = True) -> dict:
    """R and dlib's descriptor on the London people of ``pack`` with both photos (see the
    module docstring): ``{"R", "dlib_crops", "dlib_photos"}`` each ``{"all", "held_out"}`` of
    :func:`neural.gar.auxnets.metrics.verification_auc`."""
    import torch.nn.functional as F

    from neural.gar.auxnets.metrics import pair_rows, verification_auc
    from neural.gar.real_faces import RealFaces

    from .face_descriptor import aligned_descriptors, photo_descriptors

    faces = RealFaces(pack, split="all", flip=False)
    a = faces.arrays
    pairs = pair_rows(faces)
    pairs = pairs[np.asarray(a["source"]).astype(str)[pairs[:, 0]] == "london"]
    if len(pairs) < 2:
        raise InputError(f"{pack}: fewer than two London people with both photos")
    held = a["held_out"][pairs[:, 0]]
    with torch.no_grad():
        emb = [F.normalize(R(faces.batch(pairs[:, k])["image"]), dim=1).numpy() for k in (0, 1)]

    def table(sim):
        return {"all": verification_auc(sim),
                "held_out": verification_auc(sim[np.ix_(held, held)])}

    out = {"R": table(emb[0] @ emb[1].T)}
    if dlib:
        d = [aligned_descriptors(a["image"][pairs[:, k]]) for k in (0, 1)]
        out["dlib_crops"] = table(-np.linalg.norm(d[0][:, None] - d[1][None], axis=-1))
        photos = [photo_descriptors([Path(root) / str(a["name"][i]) for i in pairs[:, k]])
                  for k in (0, 1)]
        ok = np.isfinite(photos[0][:, 0]) & np.isfinite(photos[1][:, 0])
        dist = -np.linalg.norm(photos[0][:, None] - photos[1][None], axis=-1)
        both = ok & held
        out["dlib_photos"] = {"all": verification_auc(dist[np.ix_(ok, ok)]),
                              "held_out": verification_auc(dist[np.ix_(both, both)]),
                              "no_face": int((~ok).sum())}
    return out


def evaluate(pack, aux_dir=None, root=None, aflw_n=None, london=True, dlib=True,
             synthetic_n: int = 32) -> dict:
    """The report of :func:`main` (see the module docstring)."""
    from neural.gar.auxnets import NAMES, load_aux
    from neural.gar.auxnets.metrics import real_metrics, synthetic_metrics
    from neural.faces.renders import SyntheticFaces
    from neural.gar.real_faces import RealFaces

    from .bench_alignment import data_root

    root = Path(root) if root else data_root()
    test = RealFaces(pack, split="test", flip=False)
    res = test.resolution
    nets = {n: load_aux(n, None if aux_dir is None else Path(aux_dir) / f"aux_{n}.pt",
                        resolution=res) for n in NAMES}
    times = {}
    t = time.time()
    syn = SyntheticFaces(resolution=res, n_identities=200, seed=0)
    index = torch.as_tensor(np.flatnonzero(syn.model.landmark_ids >= 0))
    report = {"pack": str(pack), "aux_dir": None if aux_dir is None else str(aux_dir),
              "resolution": res, "held_out_crops": len(test),
              "held_out_by_source": {s: int(c) for s, c in zip(*np.unique(
                  np.asarray(test.arrays["source"]).astype(str), return_counts=True))},
              "real": real_metrics(nets, test, landmark_index=index)}
    times["real"] = time.time() - t
    if synthetic_n:
        t = time.time()
        fresh = SyntheticFaces(resolution=res, n_identities=64, seed=7919)
        report["synthetic"] = synthetic_metrics(nets, syn, fresh, index, n=synthetic_n)
        times["synthetic"] = time.time() - t
    if aflw_n != 0:
        t = time.time()
        report["aflw2000"] = aflw2000_landmarks(nets["L"], root, res, aflw_n)
        times["aflw2000"] = time.time() - t
    if london:
        t = time.time()
        report["london"] = london_identity(nets["R"], pack, root, dlib)
        times["london"] = time.time() - t
    report["seconds"] = {k: round(v, 1) for k, v in times.items()}
    return report


@one_line_errors("evaluation.aux_real")
def main(argv=None) -> int:
    """``python -m evaluation.aux_real``: the report (the module docstring says what it holds)."""
    p = argparse.ArgumentParser(prog="python -m evaluation.aux_real",
                                description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, help="the real pack (neural.gar.real_faces)")
    p.add_argument("--report", required=True, help="output JSON")
    p.add_argument("--aux-dir", help="folder with aux_*.pt (default: neural/gar/weights)")
    p.add_argument("--root", help="the shared data folder (default: $MORPHABLE_DATA or ../shared/data)")
    p.add_argument("--aflw", type=int, help="AFLW2000-3D photos (default all; 0 skips)")
    p.add_argument("--no-london", action="store_true", help="skip R and dlib on the London set")
    p.add_argument("--no-dlib", action="store_true",
                   help="London: skip dlib's descriptor (the reference, independent of --aux-dir)")
    p.add_argument("--synthetic", type=int, default=32,
                   help="held-out synthetic renders (0 skips)")
    p.add_argument("--threads", type=int)
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    if args.threads:
        torch.set_num_threads(args.threads)
    report = evaluate(args.data, args.aux_dir, args.root, args.aflw, not args.no_london,
                      not args.no_dlib, args.synthetic)
    from morphable.io.atomic import atomic_path

    out = Path(args.report)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
