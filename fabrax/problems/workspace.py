"""Problems drawn for the Panda, carried into another arm's workspace.

The generators (MBM-like, MPiNets-like, the demo) pose scenes and goal poses for the Panda: its
reach and its tool centre point (`PANDA_TOOL` along `panda_hand`'s z). For another arm the scene
is scaled about the base by the ratio of the arms' reaches (`workspace_reach`) and each goal pose
is moved along its approach axis so that the arm's own tool centre point (`Robot.tool_length`
along its `ee_frame`) lands where the scaled Panda's would.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from fabrax.robot.kinematics import frame_path
from fabrax.robot.robot import Robot

PANDA_TOOL = 0.1034  # m from panda_hand to the Panda's tool centre point: the scenes' goal poses are the Panda's
PANDA_REACH = 0.8621  # m, `workspace_reach` of the Panda's tool centre point: the scale the scenes are drawn at


def workspace_reach(robot: Robot, frame: str, samples: int = 4096) -> float:
    """How far the tool centre point (`tool_length` along `frame`'s z) gets from the base's vertical
    axis: the 95th percentile over `samples` configurations drawn uniformly within the limits
    (seeded, so a robot's value is fixed). The scenes are drawn for the Panda and scaled by the
    ratio of this to `PANDA_REACH` for another arm."""
    q = np.random.default_rng(0).uniform(np.asarray(robot.lower), np.asarray(robot.upper), (samples, robot.dof))
    pos, quat = frame_path(robot, jnp.asarray(q, jnp.float32), frame)
    tcp = np.asarray(pos) + robot.tool_length * _z_axis(np.asarray(quat))
    return float(np.percentile(np.linalg.norm(tcp[:, :2], axis=1), 95))


def _z_axis(wxyz: np.ndarray) -> np.ndarray:
    """The rotated z axis (..., 3) of unit quaternions (..., 4), wxyz."""
    w, x, y, z = np.moveaxis(np.asarray(wxyz, float), -1, 0)
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], -1)


def panda_workspace(robot: Robot, frame: str) -> tuple[float, float] | None:
    """(scale, tool length) that carry the Panda's scenes into `robot`'s workspace, or None for an
    arm within 2 % of the Panda's reach with the Panda's tool (the scenes as drawn)."""
    scale = workspace_reach(robot, frame) / PANDA_REACH
    if abs(scale - 1.0) < 0.02 and abs(robot.tool_length - PANDA_TOOL) < 1e-3:
        return None
    return scale, robot.tool_length


def carry(scene_dict: dict, goals: list, scale: float, tool: float) -> tuple[dict, list]:
    """A scene scaled about the base by `scale`, and its goal poses moved so that the robot's tool
    centre point lands where the scaled Panda's would (the hand's orientation is kept)."""
    obstacles = []
    for o in scene_dict["obstacles"]:
        o = dict(o, center=[scale * float(v) for v in o["center"]])
        for key in ("size", "radius", "length"):
            if key in o:
                o[key] = [scale * float(v) for v in o[key]] if isinstance(o[key], list) else scale * float(o[key])
        obstacles.append(o)
    moved = []
    for position, quat in goals:
        z = _z_axis(quat)
        moved.append((scale * (np.asarray(position) + PANDA_TOOL * z) - tool * z, quat))
    return {**scene_dict, "obstacles": obstacles}, moved
