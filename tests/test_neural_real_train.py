"""GAR training on a pack of real photos (--data): the GPU recipe's flags on the CPU, resume
with the same weights, D's photos never G's, the landmark set, bad packs."""
import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("open3d")

ARGS = ["--config", "tiny", "--set", "resolution=32", "channel_base=256", "channel_max=32",
        "z_dim=16", "w_dim=16", "aux_width=4", "batch_size=2", "sample_every=3",
        "checkpoint_every=2", "r1_every=2", "print_every=1", "--untrained-aux", "--threads", "1",
        "--quiet"]


@pytest.fixture(scope="module")
def pack(tmp_path_factory, pack_maker):
    """A tiny pack made of 10 synthetic renders: 8 train photos of 6 people, 2 held out."""
    return pack_maker(tmp_path_factory.mktemp("pack") / "tiny.npz", n=10, resolution=32,
                          person=[0, 0, 1, 1, 2, 3, 4, 5, 6, 7], held_out=[False] * 8 + [True] * 2)


def _run(args, capsys):
    from neural.gar.train import main

    threads = torch.get_num_threads()
    try:
        rc = main(args)
    finally:
        torch.set_num_threads(threads)
    return rc, capsys.readouterr()


def _rows(out: Path) -> list:
    return [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]


def test_gpu_recipe_flags_on_cpu(pack, tmp_path, capsys):
    out = tmp_path / "gpu"
    rc, io = _run(ARGS + ["--data", str(pack), "--out", str(out), "--device", "cpu",
                          "--amp", "bf16", "--channels-last", "--max-steps", "2"], capsys)
    assert rc == 0, io.err
    gen = out / "generator.pt"
    assert gen.is_file() and gen.stat().st_size <= 16 * 2**20
    rows = _rows(out)
    assert [r["step"] for r in rows] == [1, 2]
    assert all(np.isfinite(v) for r in rows for v in r.values())
    assert {"n", "ldmk", "id", "adv", "d", "r1"} <= set(rows[0])
    lines = io.out.strip().splitlines()
    assert len(lines) == 3 and lines[-1].startswith("end: step 2/") and "img/s" in lines[-1]
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 2 and ckpt["config"]["augment"] == "color,translation,cutout"
    from neural.gar.networks import load_generator

    G = load_generator(gen)
    n = torch.zeros(1, 3, 32, 32)
    n[:, 2] = 1
    assert torch.isfinite(G(n, torch.randn(1, 16))).all()


def test_resumed_run_ends_with_the_same_weights(pack, tmp_path, capsys):
    common = ARGS + ["--data", str(pack), "--steps", "4"]
    full, part = tmp_path / "full", tmp_path / "part"
    assert _run(common + ["--out", str(full)], capsys)[0] == 0
    # stopped after 2 steps (its checkpoint, as after a kill), then the same command again
    assert _run(common + ["--out", str(part), "--max-steps", "2"], capsys)[0] == 0
    assert torch.load(part / "checkpoint.pt", weights_only=True)["step"] == 2
    assert _run(common + ["--out", str(part)], capsys)[0] == 0
    assert [r["step"] for r in _rows(part)] == [1, 2, 3, 4]
    a = torch.load(part / "checkpoint.pt", weights_only=True)
    b = torch.load(full / "checkpoint.pt", weights_only=True)
    assert a["step"] == b["step"] == 4
    for key in ("G", "D", "G_ema"):
        for name, value in a[key].items():
            torch.testing.assert_close(value, b[key][name], atol=1e-5, rtol=1e-4,
                                       msg=f"{key}.{name} differs after resume")
    for ra, rb in zip(_rows(part), _rows(full)):
        assert {k: v for k, v in ra.items() if k != "seconds"} == \
               pytest.approx({k: v for k, v in rb.items() if k != "seconds"}, rel=1e-4)


def test_discriminator_photos_are_other_people(pack, tmp_path):
    from neural.gar.auxnets import NAMES, load_aux
    from neural.gar.config import get_config
    from neural.gar.real_faces import RealFaces
    from neural.gar.train import Trainer

    cfg = get_config("tiny", resolution=32, channel_base=256, channel_max=32, z_dim=16,
                     w_dim=16, aux_width=4, batch_size=2)
    aux = {n: load_aux(n, pretrained=False, width=4) for n in NAMES}
    trainer = Trainer(cfg, tmp_path / "t", aux=aux, data=pack)
    assert trainer.config.augment == "color,translation,cutout"
    faces = RealFaces(pack, "train")
    photos = faces.batch(np.arange(len(faces)))["image"]
    mirrored = faces.batch(np.arange(len(faces)), np.ones(len(faces), bool))["image"]
    person = faces.arrays["person"]
    for step in range(6):
        trainer.step = step
        batch = trainer.data.sample(2, rng=[cfg.seed, step], pair=True)
        for img in trainer.real_images(batch):
            match = [i for i in range(len(faces))
                     if torch.equal(img, photos[i]) or torch.equal(img, mirrored[i])]
            assert match and not np.isin(person[match], batch["identity_id"].numpy()).any()


def test_landmark_set():
    from neural.gar.config import get_config
    from neural.gar.train import landmark_index

    class L:
        meta = {}

    cfg = get_config("tiny")
    model = landmark_index(cfg, L, real=False)
    assert len(model) == 50                                  # SFM's fixed landmarks
    assert len(landmark_index(cfg, L, real=True)) == 68      # real photos: all 68
    L.meta = {"training_data": "SyntheticFaces (SFM, procedural albedo, SH light)"}
    assert np.array_equal(landmark_index(cfg, L, real=True), model)
    L.meta = {"landmark_index": list(range(17, 68))}
    assert np.array_equal(landmark_index(cfg, L, real=True), np.arange(17, 68))
    assert len(landmark_index(get_config("tiny", landmark_set="all"), L, real=False)) == 68
    with pytest.raises(ValueError, match="landmark_set"):
        get_config("tiny", landmark_set="some")


def test_bad_pack_one_line_error(tmp_path, capsys):
    args = [a for a in ARGS if a != "--untrained-aux"]   # (whose warning is a line too)
    not_a_pack = tmp_path / "x.npz"
    not_a_pack.write_text("hello")
    for data, words in ((tmp_path / "missing.npz", "not found"), (not_a_pack, "not a readable")):
        out = tmp_path / "out"
        rc, io = _run(args + ["--data", str(data), "--out", str(out)], capsys)
        err = io.err.strip()
        assert rc == 2 and err.count("\n") == 0 and words in err and str(data) in err
        assert not out.exists()
    rc, io = _run(args + ["--data", str(not_a_pack), "--images", str(tmp_path), "--out",
                          str(tmp_path / "o")], capsys)
    assert rc == 2 and "--images" in io.err
    rc, io = _run(args + ["--out", str(tmp_path / "o"), "--set", "augment=zoom"], capsys)
    assert rc == 2 and "zoom" in io.err and io.err.strip().count("\n") == 0


def test_gar_gpu_recipe_on_cpu(tmp_path_factory, pack_maker, tmp_path):
    """The GPU recipe's one command, 1 step of each job on the CPU: the 64-px and 128-px GARs
    from one 128-px pack, their inverters, and the few flat files the device tool returns."""
    import subprocess
    import sys

    pack128 = pack_maker(tmp_path_factory.mktemp("pack128") / "p128.npz", n=10, resolution=128,
                         person=list(range(10)), held_out=[False] * 8 + [True] * 2)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "neural.gpu_recipe", "gar", "--data", str(pack128), "--out",
           str(out), "--runs", str(tmp_path / "runs"), "--device", "cpu", "--max-steps", "1",
           "--batch-size", "2", "--set", "channel_max=16", "z_dim=16", "w_dim=16"]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, (out / "log.txt").read_text()[-3000:] + run.stderr
    names = sorted(p.name for p in out.iterdir())
    assert names == ["gar_128.pt", "gar_64.pt", "gar_64_no_norm_cycle.pt", "inverter_128.pt",
                     "inverter_64.pt", "log.txt", "recipe.json"]
    assert all((out / n).stat().st_size <= 16 * 2**20 for n in names)
    report = json.loads((out / "recipe.json").read_text())
    assert set(report["jobs"]) == {"gar64", "gar128", "gar64_n0", "inv64", "inv128"}
    assert report["jobs"]["gar64_n0"]["summary"]["config"]["lambda_n"] == 0
    for side in (64, 128):
        job = report["jobs"][f"gar{side}"]
        s = job["summary"]
        assert job["returncode"] == 0 and s["step"] == 1 and s["images_seen"] == 2
        assert s["config"]["resolution"] == side and s["images_per_second"] > 0
        assert s["device"] == "cpu" and np.isfinite(list(s["losses_recent_mean"].values())).all()
        assert report["jobs"][f"inv{side}"]["metrics"]["steps"] == 1
    from neural.gar.renderer import GARRenderer

    r = GARRenderer(weights=out / "gar_128.pt", inverter=out / "inverter_128.pt")
    n = torch.zeros(1, 3, 128, 128)
    n[:, 2] = 1
    assert r.resolution == 128 and r.render(n, r.default_appearance(1)).shape == (1, 3, 128, 128)
    assert r.generator.config.aux_size == 64


def test_gpu_recipe_bad_pack_one_line(tmp_path):
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-m", "neural.gpu_recipe", "gar", "--data",
                          str(tmp_path / "none.npz"), "--out", str(tmp_path / "o")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and not (tmp_path / "o").exists()
    assert run.stderr.strip().count("\n") == 0 and "none.npz: pack not found" in run.stderr
