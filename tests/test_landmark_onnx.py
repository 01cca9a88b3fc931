"""The landmark network without torch: numpy crops equal to the trainer's torch crops, the
exported ONNX graph on onnxruntime equal to the torch network on real photos (the committed
weights), the backend choice and its one-line errors, and no torch imported by detection or by
a default fit where onnxruntime runs the network."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from morphable.errors import InputError

REPO = Path(__file__).resolve().parents[1]
TOLERANCE = {"points_px": 1e-3, "sigma_relative": 1e-4, "probability": 1e-5}
"""onnxruntime against torch on the committed weights (measured on 20 AFLW2000-3D faces: points
1.9e-5 px, σ 4.8e-7 relative, probability 1.2e-8; ``python -m evaluation.bench_startup``)."""


def test_numpy_crops_equal_the_trainers_torch_crops():
    """sample_crops against grid_sample: upright and mirrored boxes, inside, across the edge and
    beyond it, on a random photo; a rotated crop is refused (it is the trainer's alone)."""
    torch = pytest.importorskip("torch")
    from neural.landmarks.cropping import crop_theta, sample_crops
    from neural.landmarks.network import crop_images

    rng = np.random.default_rng(0)
    img = rng.uniform(-1, 1, (90, 130, 3)).astype(np.float32)
    boxes = np.array([[20.3, 5.1, 100.2, 85.0], [-30, -20, 60, 70], [100, 50, 200, 150], [300, 300, 340, 340.0]])
    theta = crop_theta(boxes, (130, 90), flip=[False, True, False, True])
    mine = sample_crops(img, theta, 64)
    theirs = crop_images(torch.from_numpy(img).permute(2, 0, 1)[None].expand(4, -1, -1, -1), theta, 64).numpy()
    assert np.abs(mine - theirs).max() < 1e-4
    assert np.abs(mine[3]).max() == 0                      # wholly outside: zeros
    with pytest.raises(ValueError, match="rotated"):
        sample_crops(img, crop_theta(boxes[:1], (130, 90), angle=[0.3]), 64)


def test_onnxruntime_reads_real_photos_as_torch_does(data_dir):
    """The committed weights on both backends, each photo read in a face box, a box twice as
    large and a box away from the face: the same points, σ and face probability within
    TOLERANCE."""
    pytest.importorskip("torch")
    pytest.importorskip("onnxruntime")
    from morphable.detection.images import read_image
    from morphable.io.landmark_files import read_pts
    from neural.landmarks.detector import WEIGHTS_FILE, NetworkDetector, framing_box
    from neural.landmarks.runtime import onnx_path

    if not onnx_path(WEIGHTS_FILE).is_file():
        pytest.skip("no exported graph beside the weights")
    dets = [NetworkDetector(backend=b) for b in ("torch", "onnxruntime")]
    assert [d.network.backend for d in dets] == ["torch", "onnxruntime"]
    for name in ("image_0010.png", "einstein.jpg", "breakingbad.jpg", "takeo.ppm"):
        photo = data_dir / "images" / name
        img = read_image(photo)
        truth = read_pts(photo.with_suffix(".pts"))
        face = framing_box(np.r_[truth.min(0), truth.max(0)], "box")
        side = face[2] - face[0]
        boxes = np.array([face, face + [-side / 2, -side / 2, side / 2, side / 2], face + side])
        a, b = (d.refine(img, boxes) for d in dets)
        assert a["probability"][0] > 0.5 > a["probability"][2]         # a face and not one
        assert np.abs(a["points"] - b["points"]).max() < TOLERANCE["points_px"], name
        assert np.abs(b["sigma_px"] / a["sigma_px"] - 1).max() < TOLERANCE["sigma_relative"], name
        assert np.abs(a["probability"] - b["probability"]).max() < TOLERANCE["probability"], name


def test_backend_choice_and_its_one_line_errors(tmp_path, monkeypatch):
    from neural.landmarks import runtime

    pt, graph = tmp_path / "w.pt", tmp_path / "w.onnx"
    with pytest.raises(InputError, match="choose from auto, onnxruntime, torch"):
        runtime.choose_backend(pt, "tensorflow")
    monkeypatch.setattr(runtime, "_installed", lambda m: True)
    with pytest.raises(InputError, match=r"w\.pt: landmark network weights not found"):
        runtime.choose_backend(pt)
    pt.write_bytes(b"x")
    assert runtime.choose_backend(pt) == "torch"               # no graph beside the weights
    graph.write_bytes(b"not an onnx graph")
    assert runtime.choose_backend(pt) == "onnxruntime" and runtime.choose_backend(pt, "torch") == "torch"
    assert runtime.choose_backend(graph) == "onnxruntime"
    monkeypatch.setattr(runtime, "_installed", lambda m: m == "torch")
    assert runtime.choose_backend(pt) == "torch"
    with pytest.raises(InputError, match="onnxruntime is not installed"):
        runtime.choose_backend(graph)
    monkeypatch.setattr(runtime, "_installed", lambda m: m == "onnxruntime")
    with pytest.raises(InputError, match="torch is not installed"):
        runtime.choose_backend(pt, "torch")
    graph.unlink()
    with pytest.raises(InputError, match="neither onnxruntime with w.onnx beside the weights nor torch"):
        runtime.choose_backend(pt)


def test_broken_or_stale_graph_is_one_line(tmp_path):
    pytest.importorskip("onnxruntime")
    from neural.landmarks import runtime
    from neural.landmarks.detector import WEIGHTS_FILE, NetworkDetector

    graph = tmp_path / "w.onnx"
    graph.write_bytes(b"not an onnx graph")
    with pytest.raises(InputError, match=r"w\.onnx: not an exported landmark network") as e:
        NetworkDetector(graph)
    assert "\n" not in str(e.value)
    committed = runtime.onnx_path(WEIGHTS_FILE)
    if not committed.is_file():
        pytest.skip("no exported graph beside the weights")
    (tmp_path / "w.pt").write_bytes(b"other weights")
    graph.write_bytes(committed.read_bytes())
    with pytest.raises(InputError, match=r"w\.onnx was exported from other weights than .*w\.pt: export again"):
        NetworkDetector(tmp_path / "w.pt", backend="onnxruntime")
    assert NetworkDetector(graph).network.resolution == 128     # the graph alone: no check


@pytest.mark.slow
def test_export_round_trip_of_a_tiny_network(tmp_path):
    """python -m neural.landmarks.export on a tiny network: the graph on onnxruntime gives the
    torch network's outputs for any batch size, its metadata the config; its weights stored
    as float16 (``--fp16``) keep the answers to float16's precision."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("onnx")
    pytest.importorskip("onnxscript")
    pytest.importorskip("onnxruntime")
    from neural.landmarks.export import compare, main, weights_to_fp16
    from neural.landmarks.network import LandmarkConfig, LandmarkNet, save_landmark_net
    from neural.landmarks.runtime import OnnxNetwork

    torch.manual_seed(0)
    net = LandmarkNet(LandmarkConfig(widths=(4, 4, 4, 4, 4), blocks=(0, 0, 1, 0, 0), hidden=8))
    torch.nn.init.normal_(net.head[-1].weight, std=0.01)
    save_landmark_net(net, tmp_path / "tiny.pt")
    assert main(["--weights", str(tmp_path / "tiny.pt")]) == 0
    diff = compare(tmp_path / "tiny.pt", tmp_path / "tiny.onnx", n=3)
    assert max(diff.values()) < 1e-5, diff
    ort = OnnxNetwork(tmp_path / "tiny.onnx", source=tmp_path / "tiny.pt")
    assert ort.config["widths"] == [4, 4, 4, 4, 4] and ort(np.zeros((5, 3, 128, 128), np.float32))["points"].shape == (5, 546, 2)
    import onnx

    model = onnx.load(str(tmp_path / "tiny.onnx"))
    weights_to_fp16(model)
    onnx.save(model, str(tmp_path / "half.onnx"))
    assert 0 < max(compare(tmp_path / "tiny.pt", tmp_path / "half.onnx", n=3).values()) < 1e-2


CHECK = ("import sys\n"
         "import morphable.detection as d\n"
         "assert 'torch' not in sys.modules, 'import'\n"
         "{body}\n"
         "print(sorted(m for m in ('torch', 'trimesh', 'scipy', 'matplotlib') if m in sys.modules))\n")


def _run(body: str, tmp_path) -> str:
    import os

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO)] + os.environ.get("PYTHONPATH", "").split(os.pathsep))}
    env.pop("MORPHABLE_LANDMARK_WEIGHTS", None)
    out = subprocess.run([sys.executable, "-c", CHECK.format(body=body)], cwd=tmp_path, capture_output=True,
                         text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


def test_default_fit_imports_no_torch_where_onnxruntime_runs_the_network(data_dir, tmp_path):
    """``morphable fit PHOTO`` with the default detector: the fused detector ran (its report
    says so), and neither torch nor trimesh, scipy or matplotlib (mediapipe's drawing
    utilities) was imported for it."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("mediapipe")
    from morphable.detection import plugins
    from neural.landmarks.detector import WEIGHTS_FILE
    from neural.landmarks.runtime import onnx_path

    if "network" not in plugins.entry_points() or not onnx_path(WEIGHTS_FILE).is_file():
        pytest.skip("the network plugin or its exported graph is not installed here")
    photo = data_dir / "images" / "image_0010.png"
    body = ("from morphable.cli import main\n"
            f"rc = main(['fit', {str(photo)!r}, '--out-mesh', 'x.obj', '--report', 'x.json'])\n"
            "assert rc in (0, None), rc")
    assert _run(body, tmp_path) == "[]"
    import json

    report = json.loads((tmp_path / "x.json").read_text())
    assert "+ facemesh" in json.dumps(report)
    assert (tmp_path / "x.obj").read_text().startswith("v ")
