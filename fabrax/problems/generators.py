"""Problems that need no data files: a built-in shelf, and random valid problems by rejection sampling."""

from __future__ import annotations

import zlib

import jax.numpy as jnp
import numpy as np

from fabrax.check.clearance import clearances
from fabrax.problems.problem import Problem, make_problem
from fabrax.robot.ik import solve_ik
from fabrax.robot.kinematics import frame_pose
from fabrax.robot.robot import Robot
from fabrax.scene import from_dict


def shelf(center=(0.65, 0.0, 0.0), width=0.8, depth=0.35, heights=(0.25, 0.55, 0.85), thickness=0.02, yaw=0.0) -> dict:
    """A bookshelf facing the robot (open side toward the base): boards at `heights`, two sides, a back."""
    c, s = np.cos(yaw), np.sin(yaw)
    rot = lambda v: np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])  # noqa: E731
    quat = [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))]
    top = max(heights) + 0.1
    boxes = [((0.0, 0.0, h), (depth, width, thickness)) for h in heights]
    boxes += [((0.0, sy * width / 2, top / 2), (depth, thickness, top)) for sy in (-1, 1)]
    boxes += [((depth / 2, 0.0, top / 2), (thickness, width, top))]
    return {
        "obstacles": [
            {"type": "cuboid", "center": (np.asarray(center) + rot(np.asarray(off))).tolist(), "quat_wxyz": quat, "size": list(size)}
            for off, size in boxes
        ]
    }


def valid_configs(robot: Robot, scene, qs: np.ndarray, margin: float = 0.02) -> np.ndarray:
    """Mask of configurations clear of the scene by `margin`, free of self-collision and within limits."""
    env, slf, ok = clearances(robot, scene, qs)
    return (env > margin) & (slf > 0.0) & ok


def sample_configs(
    robot: Robot, scene, n: int, rng: np.random.Generator, margin: float = 0.02, batch: int = 512, around=None, spread: float = 1.0
) -> np.ndarray:
    """n valid configurations by rejection: uniform within the joint limits, or, with `around`,
    uniform within +-spread/2 of each joint's range around that posture (clipped to the limits)."""
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    if around is not None:
        half = 0.5 * spread * (hi - lo)
        lo, hi = np.maximum(lo, np.asarray(around) - half), np.minimum(hi, np.asarray(around) + half)
    scene = scene.rounded(at_least=8)  # as `clearances` pads it, once, not per batch
    out = []
    for _ in range(200):
        qs = rng.uniform(lo, hi, (batch, robot.dof))
        out.extend(qs[valid_configs(robot, scene, qs, margin)])
        if len(out) >= n:
            return np.asarray(out[:n])
    raise ValueError(f"could not find {n} valid configurations in this scene")


def ik_goal(robot, problem: Problem, frame: str, rng=None) -> np.ndarray | None:
    """A joint goal for a pose-goal problem: the collision-free IK solution of its goal pose nearest
    its start (128 seeds, 5 mm margin), or None when none is found. `rng` defaults to one seeded by
    the problem's name, so the answer does not depend on the order problems come in."""
    rng = np.random.default_rng(zlib.crc32(problem.name.encode())) if rng is None else rng
    solutions = ik_configs(robot, problem.scene, frame, *problem.goal_pose, rng, seeds=128, margin=0.005, near=np.asarray(problem.start_q))
    return solutions[0] if len(solutions) else None


def flag_unreachable(robot, problem: Problem, frame: str, seeds: int = 128) -> Problem:
    """Mark a valid pose-goal problem invalid (`valid`, `reason`) when IK from `seeds` random
    starts finds no configuration that reaches its goal pose inside the joint limits without
    collision: a goal within `Robot.reach` can still be unreachable (inside the base, or an
    orientation the wrist cannot take there), and would otherwise fail only after the full time."""
    if not problem.valid or problem.goal_pose is None or problem.goal_q is not None:
        return problem
    rng = np.random.default_rng(zlib.crc32(problem.name.encode()))
    if len(ik_configs(robot, problem.scene, frame, *problem.goal_pose, rng, seeds=seeds, margin=0.0, limit_margin=0.0)) == 0:
        problem.valid, problem.reason = False, f"{problem.name}.goal_pose: no collision-free IK solution within the joint limits ({seeds} seeds)"
    return problem


def ik_configs(
    robot, scene, frame, position, quat, rng, seeds: int = 256, tol: float = 1e-3, margin: float = 0.01, limit_margin: float = 0.1, near=None
) -> np.ndarray:
    """Valid joint configurations reaching a pose, at least `limit_margin` rad inside the joint
    limits, ordered by distance to `near` (or by residual); empty if none found."""
    q0 = jnp.asarray(rng.uniform(robot.lower, robot.upper, (seeds, robot.dof)), jnp.float32)
    qs, err = solve_ik(robot, frame, jnp.asarray(position, jnp.float32), jnp.asarray(quat, jnp.float32), q0)
    qs, err = np.asarray(qs), np.asarray(err)
    inside = np.all((qs > np.asarray(robot.lower) + limit_margin) & (qs < np.asarray(robot.upper) - limit_margin), axis=1)
    good = (err < tol) & inside & valid_configs(robot, scene, qs, margin)
    key = err[good] if near is None else np.linalg.norm(qs[good] - near, axis=1)
    return qs[good][np.argsort(key)]


DEMO_SHELF = {"center": (0.8, 0.0, 0.0), "depth": 0.4, "heights": (0.25, 0.7, 1.1)}
DEMO_HAND = ((0.7346, 0.0, 0.4644), (0.0001, 0.8776, 0.0002, 0.4794))  # the Panda's goal: panda_hand (position, wxyz)


def demo_problem(robot: Robot) -> Problem:
    """The built-in demo: from the ready posture into the middle cell of a shelf (joint goal).

    For the Panda the goal posture has the hand 15 cm inside a 45 cm cell, pitched 33 degrees
    down; straight joint interpolation passes within about a millimetre of the middle board. For
    another arm the shelf and that hand pose are carried into its workspace
    (`workspace.panda_workspace`) and the goal is the collision-free IK solution nearest its ready
    posture."""
    from fabrax.problems.workspace import carry, panda_workspace

    scene_dict = shelf(**DEMO_SHELF)
    if tuple(robot.joint_names) == tuple(f"panda_joint{i}" for i in range(1, 8)):
        ready = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
        goal = np.array([0.0, 0.5, 0.0, -1.6, 0.0, 3.1, 0.785])
        return make_problem(robot, ready, from_dict(scene_dict), goal_q=goal, name="demo_shelf", kind="shelf")
    frame = robot.ee_frame
    goals = [tuple(np.asarray(v, np.float64) for v in DEMO_HAND)]
    workspace = panda_workspace(robot, frame)
    if workspace is not None:
        scene_dict, goals = carry(scene_dict, goals, *workspace)
    scene = from_dict(scene_dict)
    ready = np.asarray(robot.ready_q, np.float64)
    rng = np.random.default_rng(0)
    near = np.clip(ready + rng.normal(scale=0.5, size=(256, robot.dof)), robot.lower, robot.upper)  # IK seeds around the ready posture
    qs, err = solve_ik(robot, frame, jnp.asarray(goals[0][0], jnp.float32), jnp.asarray(goals[0][1], jnp.float32), jnp.asarray(near, jnp.float32))
    qs, err = np.asarray(qs, np.float64), np.asarray(err)
    qs = qs[(err < 1e-3) & np.asarray(robot.within_limits(jnp.asarray(qs)))]
    solutions = qs[valid_configs(robot, scene, qs, 0.01)] if len(qs) else qs
    solutions = solutions[np.argsort(np.linalg.norm(solutions - ready, axis=1))]
    if len(solutions) == 0:
        raise ValueError(f"the demo's shelf goal has no collision-free IK solution for robot '{robot.name}' (frame {frame})")
    return make_problem(robot, ready, scene, goal_q=solutions[0], name="demo_shelf", kind="shelf")


def random_problems(
    robot: Robot, scene_dicts: list[dict], seed: int, goal: str = "joint", frame: str = "panda_hand", around=None, spread: float = 1.0
) -> list[Problem]:
    """One problem per scene: valid start and goal configurations by rejection sampling (see
    `sample_configs` for `around`/`spread`); pose goals are the goal configuration's `frame` pose."""
    rng = np.random.default_rng(seed)
    out = []
    for k, sd in enumerate(scene_dicts):
        scene = from_dict(sd)
        start, target = sample_configs(robot, scene, 2, rng, around=around, spread=spread)
        if goal == "joint":
            out.append(make_problem(robot, start, scene, goal_q=target, name=f"random_{seed}_{k}", kind="random"))
        else:
            pose = frame_pose(robot, jnp.asarray(target, jnp.float32), frame)
            gp = (np.asarray(pose.translation()), np.asarray(pose.rotation().wxyz))
            out.append(make_problem(robot, start, scene, goal_pose=gp, name=f"random_{seed}_{k}", kind="random"))
    return out


def flying_cuboids(rng: np.random.Generator, n: int = (6, 10), r_min: float = 0.35, r_max: float = 1.0, keep_out: float = 0.3) -> dict:
    """Thesis §3.4.1.2 'flying cuboids': boxes of random size and orientation around the robot;
    boxes that reach within `keep_out` of the base's vertical axis below 0.9 m (the shoulder) are dropped."""
    count = rng.integers(*n, endpoint=True)
    obs = []
    while len(obs) < count:
        d = rng.normal(size=3)
        d[2] = abs(d[2])
        d /= np.linalg.norm(d)
        center = d * rng.uniform(r_min, r_max)
        q = rng.normal(size=4)
        size = rng.uniform(0.05, 0.25, 3)
        if np.linalg.norm(center[:2]) - 0.5 * np.linalg.norm(size) < keep_out and center[2] < 0.9:
            continue
        obs.append({"type": "cuboid", "center": center.tolist(), "quat_wxyz": (q / np.linalg.norm(q)).tolist(), "size": size.tolist()})
    return {"obstacles": obs}


def cuboid_forest(rng: np.random.Generator, spacing: float = 0.45, extent: float = 1.1, keep_out: float = 0.35, jitter: float = 0.08) -> dict:
    """Thesis §3.4.1.2 'cuboid forest': vertically stretched cuboids on a jittered grid, each turned
    about z; cuboids whose footprint comes within `keep_out` of the base's vertical axis are dropped."""
    ticks = np.arange(-extent, extent + 1e-9, spacing)
    obs = []
    for x in ticks:
        for y in ticks:
            c = np.array([x, y]) + rng.uniform(-jitter, jitter, 2)
            size = np.array([*rng.uniform(0.05, 0.15, 2), rng.uniform(0.3, 1.3)])
            if np.linalg.norm(c) - 0.5 * np.linalg.norm(size[:2]) < keep_out:
                continue
            yaw = rng.uniform(-np.pi, np.pi)
            obs.append(
                {
                    "type": "cuboid",
                    "center": [float(c[0]), float(c[1]), float(size[2] / 2)],
                    "quat_wxyz": [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))],
                    "size": size.tolist(),
                }
            )
    return {"obstacles": obs}


def surrounding_shelves(rng: np.random.Generator, distance=(0.7, 0.9), spacing=(0.2, 0.4), top: float = 1.3) -> dict:
    """Thesis §3.4.1.2 'shelves': four tall shelves around the robot, each facing it, with levels
    `spacing` m apart (uniform per level)."""
    obs = []
    for yaw in np.arange(4) * np.pi / 2 + rng.uniform(-0.2, 0.2):
        heights, h = [], rng.uniform(0.0, spacing[0])
        while h < top:
            heights.append(float(h))
            h += rng.uniform(*spacing)
        r = rng.uniform(*distance)
        obs += shelf(center=(r * np.cos(yaw), r * np.sin(yaw), 0.0), width=0.9, depth=0.35, heights=heights, yaw=float(yaw))["obstacles"]
    return {"obstacles": obs}
