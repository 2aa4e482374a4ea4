"""Procedurally generated problem classes that need no data files.

MBM-like (joint goals, start at the ready posture unless the class says
otherwise, after MotionBenchMaker): table_pick (objects on a table, grasp one
from above), table_under_pick (start under the table, grasp above it), box (an
open box, reach inside), bookshelf (reach into a shelf cell), cage (an object
inside a cage of bars).

MPiNets-like (end-effector pose goals of `panda_hand`, after the Motion Policy
Networks data description: cubbies, merged cubbies, dressers with open
drawers, cluttered tabletops): cubby, merged_cubby, dresser, tabletop.
Starts are valid configurations near the ready posture.

Every scene is randomised (pose, size, clutter) from a seeded generator; goal
configurations come from the project's IK (`robot.ik.solve_ik`) and must be
collision-free with a margin, so every problem is valid by construction.
Deterministic per seed.
"""

from __future__ import annotations

import zlib

import jax.numpy as jnp
import numpy as np

from fabrax.problems.generators import ik_configs, sample_configs
from fabrax.problems.problem import Problem, make_problem
from fabrax.problems.workspace import carry, panda_workspace
from fabrax.robot.kinematics import frame_path
from fabrax.robot.robot import Robot
from fabrax.scene import COMMON_CAPACITY, from_dict

MBM_LIKE = ("table_pick", "table_under_pick", "box", "bookshelf", "cage")
MPINETS_LIKE = ("cubby", "merged_cubby", "dresser", "tabletop")
READY = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])  # the Panda's ready posture
HOVER = 0.16  # m between a surface and the hand frame of a downward grasp (fingertips ~3 cm above)


def _box(center, size, yaw=0.0, name="box"):
    return {"type": "cuboid", "name": name, "center": [float(v) for v in center], "quat_wxyz": _yaw(yaw), "size": [float(v) for v in size]}


def _yaw(yaw: float) -> list[float]:
    return [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))]


def _rotz(yaw: float, v) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    v = np.asarray(v, float)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])


def _approach(yaw: float, pitch: float = 0.0) -> np.ndarray:
    """Quaternion (wxyz) of a hand whose z axis points horizontally along yaw, tilted down by pitch."""
    # hand z -> (cos yaw cos p, sin yaw cos p, -sin p); fingers (hand y) horizontal
    z = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)])
    y = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    x = np.cross(y, z)
    return _quat_from_matrix(np.stack([x, y, z], 1))


def _down(yaw: float) -> np.ndarray:
    """Quaternion of a hand pointing down, fingers along yaw."""
    z = np.array([0.0, 0.0, -1.0])
    y = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    return _quat_from_matrix(np.stack([np.cross(y, z), y, z], 1))


def _quat_from_matrix(m: np.ndarray) -> np.ndarray:
    import jaxlie

    return np.asarray(jaxlie.SO3.from_matrix(m).wxyz, np.float64)


# ---------------------------------------------------------------------------- scenes: (scene dict, goal candidates)
# a goal candidate is (position, quaternion) of panda_hand


def _table(rng, height=None):
    h = height if height is not None else rng.uniform(0.0, 0.25)
    center = np.array([rng.uniform(0.5, 0.75), rng.uniform(-0.3, 0.3), h - 0.02])
    return _box(center, [0.8, 1.2, 0.04], rng.uniform(-0.3, 0.3), "table"), center


def _scene_table_pick(rng):
    table, c = _table(rng)
    obs, goals = [table], []
    for k in range(int(rng.integers(3, 7))):
        p = c + np.array([rng.uniform(-0.25, 0.15), rng.uniform(-0.45, 0.45), 0.0])
        size = rng.uniform(0.04, 0.08, 3) * [1, 1, 2]
        obs.append(_box(p + [0, 0, 0.02 + size[2] / 2], size, rng.uniform(-np.pi, np.pi), f"object{k}"))
        goals.append((p + [0, 0, 0.02 + size[2] + HOVER], _down(rng.uniform(-np.pi / 2, np.pi / 2))))
    return {"obstacles": obs}, goals


def _scene_box(rng):
    c = np.array([rng.uniform(0.45, 0.7), rng.uniform(-0.35, 0.35), rng.uniform(-0.3, 0.05)])
    yaw = rng.uniform(-0.5, 0.5)
    w, d, h = rng.uniform(0.4, 0.55), rng.uniform(0.4, 0.55), rng.uniform(0.15, 0.25)
    parts = [([0, 0, 0], [w, d, 0.02]), ([w / 2, 0, h / 2], [0.02, d, h]), ([-w / 2, 0, h / 2], [0.02, d, h])]
    parts += [([0, d / 2, h / 2], [w, 0.02, h]), ([0, -d / 2, h / 2], [w, 0.02, h])]
    obs = [_box(c + _rotz(yaw, off), size, yaw, f"box{k}") for k, (off, size) in enumerate(parts)]
    goal = c + _rotz(yaw, [rng.uniform(-0.08, 0.08), rng.uniform(-0.08, 0.08), HOVER])
    return {"obstacles": obs}, [(goal, _down(yaw + rng.uniform(-0.5, 0.5)))]


def _shelf_cells(rng, c, yaw, width, depth, heights, columns=1, merge=False):
    """Boards, sides, back and dividers of a shelf facing the robot; goals inside the cells."""
    obs, goals = [], []
    top = max(heights) + rng.uniform(0.0, 0.15)
    for k, h in enumerate(heights):
        obs.append(_box(c + _rotz(yaw, [0, 0, h]), [depth, width, 0.02], yaw, f"board{k}"))
    for s in (-1, 1):
        obs.append(_box(c + _rotz(yaw, [0, s * width / 2, top / 2]), [depth, 0.02, top], yaw, f"side{s}"))
    obs.append(_box(c + _rotz(yaw, [depth / 2, 0, top / 2]), [0.02, width, top], yaw, "back"))
    edges = np.linspace(-width / 2, width / 2, columns + 1)
    for k, y in enumerate(edges[1:-1]):
        for j in range(len(heights) - 1):
            if merge and rng.random() < 0.5:
                continue
            lo, hi = heights[j], heights[j + 1]
            obs.append(_box(c + _rotz(yaw, [0, y, (lo + hi) / 2]), [depth, 0.02, hi - lo], yaw, f"divider{k}_{j}"))
    for j in range(len(heights) - 1):
        lo, hi = heights[j], heights[j + 1]
        if hi - lo < 0.22:
            continue
        for y0, y1 in zip(edges[:-1], edges[1:], strict=True):
            p = c + _rotz(yaw, [rng.uniform(-0.05, 0.02), rng.uniform(y0 + 0.08, y1 - 0.08), lo + rng.uniform(0.08, min(0.14, hi - lo - 0.08))])
            goals.append((p, _approach(yaw, rng.uniform(0.0, 0.5))))
    return obs, goals


def _scene_bookshelf(rng):
    yaw = rng.uniform(-0.8, 0.8)
    c = _rotz(yaw, [rng.uniform(0.75, 0.9), 0, 0]) + [0, 0, rng.uniform(-0.1, 0.1)]
    heights = np.cumsum(rng.uniform(0.25, 0.35, 4)) - 0.05
    obs, goals = _shelf_cells(rng, c, yaw, rng.uniform(0.6, 1.0), rng.uniform(0.3, 0.4), heights)
    return {"obstacles": obs}, goals


def _scene_cage(rng):
    """An object in a pen of posts and two rails per side: the arm reaches over the rails."""
    c = np.array([rng.uniform(0.5, 0.65), rng.uniform(-0.25, 0.25), rng.uniform(0.0, 0.15)])
    yaw = rng.uniform(-0.5, 0.5)
    s, h = rng.uniform(0.32, 0.42), rng.uniform(0.18, 0.26)
    obs = [_box(c, [s, s, 0.02], yaw, "floor")]
    for k, (x, y) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
        obs.append(_box(c + _rotz(yaw, [x * s / 2, y * s / 2, h / 2]), [0.03, 0.03, h], yaw, f"post{k}"))
    for k, (x, y) in enumerate([(1, 0), (-1, 0), (0, 1), (0, -1)]):
        size = [0.02, s, 0.02] if x else [s, 0.02, 0.02]
        for z in (0.5 * h, h):
            obs.append(_box(c + _rotz(yaw, [x * s / 2, y * s / 2, z]), size, yaw, f"rail{k}"))
    target = c + [0, 0, 0.04]
    obs.append(_box(target, [0.05, 0.05, 0.06], yaw, "object"))
    return {"obstacles": obs}, [(target + [0, 0, 0.03 + HOVER], _down(yaw + rng.uniform(-0.3, 0.3)))]


def _scene_cubby(rng, merged=False):
    yaw = rng.uniform(-0.6, 0.6)
    c = _rotz(yaw, [rng.uniform(0.65, 0.8), 0, 0]) + [0, 0, rng.uniform(0.0, 0.15)]
    heights = np.cumsum([0.0] + list(rng.uniform(0.26, 0.34, 2)))
    obs, goals = _shelf_cells(rng, c, yaw, rng.uniform(0.6, 0.9), rng.uniform(0.3, 0.4), heights + 0.1, columns=2, merge=merged)
    return {"obstacles": obs}, goals


def _scene_dresser(rng):
    yaw = rng.uniform(-0.6, 0.6)
    c = _rotz(yaw, [rng.uniform(0.75, 0.9), 0, 0])
    width, depth, height = rng.uniform(0.6, 0.9), rng.uniform(0.35, 0.45), rng.uniform(0.5, 0.7)
    obs = [_box(c + _rotz(yaw, [0, 0, height / 2]), [depth, width, height], yaw, "body")]
    goals = []
    n_open = int(rng.integers(1, 3))
    for k in range(n_open):  # open drawers stick out toward the robot: a floor and three walls
        dw, dd, dh = width / 2 - 0.04, rng.uniform(0.25, 0.35), rng.uniform(0.12, 0.18)
        y = (-1 if k == 0 else 1) * width / 4
        z = rng.uniform(0.25, height - 0.1)
        front = -depth / 2 - dd / 2
        for off, size in [
            ([front, y, z - dh / 2], [dd, dw, 0.02]),
            ([front - dd / 2, y, z], [0.02, dw, dh]),
            ([front, y - dw / 2, z], [dd, 0.02, dh]),
            ([front, y + dw / 2, z], [dd, 0.02, dh]),
        ]:
            obs.append(_box(c + _rotz(yaw, off), size, yaw, f"drawer{k}"))
        goals.append((c + _rotz(yaw, [front, y, z - dh / 2 + HOVER]), _down(yaw + rng.uniform(-0.4, 0.4))))
    return {"obstacles": obs}, goals


def _scene_tabletop(rng):
    table, c = _table(rng, rng.uniform(0.05, 0.3))
    obs, goals = [table], []
    for k in range(int(rng.integers(4, 9))):
        p = c + np.array([rng.uniform(-0.3, 0.2), rng.uniform(-0.5, 0.5), 0.0])
        if rng.random() < 0.5:
            size = rng.uniform(0.04, 0.1, 3) * [1, 1, 2.5]
            obs.append(_box(p + [0, 0, 0.02 + size[2] / 2], size, rng.uniform(-np.pi, np.pi), f"object{k}"))
            top = size[2]
        else:
            r, length = rng.uniform(0.025, 0.05), rng.uniform(0.08, 0.25)
            obs.append(
                {
                    "type": "cylinder",
                    "name": f"object{k}",
                    "center": (p + [0, 0, 0.02 + length / 2]).tolist(),
                    "radius": float(r),
                    "length": float(length),
                }
            )
            top = length
        goals.append((p + [0, 0, 0.02 + top + HOVER], _down(rng.uniform(-np.pi / 2, np.pi / 2))))
    return {"obstacles": obs}, goals


SCENES = {
    "table_pick": _scene_table_pick,
    "table_under_pick": _scene_table_pick,
    "box": _scene_box,
    "bookshelf": _scene_bookshelf,
    "cage": _scene_cage,
    "cubby": _scene_cubby,
    "merged_cubby": lambda rng: _scene_cubby(rng, merged=True),
    "dresser": _scene_dresser,
    "tabletop": _scene_tabletop,
}


def _one(robot: Robot, cls: str, rng: np.random.Generator, name: str, frame: str, workspace=None, tries: int = 40) -> Problem:
    pose_goal = cls in MPINETS_LIKE
    ready = READY if robot.ready_q is None else np.asarray(robot.ready_q, np.float64)
    if ready.shape == READY.shape and np.allclose(ready, READY, atol=1e-6):
        ready = READY  # the Panda's, exactly (its config holds it in float32)
    for _ in range(tries):
        scene_dict, goals = SCENES[cls](rng)
        if not goals:
            continue
        if workspace is not None:
            scene_dict, goals = carry(scene_dict, goals, *workspace)
        scene = from_dict(scene_dict).pad(**COMMON_CAPACITY)  # one shape: one compiled IK/checker for every scene
        position, quat = goals[int(rng.integers(len(goals)))]
        solutions = ik_configs(robot, scene, frame, position, quat, rng, seeds=128, margin=0.005, near=ready)
        if len(solutions) == 0:
            continue
        if cls == "table_under_pick":  # start below the table
            table_top = scene_dict["obstacles"][0]["center"][2]
            try:
                starts = sample_configs(robot, scene, 64, rng, margin=0.02, around=ready, spread=0.8)
            except ValueError:
                continue
            z = np.asarray(frame_path(robot, jnp.asarray(starts, jnp.float32), frame)[0])[:, 2]
            below = starts[z < table_top - 0.1]
            if len(below) == 0:
                continue
            start = below[0]
        elif pose_goal:
            try:
                start = sample_configs(robot, scene, 1, rng, margin=0.03, around=ready, spread=0.5)[0]
            except ValueError:
                continue  # this scene leaves no room near the ready posture: draw another
        else:
            start = ready
        try:
            if pose_goal:
                return make_problem(robot, start, scene, goal_pose=(position, quat), name=name, kind=cls)
            return make_problem(robot, start, scene, goal_q=solutions[0], name=name, kind=cls)
        except ValueError:
            continue  # e.g. the ready posture collides with this scene: draw another
    reason = f"could not generate a valid '{cls}' problem in {tries} tries"  # reported invalid; the others go on
    return Problem(np.asarray(ready, np.float64), from_dict({"obstacles": []}), name=name, kind=cls, valid=False, reason=reason)


def generate(robot: Robot, family: str, classes=None, n: int = 100, seed: int = 0, frame: str | None = None) -> list[Problem]:
    """n problems per class of a family ('mbm_like' or 'mpinets_like'), deterministic per seed, for
    the end effector `frame` (default: the robot's ee_frame). Starts are the robot's ready posture
    (or valid configurations near it); for an arm other than the Panda the scenes are carried into
    its workspace (`workspace.panda_workspace`: scaled by its reach, goals placed for its tool)."""
    names = {"mbm_like": MBM_LIKE, "mpinets_like": MPINETS_LIKE}
    if family not in names:
        raise ValueError(f"family must be mbm_like or mpinets_like, got '{family}'")
    classes = list(classes or names[family])
    unknown = [c for c in classes if c not in names[family]]
    if unknown:
        raise ValueError(f"unknown {family} classes {unknown} (classes: {', '.join(names[family])})")
    frame = frame or robot.ee_frame
    workspace = panda_workspace(robot, frame)
    out = []
    for cls in classes:
        rng = np.random.default_rng([seed, zlib.crc32(cls.encode())])
        out.extend(_one(robot, cls, rng, f"{cls}/{k:04d}", frame, workspace) for k in range(n))
    return out
