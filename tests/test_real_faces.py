"""The real-photo pack format (neural.gar.real_faces): round trip, quantisation, mirror flips."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from neural.gar.real_faces import RealFaces, flip_faces, load_pack, save_pack  # noqa: E402


@pytest.fixture(scope="module")
def arrays():
    from neural.faces.renders import SyntheticFaces

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


def test_downsample_matches_a_render_at_the_lower_resolution():
    """A 32-px render area-downsampled to 16 px is the 16-px render with 2 x 2 supersampling
    of the same face: normals within a few degrees, coverage, landmarks to 0.01 px."""
    from neural.faces.renders import SyntheticFaces
    from neural.gar.real_faces import downsample_faces

    draw = SyntheticFaces(resolution=32).draw(np.random.default_rng(3))
    draw = {k: v for k, v in draw.items() if k != "tone"}
    big = SyntheticFaces(resolution=32, supersample=1).render(**draw)
    draw["background"] = draw["background"].reshape(16, 2, 16, 2, 3).mean((1, 3))
    small = SyntheticFaces(resolution=16, supersample=2).render(**draw)
    arrays = {"image": np.round(big["image"][None] * 255).astype(np.uint8),
              "normals": big["normals"][None].astype(np.float32),
              "mask": big["mask"][None].astype(np.float32),
              "landmarks": big["landmarks"][None].astype(np.float32)}
    d = downsample_faces(arrays, 16)
    assert d["image"].shape == (1, 16, 16, 3) and d["normals"].shape == (1, 16, 16, 3)
    np.testing.assert_allclose(d["landmarks"][0], small["landmarks"], atol=0.01)
    np.testing.assert_allclose(d["mask"][0], small["mask"], atol=1e-6)
    both = (np.abs(d["normals"][0]).sum(-1) > 0) & (np.abs(small["normals"]).sum(-1) > 0)
    assert both.sum() > 50
    assert np.median(angles_deg(d["normals"][0], small["normals"], both)) < 1.0
    np.testing.assert_allclose(np.linalg.norm(d["normals"][0][both], axis=-1), 1, atol=1e-5)
    assert downsample_faces(arrays, 32)["image"] is arrays["image"]


def test_real_faces_serves_a_pack_at_a_lower_resolution(arrays, tmp_path):
    from morphable.errors import InputError

    path = save_pack(tmp_path / "p.npz", arrays)
    faces = RealFaces(path, "all", flip=False, resolution=16)
    assert faces.resolution == 16
    b = faces.sample(3, rng=0)
    assert b["image"].shape == (3, 3, 16, 16) and b["normals"].shape == (3, 3, 16, 16)
    with pytest.raises(InputError, match="p.npz.*integer factor"):
        RealFaces(path, "all", resolution=12)
    with pytest.raises(InputError, match="p.npz.*integer factor"):
        RealFaces(path, "all", resolution=64)


def test_pack_with_normals_at_half_resolution(arrays, tmp_path):
    """normal_resolution=16 for 32-px crops: the stored normals and mask are 16 px, read back
    enlarged to 32 px as torch's bilinear interpolation does, unit length on the face."""
    import torch.nn.functional as F

    from neural.gar.real_faces import downsample_faces

    full = save_pack(tmp_path / "full.npz", arrays, normal_scale=127)
    half = save_pack(tmp_path / "half.npz", arrays, normal_scale=127, normal_resolution=16)
    assert half.stat().st_size < full.stat().st_size
    a = load_pack(half)
    assert a["normals"].shape == (4, 32, 32, 3) and a["mask"].shape == (4, 32, 32)
    np.testing.assert_array_equal(a["image"], load_pack(full)["image"])
    small = downsample_faces(arrays, 16)
    expect = F.interpolate(torch.as_tensor(small["mask"])[:, None], size=32, mode="bilinear",
                           align_corners=False)[:, 0].numpy()
    np.testing.assert_allclose(a["mask"], expect, atol=1 / 255 + 1e-6)
    on = np.abs(a["normals"]).sum(-1) > 0
    np.testing.assert_allclose(np.linalg.norm(a["normals"][on], axis=-1), 1, atol=1e-5)
    up = F.interpolate(torch.as_tensor(small["normals"]).permute(0, 3, 1, 2), size=32,
                       mode="bilinear", align_corners=False)
    up = torch.nn.functional.normalize(up, dim=1).permute(0, 2, 3, 1).numpy()
    inner = a["mask"] > 0.99
    assert np.percentile(angles_deg(a["normals"], up, inner), 99) < 1.0   # quantisation only
    with pytest.raises(Exception, match="integer factor"):
        save_pack(tmp_path / "bad.npz", arrays, normal_resolution=12)
    assert not (tmp_path / "bad.npz").exists()
