"""The geometric fabric command optimisation problem (GFCOP, gfcs_paper eqs. 4-8).

A candidate y holds n intermediate joint-space commands q_g^1..q_g^n in an
unconstrained space (each joint mapped into its limits by a sigmoid, so CMA-ES
never proposes an infeasible command); the final goal q_g is appended as
command n+1. The fabric is rolled out through the sequence, each command until
it is within epsilon or t_max has passed (eqs. 1-3, 5-7), and

    cost(y) = sum_i t*_i + M [final goal not reached] + M_c [collision] + w L_ee    (eq. 4 plus two terms)

so a colliding candidate never beats a clean one. L_ee is the path length of the
fabric's goal frame (the paper's "EE length" metric, §IV); w = 0 is eq. 4.

goal="pose" keeps eqs. 4-8 but makes command n+1 a pose goal: the last segment aims the
end-effector attractor at the goal pose (a joint goal held as the null-space posture where the
problem has one, as the pure fabric `gf` does) and ends at the pose test, so problems given
only a hand pose (MotionPolicyNetworks) need no inverse kinematics. The pose test and the
patience measure need the hand's pose at every step, one forward-kinematics pass more per step
than the joint test.

A problem is a `fabrax.problems.ProblemBatch` with joint goals (`ProblemBatch.of(problem)` for one,
`ProblemBatch.stack` for several): its start state, joint goal and scene.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fabrax.fabrics.fabric import Params
from fabrax.problems.problem import ProblemBatch
from fabrax.robot import points
from fabrax.rollout.rollout import rollout_population
from fabrax.rollout.trajectory import Trajectory

MIN_PROGRESS = 0.01  # rad (m toward a pose goal): what counts as getting closer to a command (`population_cost`'s patience)
GOALS = ("joint", "pose")


def to_commands(z: jax.Array, lower: jax.Array, upper: jax.Array) -> jax.Array:
    """Unconstrained z (..., n, dof) -> commands within the joint limits (clipped against float rounding)."""
    return jnp.clip(lower + (upper - lower) * jax.nn.sigmoid(z), lower, upper)


def to_unconstrained(q: jax.Array, lower: jax.Array, upper: jax.Array, eps: float = 1e-4) -> jax.Array:
    """Inverse of `to_commands` (commands at a limit are pulled inside by eps of the range)."""
    u = jnp.clip((q - lower) / (upper - lower), eps, 1.0 - eps)
    return jnp.log(u) - jnp.log1p(-u)


def population_cost(
    fabric,
    params: Params,
    problem: ProblemBatch,
    zs: jax.Array,
    *,
    dt: float = 0.01,
    steps: int = 700,
    penalty: float = 100.0,
    collision_penalty: float = 100.0,
    enough: int | None = None,
    patience: float | None = None,
    via_tolerance: float | None = None,
    final_pose: bool = True,
    length_weight: float = 0.0,
    goal: str = "joint",
    hand_mass: float | None = None,
    shrink: int = 4,
) -> tuple[jax.Array, Trajectory]:
    """GFCOP costs of candidates zs (P, n, dof) and their trajectories, rolled out together.

    enough: stop the population once this many candidates reached the goal
    without collision (`rollout_population`); the rest count as not reached.
    patience: s: a segment that gets no closer (by MIN_PROGRESS rad) to its command for this long
    ends, charged t_max: the arm is at rest or chattering against an obstacle (`rollout_sequence`).
    via_tolerance: joint distance (rad, 2-norm) at which an intermediate command counts as passed
    (default: the fabric's goal tolerance, i.e. the arm nearly stops at every command).
    final_pose: the last segment also attracts the hand to its pose at the goal
    (`ArmFabric.with_joint_goal(pose=True)`); the goal test stays the joint tolerance.
    length_weight: s per metre of goal-frame path added to the cost (0: the paper's time-only cost).
    goal: "joint" (eq. 6: the last command is the joint goal) or "pose" (the last segment aims the
    hand at the goal pose and ends at the pose test; see the module docstring).
    hand_mass: the end-effector attractor's mass far from its target in every segment (`with_hand_mass`).
    shrink: once at most 1/shrink of the candidates still run, they go on alone as a smaller batch
    (`rollout_population`; 1: never). Each batch size is one more loop to compile: 4 runs a
    population of 64 as 64 then 16 arms, 2 as 64, 32 and 16 (docs/gfcs.md compares them).
    """
    if goal not in GOALS:
        raise ValueError(f"goal must be one of {GOALS}, got {goal!r}")
    robot = fabric.robot
    params = with_hand_mass(params, hand_mass)
    commands = to_commands(zs, robot.lower, robot.upper)
    goals = jnp.concatenate([commands, jnp.broadcast_to(problem.goal_q, (zs.shape[0], 1, robot.dof))], axis=1)
    if goal == "pose":
        final = fabric.with_goal(params, problem.joint_goal, problem.goal_q, problem.goal_pos, problem.goal_quat, aim="pose")
    else:
        final = fabric.with_joint_goal(params, problem.goal_q, pose=final_pose)
    params_seqs = jax.vmap(jax.vmap(lambda g: fabric.with_joint_goal(params, g)))(goals)
    params_seqs = jax.tree.map(lambda a, f: a.at[:, -1].set(f), params_seqs, final)
    wait = None if patience is None else (_pose_or_joint_error(fabric) if goal == "pose" else _joint_error, patience, MIN_PROGRESS)
    via = None if via_tolerance is None else lambda p, q, qd: fabric.joint_reached(p, q, qd, via_tolerance)
    trajs = rollout_population(
        fabric,
        fabric.aimed(params_seqs),
        problem.scene,
        problem.start_q,
        problem.start_qd,
        fabric.reached if goal == "pose" else fabric.joint_reached,
        enough=enough,
        patience=wait,
        via=via,
        dt=dt,
        steps=steps,
        shared=params,
        shrink=shrink,
    )
    costs = jnp.sum(trajs.segment_times, axis=-1) + penalty * (~trajs.reached) + collision_penalty * (trajs.min_clearance < 0.0)
    if length_weight:
        costs = costs + length_weight * ee_length(fabric, trajs.q)
    return costs, trajs


def with_hand_mass(params: Params, mass: float | None) -> Params:
    """The fabric's parameters with the end-effector attractor's far mass (its energy's m_lo, thesis
    §3.3.1) set to `mass` (None or no such term: unchanged). At the near mass m_hi the hand's metric
    is the same everywhere, so while the hand attractor is on, the hand leads in task space from the
    start of a segment, where the joint attractor's metric otherwise bends its path."""
    if mass is None or "ee" not in params:
        return params
    return {**params, "ee": {**params["ee"], "m_lo": jnp.full_like(params["ee"]["m_lo"], mass)}}


def _joint_error(p, q):
    return jnp.linalg.norm(q - p["goal"]["target"])


def _pose_or_joint_error(fabric):
    """Progress toward a segment's aim: joint distance toward a command, the hand's distance (m)
    toward a pose goal (the segment whose joint attractor is off)."""

    def error(p, q):
        joint, pos, _ = fabric.goal_errors(p, q)
        return jnp.where(p["goal"]["weight"] > 0.5, joint, pos)

    return error


def ee_length(fabric, qs: jax.Array) -> jax.Array:
    """Path length (m) of the fabric's goal frame along configurations qs (..., T, dof); rows past a
    trajectory's end repeat its last state and add nothing."""
    frame, local = fabric.robot.frame_point(fabric.goal_frame)  # the frame's origin: no rotation to convert
    pos = jax.vmap(lambda q: points(fabric.robot, q, frame[None], local[None])[0])(qs.reshape(-1, qs.shape[-1]))
    pos = pos.reshape(*qs.shape[:-1], 3)
    return jnp.sum(jnp.linalg.norm(jnp.diff(pos, axis=-2), axis=-1), axis=-1)


def sequence_cost(fabric, params: Params, problem: ProblemBatch, z: jax.Array, **kwargs) -> tuple[jax.Array, Trajectory]:
    """GFCOP cost of one candidate z (n, dof) and its trajectory (keywords as `population_cost`)."""
    costs, trajs = population_cost(fabric, params, problem, z[None], **kwargs)
    return costs[0], jax.tree.map(lambda a: a[0], trajs)
