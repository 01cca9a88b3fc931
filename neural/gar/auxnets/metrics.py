"""Held-out metrics of the auxiliary networks: on synthetic renders and on real crops.

- :func:`synthetic_metrics`: held-out synthetic renders with exact labels (what
  :meth:`neural.gar.auxnets.train.AuxTrainer.validate` reports for the synthetic path);
- :func:`real_metrics`: the held-out crops of a real pack (:class:`neural.gar.real_faces.RealFaces`,
  ``split="test"``), against the labels our own fits give them: N's mean angle to the fit's
  normal map on its face pixels, P's IoU with the fit's mask, L's distance to the pack's
  landmarks (px and NME by the outer-eye-corner distance), separately for sources whose
  landmarks are ground truth (:data:`GT_LANDMARK_SOURCES`) and those whose landmarks were
  detected; R's same/different-person verification AUC on the people with two photos.

The fit labels are not ground truth: an N that reproduced them perfectly would still carry the
fit's errors (a smooth 3DMM surface without hair, eyes or mouth interior).
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

__all__ = ["GT_LANDMARK_SOURCES", "identity_labels", "verification_auc", "landmark_errors", "synthetic_metrics",
           "real_metrics", "pair_rows", "pair_verification"]

GT_LANDMARK_SOURCES = ("300w",)
"""Pack sources whose landmarks are annotations (the others' are detected)."""


def identity_labels(batch, dim: int) -> torch.Tensor:
    """R's regression target (B, dim): skin tone, then the first ``dim - 1`` identity
    coefficients (std units)."""
    return torch.cat([batch["skin_tone"][:, None], batch["identity"][:, :dim - 1]], 1)


def verification_auc(similarity) -> dict:
    """Same/different verification from a (P, P) similarity matrix of P people's first
    photos (rows) against their second photos (columns): the diagonal pairs are the same
    person. Returns ``auc`` (the rate at which a same-person pair scores above a
    different-person pair), ``same`` and ``different`` (mean similarities), ``people``."""
    s = torch.as_tensor(np.asarray(similarity), dtype=torch.float64)
    P = len(s)
    if P < 2:
        return {"auc": None, "same": None, "different": None, "people": P}
    same = s.diagonal()
    diff = s[~torch.eye(P, dtype=torch.bool)]
    auc = (same[:, None] > diff[None, :]).double().mean()
    return {"auc": float(auc), "same": float(same.mean()), "different": float(diff.mean()),
            "people": P}


def landmark_errors(pred, truth, index=None) -> dict:
    """(B, 68, 2) predicted and true landmarks (px, NaN where unknown) -> ``error_px`` (mean
    distance over the finite points), ``nme_percent`` (per crop: that mean divided by the
    outer-eye-corner distance, iBUG 37-46, then averaged; crops without both corners left out)
    and ``crops``; ``index`` restricts the points scored."""
    pred, truth = torch.as_tensor(pred, dtype=torch.float64), torch.as_tensor(truth, dtype=torch.float64)
    iod = (truth[:, 36] - truth[:, 45]).norm(dim=-1)
    if index is not None:
        pred, truth = pred[:, index], truth[:, index]
    d = (pred - truth).norm(dim=-1)
    ok = torch.isfinite(d)
    n = ok.sum(1)
    per = torch.where(ok, d, torch.zeros_like(d)).sum(1) / n.clamp_min(1)
    has = n > 0
    if not has.any():
        return {"error_px": None, "nme_percent": None, "crops": 0}
    norm = has & torch.isfinite(iod) & (iod > 0)
    return {"error_px": float(torch.where(ok, d, torch.zeros_like(d)).sum() / n.sum()),
            "nme_percent": float((100 * per[norm] / iod[norm]).mean()) if norm.any() else None,
            "crops": int(has.sum())}


@torch.no_grad()
def synthetic_metrics(nets: dict, data, fresh, landmark_index, seed: int = 0, n: int = 32) -> dict:
    """Metrics of ``nets`` ({"N", "P", "L", "R"} subset) on ``n`` held-out synthetic renders of
    ``data`` (a :class:`neural.faces.renders.SyntheticFaces`; seeds ``[seed, 2**31]`` that training
    never draws) and, for R, pairs of unseen identities of ``fresh``: normal error (degrees),
    mask IoU, landmark error (px) on ``landmark_index``, identity verification AUC, mean
    cosines and the fraction of identity-label variance R explains."""
    for net in nets.values():
        net.eval()
    b = data.sample(n, rng=[seed, 2**31])
    face = b["mask"][:, 0] > 0.5
    out = {}
    if "N" in nets:
        cos = (nets["N"](b["image"]) * b["normals"]).sum(1).clamp(-1, 1)
        out["N"] = {"normal_error_deg": float(torch.rad2deg(torch.acos(cos[face])).mean())}
    if "P" in nets:
        pred = nets["P"](b["image"])[:, 0] > 0.5
        out["P"] = {"mask_iou": float((pred & face).sum() / (pred | face).sum().clamp_min(1))}
    if "L" in nets:
        lm = nets["L"].landmarks(b["image"])[:, landmark_index]
        err = (lm - b["landmarks"][:, landmark_index]).norm(dim=-1).mean()
        out["L"] = {"landmark_error_px": float(err)}
    if "R" in nets:
        # verification on unseen identities: the AUC of same-identity pairs (two views)
        # against different-identity pairs
        p = fresh.sample(n, rng=[seed, 2**31 + 1], pair=True)
        R = nets["R"]
        ea, eb = R(p["image"]), R(p["image_b"])
        v = verification_auc(ea @ eb.T)
        out["R"] = {"identity_verification_auc": v["auc"], "identity_cos_same": v["same"],
                    "identity_cos_diff": v["different"]}
        if hasattr(R, "predict"):   # our architecture: the labels it regresses
            pred = R.predict(p["image"])
            truth = identity_labels(p, pred.shape[1])
            out["R"]["identity_variance_explained"] = \
                1 - float((pred - truth).pow(2).mean() / truth.pow(2).mean())
    return out


def pair_rows(faces) -> np.ndarray:
    """(P, 2) row indices of ``faces`` (a :class:`~neural.gar.real_faces.RealFaces`): the first two
    photos (by name) of every person with at least two, e.g. the London set's neutral
    (``neutral_front``) and smiling (``smiling_front``) photos."""
    a = faces.arrays
    order = np.lexsort((a["name"], a["person"]))
    person = a["person"][order]
    rows = []
    for start in np.flatnonzero(np.r_[True, person[1:] != person[:-1]]):
        if start + 1 < len(person) and person[start + 1] == person[start]:
            rows.append(order[start:start + 2])
    return np.array(rows, np.int64).reshape(-1, 2)


@torch.no_grad()
def pair_verification(R, faces, pairs, batch_size: int = 64) -> dict:
    """R's :func:`verification_auc` on the (P, 2) row pairs of ``faces`` (one person each):
    ``identity_verification_auc``, ``identity_cos_same``, ``identity_cos_diff``, ``people``."""
    R.eval()
    if len(pairs) >= 2:
        ea = _run(R, faces, pairs[:, 0], batch_size, lambda net, x: net(x))
        eb = _run(R, faces, pairs[:, 1], batch_size, lambda net, x: net(x))
        v = verification_auc(F.normalize(ea, dim=1) @ F.normalize(eb, dim=1).T)
    else:
        v = verification_auc(np.zeros((len(pairs), len(pairs))))
    return {"identity_verification_auc": v["auc"], "identity_cos_same": v["same"],
            "identity_cos_diff": v["different"], "people": v["people"]}


def _run(net, faces, rows, batch_size, fn):
    return torch.cat([fn(net, faces.batch(rows[i:i + batch_size])["image"])
                      for i in range(0, len(rows), batch_size)])


@torch.no_grad()
def real_metrics(nets: dict, faces, batch_size: int = 64, landmark_index=None,
                 gt_sources=GT_LANDMARK_SOURCES) -> dict:
    """Metrics of ``nets`` on every crop of ``faces`` (a :class:`~neural.gar.real_faces.RealFaces`,
    normally ``split="test", flip=False``) against the fits' labels; see the module docstring.

    Returns ``{"N": {"normal_error_deg", "crops", "by_source"}, "P": {"mask_iou", ...},
    "L": {"ground_truth": {...}, "detected": {...}}, "R": {"identity_verification_auc", ...}}``
    for the networks given; L's groups hold :func:`landmark_errors` over all finite points and,
    with ``landmark_index``, ``error_px_defined`` over those points only (the landmarks the
    synthetic renders define). A group or figure without crops is None."""
    for net in nets.values():
        net.eval()
    a = faces.arrays
    n = len(faces)
    source = np.asarray(a["source"]).astype(str)
    out = {}
    if "N" in nets or "P" in nets:
        err_sum = np.zeros(n)
        err_cnt = np.zeros(n)
        inter = union = 0.0
        for i in range(0, n, batch_size):
            rows = np.arange(i, min(n, i + batch_size))
            b = faces.batch(rows)
            face = (b["mask"][:, 0] > 0.5) & (b["normals"].norm(dim=1) > 0.5)
            if "N" in nets:
                cos = (nets["N"](b["image"]) * b["normals"]).sum(1).clamp(-1, 1)
                ang = torch.rad2deg(torch.acos(cos)) * face
                err_sum[rows] = ang.flatten(1).sum(1).double().numpy()
                err_cnt[rows] = face.flatten(1).sum(1).double().numpy()
            if "P" in nets:
                pred = nets["P"](b["image"])[:, 0] > 0.5
                fit = b["mask"][:, 0] > 0.5
                inter += float((pred & fit).sum())
                union += float((pred | fit).sum())
        if "N" in nets:
            by = {str(s): float(err_sum[source == s].sum() / max(err_cnt[source == s].sum(), 1))
                  for s in np.unique(source)}
            out["N"] = {"normal_error_deg": float(err_sum.sum() / max(err_cnt.sum(), 1)),
                        "crops": int(n), "by_source": by}
        if "P" in nets:
            out["P"] = {"mask_iou": inter / max(union, 1.0), "crops": int(n)}
    if "L" in nets:
        rows = np.arange(n)
        pred = _run(nets["L"], faces, rows, batch_size, lambda net, x: net.landmarks(x))
        truth = torch.as_tensor(a["landmarks"], dtype=torch.float32)
        gt = np.isin(source, list(gt_sources))
        out["L"] = {}
        for group, sel in (("ground_truth", gt), ("detected", ~gt)):
            sel = torch.as_tensor(sel)
            m = landmark_errors(pred[sel], truth[sel])
            if landmark_index is not None:
                m["error_px_defined"] = landmark_errors(pred[sel], truth[sel], landmark_index)["error_px"]
            out["L"][group] = m
    if "R" in nets:
        out["R"] = pair_verification(nets["R"], faces, pair_rows(faces), batch_size)
    return out
