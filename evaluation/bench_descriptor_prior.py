"""An identity prior from a face descriptor: does dlib's 128-D descriptor, mapped to SFM
identity coefficients, make the landmark fit's 3D shape better?

MICA's idea on our model: synthetic SFM faces of known identity wearing real photo textures
(:class:`neural.faces.synthetic.SyntheticEngine`, London textures, CC BY 4.0; procedural
backgrounds, near-frontal poses, no occluders or degradations) are described by dlib's network
(:func:`evaluation.face_descriptor.point_descriptors`, chip cut at the faces' exact points);
a ridge regression maps the descriptor to the identity coefficients (its ridge chosen by
5-fold cross-validation on the training faces). The training faces wear the textures of London
people 21-102, the held-out faces those of people 1-20 and identities never seen.

Measured on the held-out faces: the RMS per-vertex distance (mm) between the neutral identity
mesh and the true one after the best similarity transform, for (a) the mean face, (b) the
landmark fit (:func:`morphable.fitting.fit_landmarks`, the exact 68 labels plus Gaussian noise,
``convention="3d"``), (c) the descriptor's prediction alone, (d) the landmark fit with
``identity_prior_mean`` set to the prediction, (e) the same with the prior's standard deviation
per mode (``identity_prior_std``) set to the prediction's cross-validated residual spread (the
prior it really is).
On the London photos (:mod:`evaluation.bench_identity`'s measures: face-mesh landmarks, dlib's
own detector for the descriptor): identification rate of the landmark fit against the fit with
the prior. The descriptor alone identifies people well, so a gain there partly measures the
descriptor, not the 3D shape; the synthetic table is the shape measure.

    python -m evaluation.bench_descriptor_prior --report reports/bench_descriptor_prior.json
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity
from morphable.metrics import umeyama

from .bench_alignment import data_root
from .bench_report import write_report

__all__ = ["TEST_PEOPLE", "render_faces", "fit_ridge", "predict", "rms_error", "synthetic_table",
           "london_table", "james_table", "main"]

TEST_PEOPLE = 20
"""The London people whose textures only the held-out faces wear (the first ones)."""
RIDGES = tuple(10.0 ** np.arange(-3, 3.5, 0.5))
"""Ridge strengths tried by the cross-validation (descriptor units)."""


def render_faces(n: int, textures, seed: int = 0, resolution: int = 256, start: int = 0) -> dict:
    """Synthetic SFM faces ``start`` to ``n - 1`` (face i drawn from the seed ``[seed, i]``)
    wearing ``textures`` ((T, S, S, 3) uint8 UV textures) ->
    ``identity`` (n, K), ``points68`` (n, 68, 2) px, ``descriptor`` (n, 128), ``texture``
    (n,) index, ``ms`` (n,) wall ms to render and describe each."""
    from neural.faces.synthetic import SyntheticEngine

    from .face_descriptor import point_descriptors

    engine = SyntheticEngine("sfm", resolution=resolution, textures=textures, pose_max=(30.0, 15.0, 10.0),
                             face_fraction=(0.45, 0.6), texture_share=1.0, occluders=False,
                             degrade=False, supersample=1)
    out = {k: [] for k in ("identity", "points68", "descriptor", "texture", "ms")}
    for i in range(start, n):
        t = time.perf_counter()
        s = engine.sample(np.random.default_rng([seed, i]))
        out["descriptor"].append(point_descriptors([s["image"]], s["points68"][None])[0])
        out["ms"].append((time.perf_counter() - t) * 1e3)
        out["identity"].append(s["params"]["identity"])
        out["points68"].append(s["points68"])
        out["texture"].append(s["params"]["texture"])
    return {k: np.asarray(v) for k, v in out.items()}


def fit_ridge(D, A, ridges=RIDGES, folds: int = 5, seed: int = 0) -> dict:
    """Ridge regression ``A ~ D W + b`` from descriptors D (n, 128) to identity coefficients
    A (n, K), its strength chosen by ``folds``-fold cross-validation -> ``W`` (128, K), ``b``
    (K,), ``ridge``, ``cv_mse`` (per ridge, mean over the coefficients, in coefficient
    units^2) and ``residual_var`` (K,) (the chosen ridge's cross-validated mean squared
    residual of each coefficient)."""
    D, A = np.asarray(D, np.float64), np.asarray(A, np.float64)
    if len(D) != len(A) or len(D) < folds:
        raise InputError(f"descriptor map: {len(D)} descriptors for {len(A)} identities")
    fold = np.random.default_rng(seed).permutation(len(D)) % folds
    cv = []
    for lam in ridges:
        residual = np.zeros_like(A)
        for f in range(folds):
            residual[fold == f] = predict(_solve(D[fold != f], A[fold != f], lam), D[fold == f]) - A[fold == f]
        cv.append((residual ** 2).mean(0))
    best = int(np.argmin([c.mean() for c in cv]))
    m = _solve(D, A, ridges[best])
    m.update(ridge=float(ridges[best]), cv_mse=np.array([c.mean() for c in cv]), residual_var=cv[best])
    return m


def _solve(D, A, lam) -> dict:
    mu_d, mu_a = D.mean(0), A.mean(0)
    X = D - mu_d
    W = np.linalg.solve(X.T @ X + lam * np.eye(X.shape[1]), X.T @ (A - mu_a))
    return {"W": W, "b": mu_a - mu_d @ W}


def predict(m: dict, D) -> np.ndarray:
    """(n, K) identity coefficients predicted from descriptors D (n, 128) by a map of
    :func:`fit_ridge`."""
    return np.asarray(D, np.float64) @ m["W"] + m["b"]


def rms_error(fitted, truth) -> float:
    """RMS per-vertex distance (mm) of (V, 3) meshes after the best similarity transform
    fitted -> truth."""
    scale, R, t = umeyama(fitted, truth)
    return float(np.sqrt(((scale * fitted @ R.T + t - truth) ** 2).sum(1).mean()))


def synthetic_table(model, train: dict, test: dict, noise_px: float = 2.0, seed: int = 0) -> dict:
    """The held-out table: per row, the mean and median RMS error (mm) over the test faces
    and the mean fit time (ms); see the module docstring for the rows."""
    from morphable.fitting import fit_landmarks

    m = fit_ridge(train["descriptor"], train["identity"])
    guess = predict(m, test["descriptor"])
    rng = np.random.default_rng(seed)
    rows = {k: [] for k in ("mean face", "landmark fit", "descriptor alone", "landmark fit + descriptor mean",
                            "landmark fit + descriptor prior")}
    ms = {k: [] for k in rows}
    zero = np.zeros(model.n_identity)
    for alpha, pts, g in zip(test["identity"], test["points68"], guess):
        truth = model.vertices(alpha)
        noisy = pts + rng.normal(0, noise_px, pts.shape)
        rows["mean face"].append(rms_error(model.vertices(zero), truth))
        rows["descriptor alone"].append(rms_error(model.vertices(g), truth))
        for name, kw in (("landmark fit", {}), ("landmark fit + descriptor mean", {"identity_prior_mean": g}),
                         ("landmark fit + descriptor prior",
                          {"identity_prior_mean": g, "identity_prior_std": np.sqrt(m["residual_var"])})):
            t = time.perf_counter()
            res = fit_landmarks(model, noisy, (256, 256), convention="3d", landmark_std_px=noise_px, **kw)
            ms[name].append((time.perf_counter() - t) * 1e3)
            rows[name].append(rms_error(res.neutral_vertices(), truth))
    return {"ridge": m["ridge"], "cv_residual_var": m["residual_var"].tolist(), "train_faces": len(train["identity"]),
            "test_faces": len(test["identity"]), "noise_px": noise_px,
            "rows": {k: {"mean_mm": float(np.mean(v)), "median_mm": float(np.median(v)),
                         "fit_ms": float(np.mean(ms[k])) if ms[k] else 0.0} for k, v in rows.items()}}


def london_table(model, m: dict, root: Path, n=None) -> dict:
    """Identification on the London pairs (:func:`evaluation.bench_identity.consistency`) of
    the landmark fit (face-mesh points), the same with the descriptor's prior mean (the
    model's prior spread and the prediction's residual spread), and the descriptor's prediction alone."""
    from morphable.detection import detect
    from morphable.detection.images import read_image
    from morphable.fitting import fit_landmarks
    from morphable.fitting.options import detection_settings

    from .bench_identity import consistency, london_pairs
    from .face_descriptor import photo_descriptors

    pairs = london_pairs(root, n)
    names = ("landmark fit", "landmark fit + descriptor mean", "landmark fit + descriptor prior",
             "descriptor alone")
    meshes = {k: np.full((2, len(pairs), model.n_vertices, 3), np.nan) for k in names}
    ms, describe_s = [], 0.0
    for side in (0, 1):
        paths = [p[1 + side] for p in pairs]
        t = time.perf_counter()
        guess = predict(m, photo_descriptors(paths))
        describe_s += time.perf_counter() - t
        for i, p in enumerate(paths):
            t = time.perf_counter()
            img = read_image(p)
            found = detect(img, landmark_detector="facemesh")
            opts = detection_settings([found], len(found.points))
            size = (img.shape[1], img.shape[0])
            meshes["landmark fit"][side, i] = fit_landmarks(model, found.points, size, **opts).neutral_vertices()
            if np.isfinite(guess[i]).all():
                g = guess[i]
                meshes["descriptor alone"][side, i] = model.vertices(g)
                meshes["landmark fit + descriptor mean"][side, i] = fit_landmarks(
                    model, found.points, size, identity_prior_mean=g, **opts).neutral_vertices()
                meshes["landmark fit + descriptor prior"][side, i] = fit_landmarks(
                    model, found.points, size, identity_prior_mean=g, identity_prior_std=np.sqrt(m["residual_var"]),
                    **opts).neutral_vertices()
            ms.append((time.perf_counter() - t) * 1e3)
    return {"people": len(pairs), "ms_per_photo_all_rows": float(np.mean(ms)),
            "descriptor_ms_per_photo": describe_s * 1e3 / (2 * len(pairs)),
            "rows": {k: consistency(v[0], v[1]) for k, v in meshes.items()}}


def james_table(model, m: dict, root: Path) -> dict:
    """james' two raw scanner photos (``scans/james/james.jpg``, side by side, the scan of the
    same instant), each alone and both in one shared fit (face-mesh landmarks; the prior's
    mean: the average of the photos' predictions), against his scan
    (:func:`morphable.metrics.compare_to_scan`, the Florence protocol's point-to-plane mean,
    mm) -> {row: {photo: mm}}."""
    import tempfile

    from morphable.detection import detect
    from morphable.detection.images import read_image
    from morphable.fitting import fit_landmarks
    from morphable.fitting.options import detection_settings
    from morphable.metrics import compare_to_scan

    from .face_descriptor import photo_descriptors
    from .scans import load_scan

    folder = Path(root) / "scans" / "james"
    scan = load_scan(folder / "james.obj", folder / "james.ljson")
    img = read_image(folder / "james.jpg")
    half = img.shape[1] // 2
    photos = [np.ascontiguousarray(img[:, :half]), np.ascontiguousarray(img[:, half:])]
    with tempfile.TemporaryDirectory() as tmp:
        from PIL import Image

        paths = [Path(tmp) / f"james_{k}.png" for k in range(2)]
        for p, ph in zip(paths, photos):
            Image.fromarray(ph).save(p)
        guess = predict(m, photo_descriptors(paths))
    found = [detect(ph, landmark_detector="facemesh") for ph in photos]
    size = (half, img.shape[0])
    ids = np.asarray(model.landmark_ids)

    def error(vertices):
        lms = np.where(ids[:, None] >= 0, vertices[np.maximum(ids, 0)], np.nan)
        cmp = compare_to_scan(vertices, model.triangles, scan.vertices, scan.triangles, lms, scan.landmarks)
        return float(cmp.summary()["point_to_plane"]["mean_mm"])

    rows = {"mean face": {}, "landmark fit": {}, "landmark fit + descriptor mean": {},
            "landmark fit + descriptor prior": {}, "descriptor alone": {}}
    for name, frames in (("left", [0]), ("right", [1]), ("both", [0, 1])):
        pts = np.stack([found[k].points for k in frames])
        opts = detection_settings([found[k] for k in frames], pts.shape[1])
        g = guess[frames].mean(0)
        rows["mean face"][name] = error(model.vertices(np.zeros(model.n_identity)))
        rows["descriptor alone"][name] = error(model.vertices(g))
        for row, kw in (("landmark fit", {}), ("landmark fit + descriptor mean", {"identity_prior_mean": g}),
                        ("landmark fit + descriptor prior",
                         {"identity_prior_mean": g, "identity_prior_std": np.sqrt(m["residual_var"])})):
            rows[row][name] = error(fit_landmarks(model, pts, size, **opts, **kw).neutral_vertices())
    return rows


@one_line_errors("evaluation.bench_descriptor_prior")
def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--train", type=int, default=800, help="training faces")
    p.add_argument("--test", type=int, default=200, help="held-out faces")
    p.add_argument("--noise-px", type=float, default=2.0, help="landmark noise at 256 px")
    p.add_argument("--london", type=int, default=None, help="London people (default all; 0: none)")
    p.add_argument("--james", action="store_true", help="also james' photos against his scan")
    p.add_argument("--data", type=Path, default=None,
                   help="shared data folder (default: $MORPHABLE_DATA or ../shared/data)")
    p.add_argument("--cache", type=Path, default=Path("reports/descriptor_prior_cache"),
                   help="folder for the textures and the rendered faces' labels and descriptors")
    p.add_argument("--report", type=Path, default=Path("reports/bench_descriptor_prior.json"))
    add_verbosity_arguments(p)
    a = p.parse_args(argv)
    configure(verbosity(a))
    from morphable import load_model
    from neural.faces.synthetic import london_photos, texture_bank

    root = a.data or data_root()
    model = load_model("sfm")
    a.cache.mkdir(parents=True, exist_ok=True)
    textures, names, _ = texture_bank(london_photos(root), "sfm", 256, cache=a.cache / "textures_sfm_256.npz")
    if len(textures) <= TEST_PEOPLE:
        raise InputError(f"{root}: {len(textures)} London textures, need more than {TEST_PEOPLE}")
    sets = {}
    for name, n, tex, seed in (("train", a.train, textures[TEST_PEOPLE:], 1), ("test", a.test, textures[:TEST_PEOPLE], 2)):
        # a cache of fewer faces of the same draws is extended, one of more cut
        cached = sorted(((int(p.stem.split("_")[1]), p) for p in a.cache.glob(f"{name}_*.npz")),
                        key=lambda c: (c[0] < n, c[0] if c[0] >= n else -c[0]))
        if cached and cached[0][0] >= n:
            sets[name] = {k: v[:n] for k, v in np.load(cached[0][1]).items()}
            continue
        done = {k: v for k, v in np.load(cached[0][1]).items()} if cached else {}
        more = render_faces(n, tex, seed=seed, start=len(done.get("ms", ())))
        sets[name] = {k: np.concatenate([done[k], v]) if done else v for k, v in more.items()}
        np.savez(a.cache / f"{name}_{n}.npz", **sets[name])
    report = {"synthetic": synthetic_table(model, sets["train"], sets["test"], a.noise_px),
              "render_ms_per_face": float(np.mean(sets["train"]["ms"]))}
    syn = report["synthetic"]
    lines = [f"{syn['train_faces']} training faces, {syn['test_faces']} held out; ridge {syn['ridge']:g}, "
             f"cross-validated R^2 of the coefficients {1 - np.mean(syn['cv_residual_var']) / np.var(sets['train']['identity']):.3f} (modes 1-5: "
             f"{', '.join(f'{1 - v:.2f}' for v in syn['cv_residual_var'][:5])}); "
             f"{report['render_ms_per_face']:.0f} ms per face to render and describe", "",
             "| held-out synthetic faces | mean RMS (mm) | median RMS (mm) | fit ms |", "|---|---|---|---|"]
    for k, r in report["synthetic"]["rows"].items():
        lines.append(f"| {k} | {r['mean_mm']:.2f} | {r['median_mm']:.2f} | {r['fit_ms']:.1f} |")
    if a.london != 0:
        m = fit_ridge(sets["train"]["descriptor"], sets["train"]["identity"])
        report["london"] = london_table(model, m, root, a.london)
        lines += ["", f"London: {report['london']['people']} people; dlib's detector and descriptor "
                  f"{report['london']['descriptor_ms_per_photo']:.0f} ms per photo, detection and the three fits "
                  f"{report['london']['ms_per_photo_all_rows']:.0f} ms", "",
                  "| London | within (mm) | between (mm) | identification |", "|---|---|---|---|"]
        for k, r in report["london"]["rows"].items():
            f = lambda x, fmt="{:.2f}": fmt.format(x) if x is not None else "-"     # noqa: E731
            lines.append(f"| {k} | {f(r['within_mm'])} | {f(r['between_median_mm'])} | "
                         f"{f(r['identification_rate'], '{:.1%}')} |")
    if a.james:
        m = fit_ridge(sets["train"]["descriptor"], sets["train"]["identity"])
        report["james"] = james_table(model, m, root)
        lines += ["", "| james vs scan (mm) | left photo | right photo | both |", "|---|---|---|---|"]
        lines += [f"| {k} | {r['left']:.2f} | {r['right']:.2f} | {r['both']:.2f} |"
                  for k, r in report["james"].items()]
    write_report(a.report, report, "\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
