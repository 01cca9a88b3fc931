"""Shared fixtures: the read-only data beside the repository (../shared/data).

The suite tests this checkout with ../shared beside it, whatever the caller's environment says:
every ``MORPHABLE_*`` variable (``MORPHABLE_DATA``, ``MORPHABLE_LANDMARK_WEIGHTS``,
``MORPHABLE_GAR_WEIGHTS``, the notebooks' ``MORPHABLE_SHARED_DATA`` and
``MORPHABLE_NOTEBOOK_OUT``) is removed before any test runs, for the tests and the commands they
start. Models are then found in ../shared/data/models (:mod:`morphable.io.registry`), the
weights are the committed ones; a test that wants a variable sets it with monkeypatch."""
import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"

for _name in [k for k in os.environ if k.startswith("MORPHABLE_")]:
    del os.environ[_name]


@pytest.fixture(scope="session")
def data_dir() -> Path:
    if not DATA.is_dir():
        pytest.skip(f"shared data not found at {DATA}")
    return DATA


@pytest.fixture(scope="session")
def sfm():
    from morphable import load_model

    return load_model("sfm")


@pytest.fixture(scope="session")
def ict():
    from morphable import load_model

    return load_model("ict")


def make_tiny_pack(path, n: int = 8, resolution: int = 16, seed: int = 0, person=None,
                   held_out=None):
    """A neural.gar.real_faces pack of ``n`` synthetic SFM renders standing in for real photos in
    tests (default: two photos per person, every fourth person held out); returns the path."""
    import numpy as np

    from neural.faces.renders import SyntheticFaces
    from neural.gar.real_faces import save_pack

    faces = SyntheticFaces(resolution=resolution)
    rng = np.random.default_rng(seed)
    renders = [faces.render(**{k: v for k, v in faces.draw(rng).items() if k != "tone"})
               for _ in range(n)]
    person = np.arange(n) // 2 if person is None else np.asarray(person)
    held_out = person % 4 == 3 if held_out is None else np.asarray(held_out, bool)
    arrays = {"image": np.stack([np.round(r["image"] * 255).astype(np.uint8) for r in renders]),
              "normals": np.stack([r["normals"] for r in renders]),
              "mask": np.stack([r["mask"] for r in renders]),
              "landmarks": np.stack([r["landmarks"] for r in renders]).astype(np.float32),
              "person": person, "held_out": held_out,
              "source": np.array(["synthetic"] * n), "name": np.array([f"{i}.png" for i in range(n)]),
              "fit_pose": rng.uniform(-30, 30, (n, 3))}
    return save_pack(path, arrays)


@pytest.fixture(scope="session")
def tiny_pack(tmp_path_factory):
    """Path of a 16 px pack of 8 synthetic crops (:func:`make_tiny_pack`)."""
    pytest.importorskip("torch")
    return make_tiny_pack(tmp_path_factory.mktemp("pack") / "tiny.npz")


@pytest.fixture(scope="session")
def pack_maker():
    """:func:`make_tiny_pack`, for tests that need a pack of their own layout."""
    pytest.importorskip("torch")
    return make_tiny_pack
