"""The real-photo pack format (neural.real_faces): round trip, quantisation, mirror flips."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from neural.real_faces import RealFaces, flip_faces, load_pack, save_pack  # noqa: E402


@pytest.fixture(scope="module")
def arrays():
    from neural.data import SyntheticFaces

    faces = SyntheticFaces(resolution=32, supersample=1)
    rng = np.random.default_rng(0)
    draws = [faces.draw(rng) for _ in range(4)]
    rs = [faces.render(**{k: v for k, v in d.items() if k != "tone"}) for d in draws]
    return {"image": np.stack([np.round(r["image"] * 255).astype(np.uint8) for r in rs]),
            "normals": np.stack([r["normals"] for r in rs]).astype(np.float32),
            "mask": np.stack([r["mask"] for r in rs]).astype(np.float32),
            "landmarks": np.stack([r["landmarks"] for r in rs]).astype(np.float32),
            "person": np.array([0, 0, 1, 2]), "held_out": np.array([False, False, False, True]),
            "source": np.array(["synthetic"] * 4), "name": np.array(list("abcd")),
            "fit_pose": rng.uniform(-30, 30, (4, 3)).astype(np.float32)}


def angles_deg(a, b, on):
    return np.degrees(np.arccos(np.clip((a[on] * b[on]).sum(-1), -1, 1)))


@pytest.mark.parametrize("scale, mean_max, p99_max", [(127, 0.35, 1.2), (64, 0.7, 2.5)])
def test_round_trip_within_the_quantisation_bound(arrays, tmp_path, scale, mean_max, p99_max):
    back = load_pack(save_pack(tmp_path / "p.npz", arrays, jpeg_quality=90, normal_scale=scale))
    on = np.abs(arrays["normals"]).sum(-1) > 0
    assert np.array_equal(on, np.abs(back["normals"]).sum(-1) > 0)      # background stays zero
    ang = angles_deg(arrays["normals"], back["normals"], on)
    assert ang.mean() < mean_max and np.percentile(ang, 99) < p99_max, (ang.mean(), np.percentile(ang, 99))
    assert np.allclose(np.linalg.norm(back["normals"][on], axis=-1), 1, atol=1e-5)
    assert np.abs(back["mask"] - arrays["mask"]).max() <= 0.5 / 255 + 1e-6
    assert np.abs(back["image"].astype(float) - arrays["image"]).mean() < 4
    for k in ("landmarks", "person", "held_out", "source", "name", "fit_pose"):
        assert np.array_equal(back[k], arrays[k], equal_nan=k == "landmarks"), k


def test_flip_twice_is_the_identity_and_mirrors(arrays):
    a = [arrays[k] for k in ("image", "normals", "mask", "landmarks")]
    once = flip_faces(*a)
    twice = flip_faces(*once)
    for x, y in zip(a[:3], twice[:3]):
        assert np.array_equal(x, y)
    assert np.allclose(a[3], twice[3], atol=1e-5, equal_nan=True)    # R - 1 - (R - 1 - x)
    R = a[0].shape[2]
    assert np.array_equal(once[1][..., 0], -a[1][:, :, ::-1, 0])          # x negated
    assert np.array_equal(once[1][..., 1:], a[1][:, :, ::-1, 1:])
    # the subject's right eye corner (36) of the flip is the mirror of the left one (45)
    assert np.allclose(once[3][:, 36, 0], R - 1 - a[3][:, 45, 0])
    assert np.allclose(once[3][:, 36, 1], a[3][:, 45, 1])


def test_real_faces_batches_split_and_partner(arrays, tmp_path):
    path = save_pack(tmp_path / "p.npz", arrays)
    train, test = RealFaces(path, "train"), RealFaces(path, "test")
    assert (len(train), len(test)) == (3, 1)
    b = train.sample(8, rng=0, pair=True)
    assert b["image"].shape == (8, 3, 32, 32) and b["normals_b"].shape == (8, 3, 32, 32)
    assert float(b["image"].min()) >= -1 and float(b["image"].max()) <= 1
    other, mirrored = train.partner(np.array([0, 1, 2]), np.random.default_rng(0))
    assert other.tolist() == [1, 0, 2] and mirrored.tolist() == [False, False, True]
