"""The landmark network's face score fitted again with harder negatives.

The training run's only negatives are crops away from the face
(:func:`neural.landmarks.data.draw_batch`); the score it learned calls uniform noise a face
(0.67-0.84 on noise photos) and was never shown a crop inside a face. Here the score's row of
the last layer (the face logit: a linear function of the head's hidden layer) is fitted again by
L2-regularised logistic regression on the frozen network's hidden features of training crops:
faces as the trainer crops them, and as many negatives of each kind of
:data:`neural.landmarks.data.NEGATIVE_KINDS` (away from the face, part of a face, textures
without a photo), then again with the best windows of the network's window search on noise
photos added (hard negatives: the search takes the best of hundreds of windows, so its false
faces are the far tail of the negatives). Points and σ are untouched: the other rows and every
other layer keep their weights bit for bit.

Recall and false-positive rates at :data:`neural.landmarks.detector.FACE_THRESHOLD`, before and
after, on the held-out faces (the synthetic pack's last 256, the annotated and profiled packs'
validation splits), on negatives drawn from them with another seed and on 64 other noise
photos (where the window search finds a face), go in the file's ``meta["score_refit"]``::

    python -m neural.landmarks.score --weights runs/ldmk_cpu_c/landmarks.pt \\
        --synthetic landmark_data/synthetic_sfm160 landmark_data/synthetic_ict160 \\
        --annotated landmark_data/annotated --profiled landmark_data/profiled \\
        --out neural/landmarks/weights/landmarks.pt
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np
import torch

from morphable.errors import InputError, one_line_errors

__all__ = ["hidden_features", "fit_logistic", "noise_photos", "refit_score", "detector_rate", "main"]


@torch.no_grad()
def hidden_features(net, x: torch.Tensor, batch: int = 256) -> torch.Tensor:
    """The input of ``net``'s last layer for crops x (N, 3, R, R) in [-1, 1] -> (N, hidden)
    float64: what the face logit is a linear function of."""
    out = []
    for i in range(0, len(x), batch):
        xb = x[i:i + batch].contiguous(memory_format=torch.channels_last)
        out.append(net.head[:-1](net.features(xb)).double())
    return torch.cat(out)


def fit_logistic(h: torch.Tensor, y: torch.Tensor, w0: torch.Tensor, b0: float,
                 l2: float = 1e-3, iterations: int = 200) -> tuple:
    """Class-balanced logistic regression of labels y (N,) in {0, 1} on features h (N, D),
    from the row (w0 (D,), b0), with ``l2`` × ``|w|²`` added -> (w (D,), b) float64."""
    w = w0.double().clone().requires_grad_(True)
    b = torch.tensor(float(b0), dtype=torch.float64, requires_grad=True)
    y = y.double()
    weight = torch.where(y > 0.5, 0.5 / y.mean(), 0.5 / (1 - y.mean()))
    opt = torch.optim.LBFGS([w, b], max_iter=iterations, line_search_fn="strong_wolfe")

    def loss():
        opt.zero_grad()
        v = (weight * torch.nn.functional.binary_cross_entropy_with_logits(h @ w + b, y,
                                                                          reduction="none")).mean()
        v = v + l2 * (w ** 2).sum()
        v.backward()
        return v

    opt.step(loss)
    return w.detach(), float(b.detach())


def noise_photos(n: int, seed: int = 0) -> list:
    """``n`` photos without a face -> list of (H, W, 3) uint8: uniform or Gaussian noise, grey
    or coloured, at grain sizes of 1-8 px, 240 x 320 to 480 x 640 px (the bad-input table's
    noise photos are such)."""
    rng = np.random.default_rng([seed, 11])
    out = []
    for _ in range(n):
        H, W = (240, 320) if rng.random() < 0.5 else (480, 640)
        grain = int(rng.choice([1, 1, 2, 4, 8]))
        ch = 3 if rng.random() < 0.7 else 1
        h, w = -(-H // grain), -(-W // grain)
        small = (rng.integers(0, 256, (h, w, ch)) if rng.random() < 0.6 else
                 np.clip(rng.normal(128, rng.uniform(20, 80), (h, w, ch)), 0, 255))
        img = np.repeat(np.repeat(small, grain, 0), grain, 1)[:H, :W]
        out.append(np.broadcast_to(img, (H, W, 3)).astype(np.uint8).copy())
    return out


def _window_features(net, photos) -> list:
    """The hidden features of every window of the network's window search
    (:func:`neural.landmarks.detector.windows`) of each photo -> [((K, hidden) plain, (K,
    hidden) mirrored), ...]: what any score row ranks the windows by."""
    from .detector import crops, windows

    out = []
    for img in photos:
        x = torch.from_numpy(crops(img, windows(img.shape[1], img.shape[0]), net.config.resolution))
        h = hidden_features(net, torch.cat([x, torch.flip(x, dims=[-1])]))
        out.append((h[:len(x)], h[len(x):]))
    return out


def _best_windows(features: list, row, top: int = 16) -> tuple:
    """The ``top`` best-scoring windows of each photo's :func:`_window_features` under the
    score row ``row`` = (w, b) -> ((M, hidden) their features, unmirrored and mirrored,
    (photos,) the best window's face probability of each photo)."""
    w, b = row
    feats, best = [], []
    for plain, mirrored in features:
        logit = ((plain + mirrored) @ w) / 2 + b          # the detector merges the two readings
        order = torch.argsort(logit, descending=True)[:top]
        feats += [plain[order], mirrored[order]]
        best.append(float(torch.sigmoid(logit[order[0]])))
    return (torch.cat(feats) if feats else torch.zeros(0)), np.array(best)


def detector_rate(weights, photos) -> float:
    """The share of ``photos`` in which :class:`neural.landmarks.detector.NetworkDetector` with
    ``weights`` finds a face by its window search."""
    from .detector import FACE_THRESHOLD, NetworkDetector

    det = NetworkDetector(weights)
    return round(float(np.mean([det.search(p)["probability"][0] >= FACE_THRESHOLD for p in photos])), 4)


def _rates(net, row, held: dict, negatives: dict) -> dict:
    """Face probability >= threshold: recall on each held-out source, false positives on each
    negative kind, with the score row ``row`` = (w, b)."""
    from .detector import FACE_THRESHOLD

    w, b = row
    out = {}
    for name, h in {**held, **negatives}.items():
        p = torch.sigmoid(h @ w + b)
        key = "recall" if name in held else "false_positive"
        out[f"{key} {name}"] = round(float((p >= FACE_THRESHOLD).double().mean()), 4)
    return out


def _photo_rate(features: list, row) -> float:
    """The share of photos (their :func:`_window_features`) whose best window is a face under
    ``row``."""
    from .detector import FACE_THRESHOLD

    return round(float((_best_windows(features, row, top=1)[1] >= FACE_THRESHOLD).mean()), 4)


def refit_score(net, sources: dict, validation: dict, n: int = 4096, l2: float = 1e-3,
                seed: int = 0, mining_photos: int = 64, mining_rounds: int = 2) -> dict:
    """Fit ``net``'s face-score row again (in place) -> a report: the rates before and after
    (``_rates``), crops used, seconds.

    Parameters
    ----------
    sources : kind -> training LandmarkSource (:func:`neural.landmarks.train.load_sources`)
    validation : name -> held-out LandmarkSource (faces only: negatives are drawn from them)
    n : training faces; as many negatives of each kind
    mining_photos, mining_rounds : noise photos (:func:`noise_photos`) whose best windows are
        added as negatives after each of ``mining_rounds`` fits
    """
    from .data import NEGATIVE_KINDS, draw_batch, negative_crops, validation_batch

    t = time.perf_counter()
    config = replace(net.config, negatives=0.0, batch_size=n, seed=net.config.seed + 1000 + seed)

    def negatives(pool: dict, count: int, k: str, draw: int) -> torch.Tensor:
        # away from and inside the faces of every source alike; textures need none
        if k == "texture":
            return negative_crops(None, config, count, k, draw)
        return torch.cat([negative_crops(src, config, count // len(pool), k, draw + i)
                          for i, src in enumerate(pool.values())])

    per_kind = n // len(NEGATIVE_KINDS)
    pos = hidden_features(net, draw_batch(sources, config, 0)["image"])
    neg = {k: hidden_features(net, negatives(sources, per_kind, k, seed)) for k in NEGATIVE_KINDS}
    held = {name: hidden_features(net, validation_batch(src, net.config, 256)["image"])
            for name, src in validation.items()}
    held_neg = {k: hidden_features(net, negatives(validation, 256, k, seed + 100))
                for k in NEGATIVE_KINDS}
    last = net.head[-1]
    before = (last.weight[-1].detach().double(), float(last.bias[-1]))
    # the window search takes the best of hundreds of windows: its false faces are the
    # negatives' extreme tail, so the best windows on noise photos are mined and added
    # (hard negatives), twice
    train = _window_features(net, noise_photos(mining_photos, seed))
    held_windows = _window_features(net, noise_photos(64, seed + 100))
    row, mined = before, []
    for r in range(1 + mining_rounds):
        h = torch.cat([pos, *neg.values(), *mined])
        y = torch.cat([torch.ones(len(pos)), torch.zeros(len(h) - len(pos))])
        row = fit_logistic(h, y, *row, l2=l2)
        if train and r < mining_rounds:
            mined.append(_best_windows(train, row)[0])
    with torch.no_grad():
        last.weight[-1] = row[0].to(last.weight)
        last.bias[-1] = row[1]
    return {"before": {**_rates(net, before, held, held_neg),
                       "noise photos with a face": _photo_rate(held_windows, before)},
            "after": {**_rates(net, row, held, held_neg),
                      "noise photos with a face": _photo_rate(held_windows, row)},
            "mined_windows": int(sum(len(m) for m in mined)),
            "faces": len(pos), "negatives": {k: len(v) for k, v in neg.items()},
            "l2": l2, "seconds": round(time.perf_counter() - t, 1)}


@one_line_errors("python -m neural.landmarks.score")
def main(argv=None) -> int:
    from morphable.io.atomic import write_json

    from .data import load_source
    from .network import load_landmark_net, save_landmark_net
    from .train import load_sources

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--weights", required=True, help="landmarks.pt whose face score is refitted")
    p.add_argument("--synthetic", nargs="*", default=[], metavar="PACK")
    p.add_argument("--annotated", metavar="PACK")
    p.add_argument("--profiled", metavar="PACK")
    p.add_argument("--n", type=int, default=4096, help="training faces, and as many negatives")
    p.add_argument("--l2", type=float, default=1e-3)
    p.add_argument("--mining-photos", type=int, default=64,
                   help="noise photos whose best windows are mined as negatives (default 64)")
    p.add_argument("--mining-rounds", type=int, default=2)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", required=True, help="the weights with the new score (may be --weights)")
    p.add_argument("--report", help="the rates as JSON too")
    a = p.parse_args(argv)
    if a.n < 3 or a.mining_photos < 0 or a.mining_rounds < 0:
        raise InputError("--n must be >= 3, --mining-photos and --mining-rounds >= 0")
    torch.set_num_threads(a.threads)
    net = load_landmark_net(a.weights)
    sources, validation, _ = load_sources(a.synthetic, a.annotated, a.profiled)
    if a.profiled:
        validation["profiled"] = load_source(a.profiled, "profiled", "validation")
    validation = {k: v for k, v in validation.items() if len(v)}
    if not validation:
        raise InputError("no held-out faces to measure the score on (give a synthetic pack of "
                         "more than 512 faces, or the annotated or profiled pack)")
    report = refit_score(net, sources, validation, a.n, a.l2, mining_photos=a.mining_photos,
                         mining_rounds=a.mining_rounds)
    net.meta = {**net.meta, "score_refit": {**report, "command": "python -m neural.landmarks.score "
                                            + " ".join(sys.argv[1:] if argv is None else argv)}}
    # what the detector does on the held-out noise photos: its window search reads the best
    # window's face again in the framing of its points (NetworkDetector.search); "before" is
    # read before --out may overwrite --weights
    photos = noise_photos(64, 100)
    report["before"]["noise photos with a face, the detector"] = detector_rate(a.weights, photos)
    save_landmark_net(net, a.out)
    report["after"]["noise photos with a face, the detector"] = detector_rate(a.out, photos)
    net.meta["score_refit"] = {**net.meta["score_refit"], **report}
    save_landmark_net(net, a.out)
    if a.report:
        write_json(a.report, report)
    for k in report["before"]:
        print(f"{k}: {report['before'][k]:.4f} -> {report['after'][k]:.4f}")
    print(f"{report['seconds']:.0f} s; wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
