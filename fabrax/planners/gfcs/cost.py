"""The geometric fabric command optimisation problem (GFCOP, gfcs_paper eqs. 4-8).

A candidate y holds n intermediate joint-space commands q_g^1..q_g^n in an
unconstrained space (each joint mapped into its limits by a sigmoid, so CMA-ES
never proposes an infeasible command); the final goal q_g is appended as
command n+1. The fabric is rolled out through the sequence, each command until
it is within epsilon or t_max has passed (eqs. 1-3, 5-7), and

    cost(y) = sum_i t*_i + M [final goal not reached] + M_c [collision]    (eq. 8 plus a collision penalty)

so a colliding candidate never beats a clean one.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fabrax.fabrics.fabric import Params
from fabrax.rollout.rollout import rollout_sequence
from fabrax.rollout.trajectory import Trajectory
from fabrax.scene import COMMON_CAPACITY, Scene


@struct.dataclass
class GFCOP:
    """One problem: start state, joint goal and scene (batch it with a leading axis for vmap)."""

    start_q: jax.Array
    start_qd: jax.Array
    goal_q: jax.Array
    scene: Scene

    @classmethod
    def from_problem(cls, p) -> "GFCOP":
        """From a `fabrax.problems.Problem` with a joint goal; the scene padded to `COMMON_CAPACITY`
        so that every problem runs the same compiled solver."""
        if p.goal_q is None:
            raise ValueError(f"{p.name}: GFCS optimises joint-space commands toward a joint goal; this problem has a pose goal")
        qd = p.start_qd if p.start_qd is not None else np.zeros(len(p.start_q))
        f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
        return cls(f32(p.start_q), f32(qd), f32(p.goal_q), p.scene.pad(**COMMON_CAPACITY))


def to_commands(z: jax.Array, lower: jax.Array, upper: jax.Array) -> jax.Array:
    """Unconstrained z (..., n, dof) -> commands within the joint limits (clipped against float rounding)."""
    return jnp.clip(lower + (upper - lower) * jax.nn.sigmoid(z), lower, upper)


def to_unconstrained(q: jax.Array, lower: jax.Array, upper: jax.Array, eps: float = 1e-4) -> jax.Array:
    """Inverse of `to_commands` (commands at a limit are pulled inside by eps of the range)."""
    u = jnp.clip((q - lower) / (upper - lower), eps, 1.0 - eps)
    return jnp.log(u) - jnp.log1p(-u)


def sequence_cost(
    fabric,
    params: Params,
    problem: GFCOP,
    z: jax.Array,
    *,
    dt: float = 0.01,
    steps: int = 700,
    penalty: float = 100.0,
    collision_penalty: float = 100.0,
) -> tuple[jax.Array, Trajectory]:
    """GFCOP cost of one candidate z (n, dof) and its trajectory."""
    robot = fabric.robot
    commands = to_commands(z, robot.lower, robot.upper)
    goals = jnp.concatenate([commands, problem.goal_q[None]], axis=0)
    params_seq = jax.vmap(lambda g: fabric.with_joint_goal(params, g))(goals)
    traj = rollout_sequence(fabric, params_seq, problem.scene, problem.start_q, problem.start_qd, fabric.reached, dt=dt, steps=steps)
    cost = jnp.sum(traj.segment_times) + penalty * (~traj.reached) + collision_penalty * (traj.min_clearance < 0.0)
    return cost, traj
