"""VAMP baselines (optional: `pip install -e ".[vamp]"`, which pins `vamp-planner==0.6.4`).

VAMP (Thomason, Kingston, Kavraki, ICRA 2024) plans with SIMD-vectorised
collision checks of its own sphere model of a few built-in robots (panda, ur5,
fetch, baxter), so it runs only for a robot whose name and joints match one of
them. The scene is given to VAMP as its primitives (cuboids; cylinders become
VAMP's capsules, an over-approximation). VAMP's planners stop after an
iteration budget, not a time budget. Its paths are then judged like every
other method's: re-checked by the benchmark's own checker (VAMP's spheres are
not ours) and retimed rest to rest (`fabrax.bench.retime`).
"""

from __future__ import annotations

import numpy as np

from fabrax.problems.problem import Problem
from fabrax.robot.robot import Robot

PLANNERS = ("rrtc", "prm", "fcit", "aorrtc")


def robot_module(robot: Robot):
    """VAMP's model of `robot`, refused in one line when VAMP has none with the same joints."""
    try:
        import vamp
    except ImportError:
        raise ValueError("VAMP is not installed (pip install -e '.[vamp]')") from None
    if robot.name not in vamp.robots:
        raise ValueError(f"VAMP has no model of robot '{robot.name}' (its robots: {', '.join(vamp.robots)})")
    module = getattr(vamp, robot.name)
    if tuple(module.joint_names()) != tuple(robot.joint_names):
        raise ValueError(f"VAMP's {robot.name} has joints {list(module.joint_names())}, the robot {list(robot.joint_names)}")
    return module


def environment(scene, padding: float = 0.0):
    """The scene's primitives as a `vamp.Environment` (orientations as VAMP's extrinsic XYZ Euler
    angles, R = Rz Ry Rx, which is jaxlie's roll-pitch-yaw), each grown by `padding` (m)."""
    import jaxlie
    import vamp

    if int(np.asarray(scene.cloud.mask).sum()):
        raise ValueError("VAMP baselines take primitive scenes; this scene has a point cloud")
    env = vamp.Environment()
    rpy = lambda quat: np.stack(jaxlie.SO3(np.asarray(quat, np.float64).reshape(-1, 4)).as_rpy_radians(), -1).tolist()  # noqa: E731  (one call per kind)
    used = lambda prims, *fields: [np.asarray(getattr(prims, f))[np.asarray(prims.mask, bool)] for f in fields]  # noqa: E731
    center, quat, half = used(scene.cuboids, "center", "quat", "half_extents")
    for c, e, h in zip(center, rpy(quat), half, strict=True):
        env.add_cuboid(vamp.Cuboid(c.tolist(), e, (h + padding).tolist()))
    center, quat, radius, half = used(scene.cylinders, "center", "quat", "radius", "half_length")
    for c, e, r, h in zip(center, rpy(quat), radius, half, strict=True):
        env.add_capsule(vamp.Cylinder(c.tolist(), e, float(r + padding), 2.0 * float(h + padding)))
    for c, r in zip(*used(scene.spheres, "center", "radius"), strict=True):
        env.add_sphere(vamp.Sphere(c.tolist(), float(r + padding)))
    return env


def settings(module, name: str, planner: str, iterations: int):
    """VAMP's planner settings as its own `configure_robot_and_planner_with_kwargs` makes them (the
    robot's RRT range), with `iterations` as the iteration and sample budget."""
    import vamp

    if planner == "rrtc":
        s = vamp.RRTCSettings()
        s.range = vamp.ROBOT_RRT_RANGES.get(name, s.range)
    elif planner == "prm":
        s = vamp.PRMSettings(vamp.PRMNeighborParams(module.dimension(), module.space_measure()))
    elif planner == "fcit":
        s = vamp.FCITSettings(vamp.FCITNeighborParams(module.dimension(), module.space_measure()))
    elif planner == "aorrtc":
        s = vamp.AORRTCSettings()
        s.rrtc.range = vamp.ROBOT_RRT_RANGES.get(name, s.rrtc.range)
        s.simplify = vamp.SimplifySettings()
    else:
        raise ValueError(f"unknown VAMP planner '{planner}' (VAMP's: {', '.join(PLANNERS)})")
    s.max_iterations = iterations
    s.max_samples = iterations
    return s


def plan(robot: Robot, problem: Problem, planner: str, iterations: int, simplify: bool, padding: float = 0.0):
    """A joint path (W, n) from start to the joint goal planned by VAMP, or None; and info
    (VAMP's own planning and simplification times). `padding` (m) grows the obstacles VAMP plans
    around, a margin for the difference between its robot spheres and the benchmark's; it is halved
    (twice, then dropped) where the start or the goal lies within it or no path is found with it."""
    import vamp

    module = robot_module(robot)
    if problem.goal_q is None:
        raise ValueError(f"{problem.name}: VAMP baselines plan to joint goals; this problem has a pose goal (bench ik_goals=true adds one)")
    start, goal = (np.clip(np.asarray(q, np.float32), robot.lower, robot.upper).astype(np.float32) for q in (problem.start_q, problem.goal_q))
    plan_settings = settings(module, robot.name, planner, iterations)
    rng = module.halton()
    solve_s = 0.0
    for padding in dict.fromkeys((padding, padding / 2, padding / 4, 0.0)):  # the margin halves where start or goal lie in it or no path is found
        env = environment(problem.scene, padding)
        if padding and not (module.validate(start, env) and module.validate(goal, env)):
            continue
        result = getattr(module, planner)(start, goal, env, plan_settings, rng)
        solve_s += result.nanoseconds * 1e-9
        if result.solved:
            break
    info = {"planner": f"vamp_{planner}", "solve_s": solve_s, "simplify_s": 0.0, "iterations": int(result.iterations), "padding": padding}
    if not result.solved:
        return None, info
    path = result.path
    if simplify and planner != "aorrtc":  # AORRTC simplifies its own paths
        simple = module.simplify(path, env, vamp.SimplifySettings(), rng)
        info["simplify_s"] = simple.nanoseconds * 1e-9
        path = simple.path
    # VAMP's model has its own joint bounds (its Panda's are 0.07 rad wider than the benchmark's limits,
    # 0.16 at joint 4): its waypoints are projected onto the robot's limits, and the checker re-checks them
    waypoints = np.asarray(path.numpy(), np.float64)
    clipped = np.clip(waypoints, np.asarray(robot.lower), np.asarray(robot.upper))
    return clipped, {**info, "clipped_rad": float(np.abs(clipped - waypoints).max())}
