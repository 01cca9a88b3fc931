"""Shared fixtures: the read-only data beside the repository (../shared/data)."""
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"


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
