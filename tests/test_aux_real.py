"""The aux networks on real crops: metrics, fine-tuning on a pack, the report, face-FD
(tiny packs of synthetic renders; dlib on a few crops)."""
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from neural.gar.auxnets import build_aux, save_aux  # noqa: E402
from neural.gar.auxnets.metrics import landmark_errors, pair_rows, real_metrics, verification_auc
from neural.gar.real_faces import RealFaces, save_pack  # noqa: E402


@pytest.fixture(scope="module")
def renders():
    from neural.faces.renders import SyntheticFaces

    return SyntheticFaces(resolution=32).sample(12, rng=3)


@pytest.fixture(scope="module")
def pack(tmp_path_factory, renders):
    """12 crops of 6 people (two photos each); people 0 and 3 held out; sources 300w/aflw/london."""
    b = renders
    n = len(b["image"])
    img = np.round((b["image"].numpy().transpose(0, 2, 3, 1) + 1) * 127.5).astype(np.uint8)
    person = np.arange(n) // 2
    path = tmp_path_factory.mktemp("pack") / "tiny.npz"
    save_pack(path, {"image": img, "normals": b["normals"].numpy().transpose(0, 2, 3, 1),
                     "mask": b["mask"].numpy()[:, 0], "landmarks": b["landmarks"].numpy(),
                     "person": person, "held_out": person % 3 == 0,
                     "source": np.array(["300w"] * 4 + ["aflw"] * 4 + ["london"] * 4),
                     "name": np.array([f"p{i // 2}_{'ab'[i % 2]}.jpg" for i in range(n)])})
    return path


@pytest.fixture(scope="module")
def aux_dir(tmp_path_factory):
    torch.manual_seed(0)
    d = tmp_path_factory.mktemp("aux")
    for name in "NPLR":
        save_aux(build_aux(name, 4), name, d / f"aux_{name}.pt", width=4)
    return d


def test_verification_auc_and_landmark_errors():
    sim = np.array([[0.9, 0.1, 0.2], [0.3, 0.8, 0.0], [0.95, 0.1, 0.7]])
    v = verification_auc(sim)
    # same 0.9, 0.8, 0.7 against different 0.1 0.2 0.3 0.0 0.95 0.1: 5 of 6 below each
    assert v["auc"] == pytest.approx(5 / 6) and v["people"] == 3
    assert verification_auc(np.eye(1))["auc"] is None
    truth = np.zeros((2, 68, 2))
    truth[:, 45, 0] = 10.0                              # eye corners 10 px apart
    truth[1, :10] = np.nan                              # unknown points are left out
    pred = truth + np.array([3.0, 4.0])                 # 5 px everywhere
    e = landmark_errors(pred, truth)
    assert e["error_px"] == pytest.approx(5.0) and e["nme_percent"] == pytest.approx(50.0)
    assert e["crops"] == 2
    assert landmark_errors(pred, truth, index=[1, 2])["crops"] == 1


def test_pair_rows_and_real_metrics(pack, aux_dir):
    from neural.gar.auxnets import load_aux

    faces = RealFaces(pack, split="test", flip=False)
    rows = pair_rows(faces)
    assert rows.shape == (2, 2)
    assert (faces.arrays["person"][rows[:, 0]] == faces.arrays["person"][rows[:, 1]]).all()
    assert all(str(faces.arrays["name"][r]).endswith("_a.jpg") for r in rows[:, 0])
    nets = {n: load_aux(n, aux_dir / f"aux_{n}.pt", resolution=32) for n in "NPLR"}
    m = real_metrics(nets, faces, batch_size=3)
    assert 0 < m["N"]["normal_error_deg"] < 180 and set(m["N"]["by_source"]) == {"300w", "aflw"}
    assert 0 <= m["P"]["mask_iou"] <= 1
    assert m["L"]["ground_truth"]["crops"] == 2 and m["L"]["detected"]["crops"] == 2
    assert m["R"]["people"] == 2 and 0 <= m["R"]["identity_verification_auc"] <= 1


class _Oracle(torch.nn.Module):
    """N that returns a fixed normal map, P a fixed mask: what real_metrics must score 0 / 1."""

    def __init__(self, out):
        super().__init__()
        self.out = out

    def forward(self, image):
        return self.out[: len(image)]


def test_real_metrics_exact_labels(pack):
    faces = RealFaces(pack, split="test", flip=False)
    b = faces.batch(np.arange(len(faces)))
    m = real_metrics({"N": _Oracle(b["normals"]), "P": _Oracle((b["mask"] > 0.5).float())},
                     faces, batch_size=len(faces))
    assert m["N"]["normal_error_deg"] < 0.5          # the pack's quantisation only
    assert m["P"]["mask_iou"] == pytest.approx(1.0)


def test_fine_tune_on_pack(pack, aux_dir, tmp_path):
    from neural.gar.auxnets.train import AuxTrainer

    t = AuxTrainer(batch_size=4, lr=1e-2, nets="NPLR", pack=pack, init=aux_dir,
                   synthetic_share=0.25)
    assert t.widths == {n: 4 for n in "NPLR"} and len(t.real) == 8
    before = {n: [p.clone() for p in net.parameters()] for n, net in t.nets.items()}
    terms = t.train_step()
    assert set(terms) == set("NPLR") and all(np.isfinite(v) for v in terms.values())
    for n, net in t.nets.items():
        assert any(not torch.equal(a, b) for a, b in zip(before[n], net.parameters())), n
    metrics = t.validate(n=2)
    assert "ground_truth" in metrics["L"] and "synthetic" in metrics["N"]
    # people kept out of R's training: never drawn, measured on their own
    r = AuxTrainer(batch_size=4, nets="R", pack=pack, init=aux_dir, r_exclude_every=2)
    out = r.real.arrays["person"][r.r_excluded[:, 0]]
    assert len(out) == 2 and not np.isin(r.real.arrays["person"][r.r_rows], out).any()
    assert np.isfinite(r.train_step()["R"])
    assert r.excluded_verification()["people"] == 2
    paths = t.save(tmp_path, metrics)
    ck = torch.load(paths[0], weights_only=True)
    assert ck["width"] == 4 and "real pack" in ck["meta"]["training_data"]
    assert ck["meta"]["metrics"]["normal_error_deg"] == metrics["N"]["normal_error_deg"]


def test_fine_tune_cli_and_report(pack, aux_dir, tmp_path, data_dir):
    from evaluation.aux_real import main as report_main
    from neural.gar.auxnets.train import main as train_main

    assert train_main(["--data", str(pack), "--init", str(aux_dir), "--out", str(tmp_path / "ft"),
                       "--nets", "L", "--steps", "2", "--batch-size", "2", "--val-size", "2",
                       "-q"]) == 0
    out = tmp_path / "r.json"
    assert report_main(["--data", str(pack), "--report", str(out), "--aux-dir", str(aux_dir),
                        "--root", str(data_dir), "--aflw", "3", "--no-dlib", "--synthetic", "2",
                        "-q"]) == 0
    r = json.loads(out.read_text())
    assert r["held_out_crops"] == 4 and r["aflw2000"]["photos"] == 3
    assert np.isfinite(r["aflw2000"]["nme68"]["bins"][0]["nme_percent"])
    assert set(r["london"]) == {"R"} and r["london"]["R"]["all"]["people"] == 2
    assert set(r["synthetic"]) == set("NPLR")


def test_alignment_maps_landmarks_onto_the_template():
    from neural.gar.data import alignment
    from neural.faces.renders import template

    t = template(64)
    rot = np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    photo = 3 * t @ rot.T + [40, -7]
    A = alignment(photo)
    ok = np.isfinite(t[:, 0])
    assert np.allclose(photo[ok] @ A[:, :2].T + A[:, 2], t[ok], atol=1e-6)


def test_face_fd(renders):
    from evaluation.face_descriptor import as_uint8_images
    from evaluation.gar_quality import face_fd

    a = renders["image"][:6]
    u8 = as_uint8_images(a)
    assert u8.shape == (6, 32, 32, 3) and u8.dtype == np.uint8
    assert np.array_equal(as_uint8_images(u8), u8)
    same = face_fd(a, u8)
    shifted = face_fd(a, (a * 0.4 - 0.6).clamp(-1, 1))      # the same faces, dark and dull
    assert abs(same) < 1e-3
    assert shifted > 0.05
