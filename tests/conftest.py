import os
from pathlib import Path

import pytest

import fabrax  # noqa: F401  (sets XLA flags before jax loads)
from fabrax import config
from fabrax.robot import build_robot


def data_dir() -> Path | None:
    """The MotionBenchMaker/sphere data folder from $FABRAX_DATA, if present."""
    path = os.environ.get("FABRAX_DATA")
    return Path(path) if path and Path(path).is_dir() else None


@pytest.fixture(scope="session")
def panda():
    return build_robot(config.load("robot", "panda"))


@pytest.fixture
def shared_data():
    path = data_dir()
    if path is None:
        pytest.skip("FABRAX_DATA is not set to the shared data folder (../shared/data)")
    return path
