"""The 3DDFA-V2 peer (evaluation.peers_3ddfa): its loader on synthetic files of the released
layout, its crop and camera conventions, the benchmark's one-line skip without its files, and
(only where $MORPHABLE_3DDFA_DIR holds the released files) real photos' landmarks."""
import json
import pickle

import numpy as np
import pytest

from evaluation import peers_3ddfa as peer
from morphable.errors import InputError

# MobileNet-V1's blocks at width 1: (name, input channels, output channels), as released
LAYOUT = [("dw2_1", 32, 64), ("dw2_2", 64, 128), ("dw3_1", 128, 128), ("dw3_2", 128, 256),
          ("dw4_1", 256, 256), ("dw4_2", 256, 512)] + [(f"dw5_{i}", 512, 512) for i in range(1, 6)] + \
         [("dw5_6", 512, 1024), ("dw6", 1024, 1024)]


def released_state(widen: float, seed: int = 0) -> dict:
    """A state dict with the released checkpoint's keys and shapes at width ``widen`` (random
    values; the released one is width 0.5: 166 entries)."""
    import torch

    g = torch.Generator().manual_seed(seed)

    def bn(prefix, c):
        return {f"{prefix}.weight": 1 + 0.1 * torch.rand(c, generator=g),
                f"{prefix}.bias": 0.1 * torch.randn(c, generator=g),
                f"{prefix}.running_mean": 0.1 * torch.randn(c, generator=g),
                f"{prefix}.running_var": 1 + torch.rand(c, generator=g),
                f"{prefix}.num_batches_tracked": torch.tensor(7)}

    c = lambda n: int(n * widen)                              # noqa: E731
    s = {"conv1.weight": 0.2 * torch.randn(c(32), 3, 3, 3, generator=g), **bn("bn1", c(32))}
    for name, cin, cout in LAYOUT:
        s[f"{name}.conv_dw.weight"] = 0.3 * torch.randn(c(cin), 1, 3, 3, generator=g)
        s.update(bn(f"{name}.bn_dw", c(cin)))
        s[f"{name}.conv_sep.weight"] = torch.randn(c(cout), c(cin), 1, 1, generator=g) / c(cin) ** 0.5
        s.update(bn(f"{name}.bn_sep", c(cout)))
    s.update({"fc_param.weight": 0.01 * torch.randn(62, c(1024), generator=g),
              "fc_param.bias": torch.randn(62, generator=g),
              "fc_lm.weight": torch.randn(136, c(1024), generator=g),
              "fc_lm.bias": torch.randn(136, generator=g)})
    return {f"module.{k}": v for k, v in s.items()}


def test_synthetic_layout_is_the_released_one():
    pytest.importorskip("torch")
    s = released_state(0.5)
    assert len(s) == 166                       # the released mb05_120x120.pth's entries
    assert tuple(s["module.dw5_6.conv_sep.weight"].shape) == (512, 256, 1, 1)
    assert tuple(s["module.fc_param.weight"].shape) == (62, 512)
    assert tuple(s["module.fc_lm.weight"].shape) == (136, 512)


def test_loader_maps_the_released_keys(tmp_path):
    torch = pytest.importorskip("torch")
    state = released_state(0.25)
    state["module.fc_param.weight"] = torch.zeros_like(state["module.fc_param.weight"])
    torch.save({"epoch": 3, "state_dict": state}, tmp_path / "w.pth")
    net = peer.load_weights(tmp_path / "w.pth")
    assert not net.training and net.conv1.out_channels == 8
    # the parameter head is fc_param: with its weights zero the output is its bias
    out = net(torch.randn(2, 3, 120, 120)).detach()
    np.testing.assert_allclose(out, state["module.fc_param.bias"].expand(2, -1), atol=1e-6)
    np.testing.assert_array_equal(net.dw4_2.bn_sep.running_var, state["module.dw4_2.bn_sep.running_var"])

    del state["module.dw3_1.bn_dw.bias"]
    torch.save({"epoch": 3, "state_dict": state}, tmp_path / "broken.pth")
    with pytest.raises(InputError, match=r"broken\.pth: not the layout.*dw3_1\.bn_dw\.bias"):
        peer.load_weights(tmp_path / "broken.pth")
    (tmp_path / "text.pth").write_text("not a checkpoint")
    with pytest.raises(InputError, match=r"text\.pth: not a 3DDFA-V2 checkpoint"):
        peer.load_weights(tmp_path / "text.pth")


def test_keypoint_bases_from_the_pickle_and_the_text_files_agree(tmp_path):
    rng = np.random.default_rng(0)
    n = 500
    vertex = rng.choice(n, 68, replace=False)
    rows = (3 * vertex[:, None] + np.arange(3)).ravel()              # x, y, z of each keypoint
    bfm = {"u": rng.normal(0, 1e4, (3 * n, 1)).astype(np.float32),
           "w_shp": rng.normal(0, 1e3, (3 * n, 45)).astype(np.float32),
           "w_exp": rng.normal(0, 1e3, (3 * n, 12)).astype(np.float32), "keypoints": rows}
    (tmp_path / "pkl").mkdir()
    with open(tmp_path / "pkl" / peer.BFM_FILE, "wb") as f:
        pickle.dump(bfm, f)
    (tmp_path / "txt").mkdir()
    released = (bfm["u"][rows], bfm["w_shp"][rows, :40], bfm["w_exp"][rows, :10])
    for name, a in zip(peer.KEYPOINT_FILES, released):
        np.savetxt(tmp_path / "txt" / name, a, fmt="%.6f")
    a, b = peer.load_keypoint_bases(tmp_path / "pkl"), peer.load_keypoint_bases(tmp_path / "txt")
    assert a["mean"].shape == (68, 3) and a["shape"].shape == (68, 3, 40)
    assert a["expression"].shape == (68, 3, 10)
    np.testing.assert_allclose(a["mean"][5], bfm["u"][3 * vertex[5]:3 * vertex[5] + 3, 0], rtol=1e-6)
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-5, atol=1e-3)

    np.savetxt(tmp_path / "txt" / "w_exp_base.txt", bfm["w_exp"][rows, :9])
    with pytest.raises(InputError, match=r"u_base\.txt: expected 204 keypoint rows"):
        peer.load_keypoint_bases(tmp_path / "txt")


def test_pickles_build_arrays_and_nothing_else(tmp_path):
    class Evil:
        def __reduce__(self):
            return (print, ("ran",))

    with open(tmp_path / peer.PARAM_STATS_FILE, "wb") as f:
        pickle.dump({"mean": Evil(), "std": np.ones(62)}, f)
    with pytest.raises(InputError, match=r"not a pickle of arrays \(builtins\.print"):
        peer.load_param_stats(tmp_path / peer.PARAM_STATS_FILE)
    with open(tmp_path / peer.PARAM_STATS_FILE, "wb") as f:
        pickle.dump({"mean": np.arange(62, dtype=np.float32), "std": np.ones(62, np.float32)}, f)
    mean, std = peer.load_param_stats(tmp_path / peer.PARAM_STATS_FILE)
    np.testing.assert_array_equal(mean, np.arange(62))


def test_crop_and_camera_conventions():
    torch = pytest.importorskip("torch")
    h = 50 * 2 ** 0.5
    np.testing.assert_allclose(peer.crop_box([150, 75, 250, 125]), [200 - h, 100 - h, 200 + h, 100 + h])
    img = np.random.default_rng(1).integers(0, 256, (200, 180, 3), dtype=np.uint8)
    x = peer.crop(img, np.array([100.0, 20.0, 220.0, 140.0]))          # 120 px: no resampling
    assert x.shape == (1, 3, 120, 120) and x.dtype == torch.float32
    inside = img[20:140, 100:180, ::-1].transpose(2, 0, 1)             # BGR
    np.testing.assert_allclose(x[0, :, :, :80], (inside - 127.5) / 128)
    np.testing.assert_allclose(x[0, :, :, 80:], -127.5 / 128)          # black beyond the photo
    assert peer.crop(img, np.array([0.0, 0.0, 360.0, 400.0])).shape == (1, 3, 120, 120)

    # the camera: scaled identity and an offset; crop frame 1-based with y up
    bases = {"mean": np.random.default_rng(2).normal(0, 1, (68, 3)), "shape": np.ones((68, 3, 40)),
             "expression": np.ones((68, 3, 10))}
    p = np.zeros(62)
    p[:12] = [2, 0, 0, 5, 0, 2, 0, 6, 0, 0, 2, 7]
    np.testing.assert_allclose(peer.keypoints_in_crop(p, bases), 2 * bases["mean"] + [5, 6, 7])
    roi = np.array([10.0, 20.0, 250.0, 260.0])                         # 2 px per crop px
    np.testing.assert_allclose(peer.crop_to_image([[1, 120, 0], [121, 0, 0], [61, 60, 3]], roi),
                               [[10, 20], [250, 260], [130, 140]])


def test_unavailable_says_why(tmp_path, monkeypatch):
    monkeypatch.delenv(peer.DIR_ENV, raising=False)
    assert "no folder" in peer.unavailable()
    assert "lacks mb05_120x120.pth; param_mean_std" in peer.unavailable(tmp_path)
    for name in (peer.WEIGHTS_FILE, peer.PARAM_STATS_FILE, *peer.KEYPOINT_FILES):
        (tmp_path / name).write_text("")
    monkeypatch.setenv(peer.DIR_ENV, str(tmp_path))
    assert peer.unavailable() is None or "torch" in peer.unavailable()


def test_benchmark_skips_the_peer_with_one_line(data_dir, tmp_path, monkeypatch, capsys):
    from evaluation.bench_alignment import main

    monkeypatch.delenv(peer.DIR_ENV, raising=False)
    main(["--set", "aflw2000", "--n", "1", "--methods", "3ddfa-v2", "--report", str(tmp_path / "r.json"), "-q"])
    out = capsys.readouterr().out
    said = [line for line in out.splitlines() if "3ddfa-v2" in line]
    assert said == ["3ddfa-v2: skipped, no folder of its released files (--3ddfa-dir or $MORPHABLE_3DDFA_DIR)"]
    assert json.loads((tmp_path / "r.json").read_text())["aflw2000"]["methods"] == {}
    main(["--set", "aflw2000", "--n", "1", "--methods", "3ddfa-v2", "--3ddfa-dir", str(tmp_path),
          "--report", str(tmp_path / "r.json"), "-q"])
    assert capsys.readouterr().out.startswith(f"3ddfa-v2: skipped, {tmp_path} lacks mb05_120x120.pth")


@pytest.mark.skipif(peer.unavailable() is not None,
                    reason="no released 3DDFA-V2 files ($MORPHABLE_3DDFA_DIR)")
def test_real_photos_landmarks_within_a_bound(data_dir):
    from evaluation.bench_alignment import box_size, dataset_boxes, nme
    from morphable.detection.images import read_image
    from morphable.io.landmark_files import read_pts

    import torch

    released = torch.load(peer.peer_dir() / peer.WEIGHTS_FILE, map_location="cpu",
                          weights_only=True)["state_dict"]
    assert {k: tuple(v.shape) for k, v in released.items()} == \
        {k: tuple(v.shape) for k, v in released_state(0.5).items()}
    model = peer.ThreeDDFA()
    # the released network's error on these two annotated photos with the box of their points
    # is 3.7 and 2.8 % of sqrt(w h); a wrong crop, channel order or camera convention is several times that
    for name in ("image_0010.png", "takeo.ppm"):
        path = data_dir / "images" / name
        gt = read_pts(path.with_suffix(".pts"))[None]
        pred = model.ibug68(read_image(path), dataset_boxes(gt)[0])[None]
        assert nme(pred, gt, box_size(gt))[0] < 5.0, name
