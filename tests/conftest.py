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
def free_port() -> int:
    """A TCP port on the loopback that nothing listens on (for a viewer under test)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def shared_data():
    path = data_dir()
    if path is None:
        pytest.skip("FABRAX_DATA is not set to the shared data folder (../shared/data)")
    return path


@pytest.fixture(scope="session")
def box_on_hand():
    """A function (env, state) -> state with a 0.2 m cube in the first cuboid slot, centred on the hand."""
    import jax.numpy as jnp

    from fabrax.robot.kinematics import frame_pose

    def place(env, state):
        ep = state.pipeline_state
        hand = frame_pose(env.robot, ep.q, env.fabric.goal_frame).translation()
        c = ep.scene.cuboids
        box = c.replace(center=c.center.at[0].set(hand), half_extents=c.half_extents.at[0].set(jnp.full(3, 0.1)), mask=c.mask.at[0].set(True))
        return state.replace(pipeline_state=ep.replace(scene=ep.scene.replace(cuboids=box)))

    return place
