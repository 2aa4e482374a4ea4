"""Inverse kinematics: batched damped least squares on three points of a frame.

The residual stacks three non-collinear points of the target frame (so one
objective carries position and orientation); Levenberg-Marquardt steps from
many random seeds run in one `vmap`, clipped to the joint limits. Jitted once per frame: an
unjitted scan would compile a fresh executable per call.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jaxlie

from fabrax.robot.kinematics import point_kinematics
from fabrax.robot.robot import Robot

_POINTS = jnp.asarray([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])


def _frame_points(robot: Robot, frame: str):
    i = robot.frame_index(frame)
    local = _POINTS @ robot.frame_offset_r[i].T + robot.frame_offset_t[i]
    return jnp.full((3,), robot.frame_parent[i]), local


@functools.partial(jax.jit, static_argnames=("frame", "iters"))
def solve_ik(
    robot: Robot,
    frame: str,
    position,
    quat_wxyz,
    seeds: jax.Array,
    iters: int = 100,
    damping: float = 1e-3,
    posture=None,
    posture_weight: float = 0.0,
):
    """Joint configurations (S, n) from seeds (S, n) that put `frame` at the pose; and their residuals (S,) in m.
    posture (n,), posture_weight (m^2 per rad^2): a soft pull toward a configuration that picks among the
    redundant solutions (the residual reported is the pose part alone)."""
    posture = seeds[0] if posture is None else jnp.asarray(posture)
    fr, local = _frame_points(robot, frame)
    target = jaxlie.SO3(jnp.asarray(quat_wxyz) / jnp.linalg.norm(quat_wxyz)).apply(_POINTS) + jnp.asarray(position)

    def residual_jac(q):
        kin = point_kinematics(robot, q, jnp.zeros_like(q), fr, local)
        r = (kin.x.T - target).reshape(-1)
        return r, kin.jac.transpose(2, 0, 1).reshape(-1, q.shape[0])

    def step(q, _):
        r, jac = residual_jac(q)
        jtj = jac.T @ jac + posture_weight * jnp.eye(q.shape[0])
        grad = jac.T @ r + posture_weight * (q - posture)
        dq = -jnp.linalg.solve(jtj + damping * (1.0 + jnp.diag(jtj).mean()) * jnp.eye(q.shape[0]), grad)
        return robot.clip(q + dq), None

    def one(q0):
        q, _ = jax.lax.scan(step, q0, None, length=iters)
        return q, jnp.sqrt(jnp.mean(jnp.square(residual_jac(q)[0])) * 3.0)

    return jax.vmap(one)(seeds)
