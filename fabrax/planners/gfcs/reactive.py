"""Reactive re-execution of a solved command sequence among new obstacles (gfcs_paper §V, Fig. 4).

After GFCS has solved a problem, cuboids are added that block the solved
motion: each is centred on a collision sphere of the arm at a random moment of
the middle of the trajectory, so the old motion runs into it, and is rejected
if it touches the start or goal configuration. The same commands are then
executed by the fabric in the new scene without re-optimising; the fabric's
obstacle terms must avoid what the optimiser never saw.

`replan` is what the paper does not: CMA-ES again in the new scene, warm-started at the old
solution, for a fixed budget of batches (Algorithm 1 with its first population drawn around the
previous command sequence instead of uniformly).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from fabrax.check.checker import check_path
from fabrax.planners.gfcs.solver import GFCSConfig, GFCSResult, solve
from fabrax.problems.problem import ProblemBatch
from fabrax.robot.kinematics import sphere_centers
from fabrax.rollout.rollout import rollout_sequence
from fabrax.rollout.trajectory import Trajectory
from fabrax.scene import COMMON_CAPACITY, Scene, from_dict, to_dict

_sphere_centers = jax.jit(sphere_centers)


def blocking_cuboids(
    robot,
    q_path: np.ndarray,
    start_q,
    goal_q,
    rng: np.random.Generator,
    n: int = 1,
    size=(0.06, 0.14),
    clear: float = 0.03,
    tries: int = 200,
) -> list[dict]:
    """n random cuboids that intersect the path q_path (T, dof) but keep `clear` m from the start and goal."""
    out = []
    for _ in range(tries):
        if len(out) == n:
            break
        t = int(rng.integers(int(0.25 * len(q_path)), max(int(0.75 * len(q_path)), int(0.25 * len(q_path)) + 1)))
        x = np.asarray(_sphere_centers(robot, jnp.asarray(q_path[t], jnp.float32)))
        center = x[int(rng.integers(len(x)))]
        yaw = rng.uniform(-np.pi, np.pi)
        cub = {
            "type": "cuboid",
            "center": center.tolist(),
            "quat_wxyz": [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)],
            "size": rng.uniform(*size, 3).tolist(),
        }
        trial = from_dict({"obstacles": [cub]})
        ends = np.stack([start_q, goal_q])
        if check_path(robot, trial, ends[:1], margin=clear).collision or check_path(robot, trial, ends[1:], margin=clear).collision:
            continue
        out.append(cub)
    if len(out) < n:
        raise ValueError(f"could not place {n} blocking cuboids clear of the start and goal in {tries} tries")
    return out


def with_obstacles(scene: Scene, obstacles: list[dict]) -> Scene:
    """The scene plus extra obstacles, padded to the common capacity."""
    data = to_dict(scene)
    data["obstacles"] = data["obstacles"] + obstacles
    return from_dict(data).pad(**COMMON_CAPACITY)


def reexecute(
    fabric,
    params,
    problem: ProblemBatch,
    commands: jax.Array,
    scene: Scene,
    dt: float = 0.01,
    steps: int = 700,
    final_pose: bool = True,
    via_tolerance=None,
) -> Trajectory:
    """Execute commands (n, dof) then the goal with the fabric in `scene`, without re-optimising
    (final_pose, via_tolerance as in `GFCSConfig`: the sequence as the solver ran it)."""
    goals = jnp.concatenate([jnp.asarray(commands, jnp.float32), problem.goal_q[None]], axis=0)
    params_seq = jax.vmap(lambda g: fabric.with_joint_goal(params, g))(goals)
    final = fabric.with_joint_goal(params, problem.goal_q, pose=final_pose)
    params_seq = jax.tree.map(lambda a, f: a.at[-1].set(f), params_seq, final)
    via = None if via_tolerance is None else lambda p, q, qd: fabric.joint_reached(p, q, qd, via_tolerance)
    return rollout_sequence(fabric, params_seq, scene, problem.start_q, problem.start_qd, fabric.reached, dt=dt, steps=steps, via=via)


def warm_samples(key: jax.Array, z, population: int, sigma: float) -> jax.Array:
    """A first CMA-ES population (population, n, dof) around a previous solution z (n, dof) in the
    unconstrained space: population - 1 Gaussian perturbations of std `sigma`, then z itself last
    (the first slot is the one `GFCSConfig.direct` replaces with the fabric alone)."""
    if population < 2:
        raise ValueError(f"warm_samples: population must be at least 2, got {population}")
    z = jnp.asarray(z, jnp.float32)
    noise = sigma * jax.random.normal(key, (population - 1, *z.shape), jnp.float32)
    return jnp.concatenate([z[None] + noise, z[None]])


def replan_config(cfg: GFCSConfig, batches: int = 2, std: float = 0.3) -> GFCSConfig:
    """The solver settings of `replan`: a fixed budget of `batches`, CMA-ES's step size `std`, and
    no patience, so that the old solution's rollout in the first batch is its re-execution (a
    patience cut would drop a slow detour that re-execution completes, and the re-plan could
    answer worse than re-executing)."""
    if batches < 1:
        raise ValueError(f"replan: batches must be at least 1, got {batches}")
    if not std > 0:
        raise ValueError(f"replan: std must be positive, got {std}")
    return dataclasses.replace(cfg, batches=int(batches), std_init=float(std), patience=None)


def replan(fabric, params, problem: ProblemBatch, z, key: jax.Array, cfg: GFCSConfig, steps_fns=None) -> GFCSResult:
    """Re-plan `problem` (its changed scene, from its start state) by CMA-ES warm-started at the
    previous solution z (n, dof, unconstrained): `warm_samples` with std cfg.std_init as the first
    batch, CMA-ES's step size the same, for cfg.batches batches (a fixed budget). cfg: a
    `replan_config`; `steps_fns`: `make_step(fabric, params, cfg)` with it, reused across problems."""
    k_samples, k_solve = jax.random.split(key)
    samples = warm_samples(k_samples, z, cfg.population, cfg.std_init)
    return solve(fabric, params, problem, k_solve, cfg, samples=samples, steps_fns=steps_fns)
