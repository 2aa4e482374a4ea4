"""Acceleration, jerk, velocity and position limits on the fabric's solve (thesis §3.3.4).

Jerk: with |qdd| <= a' = min(a_max, dt j_max / 2) (eq. 3.8) the discrete jerk
(qdd_t+1 - qdd_t)/dt never exceeds j_max (eqs. 3.4-3.7). The acceleration box
also keeps |qd| within the velocity limits after the step and keeps every joint
able to brake at a' before its position limit. Where thesis eqs. 3.9-3.10
shrink the whole solve, (M + alpha I) qdd + f = 0, until it fits the box,
fabrax takes the acceleration nearest to the fabric's in the fabric's own
metric that satisfies the box (`solve_in_box`): a repulsion term near contact
has a large metric and keeps its braking, the other directions give way.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fabrax.fabrics.linalg import cholesky_solve
from fabrax.fabrics.spec import Spec
from fabrax.robot.limits import max_acceleration
from fabrax.robot.robot import Robot
from fabrax.soa import matvec


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


def solve_in_box(spec: Spec, lo: jax.Array, hi: jax.Array, iters: int = 8) -> jax.Array:
    """The acceleration closest to the fabric's in its own metric that lies in the box:

        argmin_a 1/2 a^T M a + f^T a   subject to   lo <= a <= hi,

    i.e. the M-weighted projection of -M^-1 f onto the box. Directions of large
    metric (a repulsion term near contact) keep their acceleration and the
    others give way, where the uniform (M + alpha I) of thesis eq. 3.9 shrinks
    every direction, the barrier's braking with them. Solved by primal-dual
    active sets (free joints solve the reduced system, bounds are released by
    the sign of their multiplier) for at most `iters` rounds, stopping once the
    active sets repeat; the best feasible iterate is returned, so the result
    always lies in the box. A `lax.while_loop`: differentiable in forward mode only.
    """
    M, f = spec.M, spec.f
    n = M.shape[-1]
    eye = jnp.eye(n, dtype=M.dtype)

    def cost(a):
        return jnp.sum(a * (0.5 * matvec(M, a) + f))

    a = jnp.clip(-cholesky_solve(M, f), lo, hi)
    at_lo, at_hi = a <= lo, a >= hi

    def round_(state):
        k, at_lo, at_hi, best, best_cost, _ = state
        bound = at_lo | at_hi
        b = jnp.where(at_lo, lo, jnp.where(at_hi, hi, 0.0))
        free = ~bound
        reduced = jnp.where(free[:, None] & free[None, :], M, 0.0) + jnp.where(bound, 1.0, 0.0)[:, None] * eye
        a = cholesky_solve(reduced, jnp.where(free, -(f + matvec(M, b)), b))
        grad = matvec(M, a) + f  # multipliers of the bound joints
        new_lo = (at_lo & (grad >= 0.0)) | (free & (a < lo))
        new_hi = (at_hi & (grad <= 0.0)) | (free & (a > hi))
        clipped = jnp.clip(a, lo, hi)
        c = cost(clipped)
        better = c < best_cost
        changed = jnp.any((new_lo != at_lo) | (new_hi != at_hi))
        return k + 1, new_lo, new_hi, jnp.where(better, clipped, best), jnp.where(better, c, best_cost), changed

    # A round is a function of the active sets alone: once they repeat, every further round repeats it
    # and leaves `best` as it is, so the loop stops there (the same result as `iters` rounds). With no
    # bound active, the first round re-solves the free system and repeats: no round at all.
    state = (jnp.zeros((), jnp.int32), at_lo, at_hi, a, cost(a), jnp.any(at_lo | at_hi))
    return jax.lax.while_loop(lambda s: (s[0] < iters) & s[5], round_, state)[3]


def solve_shrinking(spec: Spec, lo: jax.Array, hi: jax.Array, rungs: int = 12, ratio: float = 4.0) -> jax.Array:
    """Thesis eqs. 3.9-3.10 as written: qdd = -(M + alpha I)^-1 f for the smallest alpha, on a geometric
    ladder, whose solution lies in the box (alpha_max = |f| / min(hi, -lo) always does when the box
    contains 0; rungs alpha_max ratio^-k and alpha = 0 are solved together). Kept to compare limiters
    (experiments/bench_sweeps.py); `solve_in_box` is the default."""
    n = spec.M.shape[-1]
    room = jnp.maximum(jnp.min(jnp.minimum(hi, -lo)), 1e-9)
    alpha_max = jnp.linalg.norm(spec.f) / room
    alphas = jnp.concatenate([jnp.zeros(1, spec.f.dtype), alpha_max * ratio ** -jnp.arange(rungs - 1, -1, -1, dtype=spec.f.dtype)])
    eye = jnp.eye(n, dtype=spec.M.dtype)
    qdd = -cholesky_solve(spec.M + alphas[:, None, None] * eye, jnp.broadcast_to(spec.f, (rungs + 1, n)))
    ok = jnp.all((qdd >= lo) & (qdd <= hi), axis=-1)
    k = jnp.where(ok.any(), jnp.argmax(ok), rungs)  # alphas ascend: the first feasible rung is the smallest alpha
    return jnp.clip(qdd[k], lo, hi)


LIMITERS = {"metric": solve_in_box, "shrink": solve_shrinking}
