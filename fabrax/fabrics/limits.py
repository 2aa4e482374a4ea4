"""Acceleration, jerk, velocity and position limits on the fabric's solve (thesis §3.3.4).

Jerk: with |qdd| <= a' = min(a_max, dt j_max / 2) (eq. 3.8) the discrete jerk
(qdd_t+1 - qdd_t)/dt never exceeds j_max (eqs. 3.4-3.7). The acceleration box
also keeps |qd| within the velocity limits after the step and keeps every joint
able to brake at a' before its position limit. The fabric is solved as
(M + alpha I) qdd + f = 0 (eqs. 3.9-3.10) with the smallest alpha, from a
geometric ladder of candidates, whose solution lies in the box; a final clip
only acts when the box excludes zero (a state already outside the limits).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fabrax.fabrics.linalg import cholesky_solve
from fabrax.fabrics.spec import Spec
from fabrax.robot.robot import Robot


def max_acceleration(robot: Robot, dt: float) -> jax.Array:
    """a' = min(a_max, dt j_max / 2) per joint (eq. 3.8)."""
    return jnp.minimum(robot.acceleration, 0.5 * dt * robot.jerk)


def acceleration_box(robot: Robot, q: jax.Array, qd: jax.Array, dt: float, margin: float = 1e-4):
    """Per-joint bounds (lo, hi) on qdd for the step q' = q + dt qd + dt^2/2 qdd, qd' = qd + dt qdd."""
    a = max_acceleration(robot, dt)
    lo = jnp.maximum(-a, (-robot.velocity - qd) / dt)
    hi = jnp.minimum(a, (robot.velocity - qd) / dt)
    # after the step, the remaining distance must let the joint stop at deceleration a
    slack = dt * qd + 0.5 * dt * dt * a + margin
    room_hi = jnp.maximum(robot.upper - q - slack, 0.0)
    room_lo = jnp.maximum(q - robot.lower + dt * qd - 0.5 * dt * dt * a - margin, 0.0)
    hi = jnp.minimum(hi, jnp.maximum((jnp.sqrt(2.0 * a * room_hi) - qd) / dt, -a))
    lo = jnp.maximum(lo, jnp.minimum((-jnp.sqrt(2.0 * a * room_lo) - qd) / dt, a))
    return jnp.minimum(lo, hi), hi


def solve_in_box(spec: Spec, lo: jax.Array, hi: jax.Array, rungs: int = 12, ratio: float = 4.0) -> tuple[jax.Array, jax.Array]:
    """qdd = -(M + alpha I)^-1 f for the smallest feasible alpha on a ladder (eqs. 3.9-3.10).

    alpha_max = |f| / min(hi, -lo) always keeps qdd in the box when it contains
    0 (|(M + aI)^-1 f| <= |f| / a); rungs alpha_max ratio^-k and alpha = 0 are
    solved together. Returns (qdd, alpha).
    """
    n = spec.M.shape[-1]
    room = jnp.maximum(jnp.min(jnp.minimum(hi, -lo)), 1e-9)
    alpha_max = jnp.linalg.norm(spec.f) / room
    alphas = jnp.concatenate([jnp.zeros(1, spec.f.dtype), alpha_max * ratio ** -jnp.arange(rungs - 1, -1, -1, dtype=spec.f.dtype)])
    eye = jnp.eye(n, dtype=spec.M.dtype)
    qdd = -cholesky_solve(spec.M + alphas[:, None, None] * eye, jnp.broadcast_to(spec.f, (rungs + 1, n)))
    ok = jnp.all((qdd >= lo) & (qdd <= hi), axis=-1)
    k = jnp.argmax(ok)  # alphas ascend: the first feasible rung is the smallest alpha
    k = jnp.where(ok.any(), k, rungs)
    return jnp.clip(qdd[k], lo, hi), alphas[k]
