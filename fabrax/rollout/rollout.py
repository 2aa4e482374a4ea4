"""Rollouts: fabric integration in `lax.scan`, time to goal and command sequences.

`rollout_sequence` integrates a fabric through m command segments (gfcs_paper
eqs. 1-7): segment i uses the parameters `params_seq[i]` (e.g. a joint
attractor aimed at command q_g^i) from the end state of segment i-1, until its
goal test holds or `steps` steps pass; its duration is t*_i (eq. 2). The last
segment is the final goal. Steps run in chunks of a `lax.scan` inside a
`lax.while_loop` that stops once the arm is done; under `jax.vmap` the loop
runs until every arm is done (early exit for the batch) and finished arms
hold still. `rollout_population` runs many sequences from one start, goes on
with its running arms alone once most have finished, and may stop the whole
population once enough of it has arrived. All of it is one pure function: jit it, vmap it over arms, goals
and scenes.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from flax import struct

from fabrax import sharding, validate
from fabrax.fabrics.fabric import Fabric, Params
from fabrax.fabrics.limits import LIMITERS, acceleration_box
from fabrax.fabrics.spec import solve
from fabrax.rollout.trajectory import Trajectory
from fabrax.scene import FAR, Scene
from fabrax.shrink import loop as shrink_loop

Reached = Callable[[Params, jax.Array, jax.Array], jax.Array]
Distance = Callable[[Params, jax.Array], jax.Array]
INTEGRATORS = ("euler", "second_order", "rk4")


def accel(fabric: Fabric, params: Params, scene: Scene, q, qd, dt: float, limits: bool | str = True):
    """Fabric acceleration with the limits of thesis §3.3.4 applied; also returns the clearance.
    limits: True or "metric" (`limits.solve_in_box`), "shrink" (thesis eq. 3.9, `limits.solve_shrinking`),
    False (none)."""
    ev = fabric.evaluate(params, scene, q, qd)
    if limits is False:
        return solve(ev.spec), ev.terms.clearance
    limiter = LIMITERS["metric" if limits is True else limits]
    with jax.named_scope("limiter"):
        lo, hi = acceleration_box(fabric.robot, q, qd, dt)
        return limiter(ev.spec, lo, hi), ev.terms.clearance


def integrate(fabric: Fabric, params: Params, scene: Scene, q, qd, dt: float, integrator: str = "second_order", limits: bool | str = True):
    """One step. euler: q += dt qd (gfcs_paper); second_order: q += dt qd + dt^2/2 qdd (thesis eq. 3.13-3.14); rk4 for accuracy checks."""
    qdd, clearance = accel(fabric, params, scene, q, qd, dt, limits)
    if integrator == "euler":
        return q + dt * qd, qd + dt * qdd, qdd, clearance
    if integrator == "second_order":
        return q + dt * qd + 0.5 * dt * dt * qdd, qd + dt * qdd, qdd, clearance
    if integrator == "rk4":
        f = lambda q_, qd_: accel(fabric, params, scene, q_, qd_, dt, limits)[0]  # noqa: E731
        k1q, k1v = qd, qdd
        k2q, k2v = qd + 0.5 * dt * k1v, f(q + 0.5 * dt * k1q, qd + 0.5 * dt * k1v)
        k3q, k3v = qd + 0.5 * dt * k2v, f(q + 0.5 * dt * k2q, qd + 0.5 * dt * k2v)
        k4q, k4v = qd + dt * k3v, f(q + dt * k3q, qd + dt * k3v)
        return (
            q + dt / 6 * (k1q + 2 * k2q + 2 * k3q + k4q),
            qd + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v),
            qdd,
            clearance,
        )
    raise ValueError(f"integrator must be one of {INTEGRATORS}, got '{integrator}'")


@struct.dataclass
class _Carry:
    t: jax.Array  # steps taken
    seg: jax.Array  # current segment
    seg_t: jax.Array  # steps taken in the current segment
    q: jax.Array
    qd: jax.Array
    done: jax.Array
    reached: jax.Array
    t_goal: jax.Array
    seg_times: jax.Array
    clearance: jax.Array
    best: jax.Array  # smallest distance to the current segment's command so far
    since: jax.Array  # steps since `best` last fell by min_progress


def _check_shared(shared: Params | None, varying: Params, name: str) -> None:
    if shared is not None and not set(varying) <= set(shared):
        raise ValueError(f"{name}: terms {sorted(set(varying) - set(shared))} are not in `shared`; pass the full parameters as `shared`")


def _merge(shared: Params | None, varying: Params) -> Params:
    """`shared` with the leaves of the partial tree `varying` (same nested keys) put in."""
    if shared is None:
        return varying
    out = dict(shared)
    for k, v in varying.items():
        out[k] = _merge(shared[k], v) if isinstance(v, dict) else v
    return out


def _program(fabric, scene, q0, qd0, reached, m, *, dt, steps, integrator, limits, chunk, stop_at_goal, patience, via, shared):
    """(init, body, finish) of one arm's sequence rollout: init(params_seq) -> loop state; body advances
    one chunk of `chunk` steps; finish turns the final loop state into a `Trajectory`."""
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {INTEGRATORS}, got '{integrator}'")
    if limits not in (True, False) and limits not in LIMITERS:
        raise ValueError(f"limits must be True, False or one of {tuple(LIMITERS)}, got {limits!r}")
    if patience is not None:
        patience = (patience[0], max(1, int(round(patience[1] / dt))), patience[2])  # seconds -> steps
    total = m * steps
    n_chunks = -(-total // chunk)
    rows = 1 + n_chunks * chunk
    dtype = q0.dtype

    def step(params_seq, c: _Carry):
        p = _merge(shared, jax.tree.map(lambda a: a[c.seg], params_seq))
        q, qd, qdd, clearance = integrate(fabric, p, scene, c.q, c.qd, dt, integrator, limits)
        seg_t = c.seg_t + 1
        last = c.seg == m - 1
        hit = reached(p, q, qd) if via is None else jnp.where(last, reached(p, q, qd), via(p, q, qd))
        if patience is None:
            best, since = c.best, c.since
        else:  # no progress toward the command for `patience` steps: charge the whole budget and move on
            dist, wait, min_progress = patience[0](p, q), patience[1], patience[2]
            better = dist < c.best - min_progress
            best, since = jnp.where(better, dist, c.best), jnp.where(better, 0, c.since + 1)
            seg_t = jnp.where((since >= wait) & ~hit, steps, seg_t)
        seg_over = hit | (seg_t >= steps)
        final_hit = last & hit
        new = _Carry(
            t=c.t + 1,
            seg=jnp.where(seg_over & ~last, c.seg + 1, c.seg),
            seg_t=jnp.where(seg_over & ~last, 0, seg_t),
            q=q,
            qd=qd,
            done=last & ((stop_at_goal & hit) | (seg_t >= steps)),
            reached=c.reached | final_hit,
            t_goal=jnp.where(final_hit & ~c.reached, (c.t + 1) * dt, c.t_goal),
            seg_times=jnp.where((jnp.arange(m) == c.seg) & seg_over, seg_t * dt, c.seg_times),
            clearance=jnp.minimum(c.clearance, clearance),
            best=jnp.where(seg_over, jnp.inf, best),
            since=jnp.where(seg_over, 0, since),
        )
        new = jax.tree.map(lambda a, b: jnp.where(c.done, a, b), c, new)  # finished arms hold still
        zero = jnp.zeros_like(qdd)
        return new, (new.q, jnp.where(c.done, zero, new.qd), jnp.where(c.done, zero, qdd))

    def init(params_seq):
        buf = (
            jnp.zeros((rows, q0.shape[0]), dtype).at[0].set(q0),
            jnp.zeros((rows, q0.shape[0]), dtype).at[0].set(qd0),
            jnp.zeros((rows, q0.shape[0]), dtype),
        )
        c0 = _Carry(
            t=jnp.zeros((), jnp.int32),
            seg=jnp.zeros((), jnp.int32),
            seg_t=jnp.zeros((), jnp.int32),
            q=q0,
            qd=qd0,
            done=jnp.zeros((), bool),
            reached=jnp.zeros((), bool),
            t_goal=jnp.asarray(total * dt, dtype),
            seg_times=jnp.full((m,), steps * dt, dtype),
            clearance=jnp.asarray(FAR, dtype),
            best=jnp.asarray(jnp.inf, dtype),
            since=jnp.zeros((), jnp.int32),
        )
        return jnp.zeros((), jnp.int32), c0, buf

    def body(params_seq, state):
        i, c, buf = state
        c, (qs, qds, qdds) = jax.lax.scan(lambda c_, _: step(params_seq, c_), c, None, length=chunk)
        buf = tuple(jax.lax.dynamic_update_slice_in_dim(b, x, 1 + i * chunk, axis=0) for b, x in zip(buf, (qs, qds, qdds)))
        return i + 1, c, buf

    def finish(state):
        _, c, (qs, qds, qdds) = state
        length = c.t + 1
        valid = (jnp.arange(rows) < length)[:, None]
        qs = jnp.where(valid, qs, c.q)[: total + 1]
        qds = jnp.where(valid, qds, 0.0)[: total + 1]
        qdds = jnp.where(valid, qdds, 0.0)[: total + 1]
        return Trajectory(qs, qds, qdds, jnp.asarray(dt, dtype), length, c.reached, c.t_goal, c.seg_times, c.clearance)

    return init, body, finish, n_chunks


def rollout_sequence(
    fabric: Fabric,
    params_seq: Params,
    scene: Scene,
    q0: jax.Array,
    qd0: jax.Array,
    reached: Reached,
    *,
    dt: float = 0.01,
    steps: int = 700,
    integrator: str = "second_order",
    limits: bool | str = True,
    chunk: int = 25,
    stop_at_goal: bool = True,
    patience: tuple[Distance, float, float] | None = None,
    via: Reached | None = None,
    shared: Params | None = None,
) -> Trajectory:
    """Integrate through every segment of `params_seq` (leading axis m); see the module docstring.

    steps: budget per segment (t_max = steps dt). The returned trajectory has
    m * steps + 1 rows; rows past `length` repeat the final state.
    With stop_at_goal=False the last segment runs its whole budget.
    patience: (distance, seconds, min_progress): a segment whose `distance(params, q)` to its
    command has not fallen by min_progress for `seconds` (an arm at rest or chattering against an
    obstacle short of its command) ends there and is charged its whole budget (t*_i = t_max).
    via: the test that ends an intermediate segment (default `reached`), e.g. a looser
    tolerance so that the arm passes a via command without stopping at it.
    shared: the parameters that every segment shares; params_seq then holds only
    those that change (a partial tree of the same nested keys, e.g. the goal
    terms' from `ArmFabric.aimed`). The shared ones stay constants of the
    compiled step, which XLA folds (a step with every parameter per arm is
    slower).
    """
    validate.vector("q0", q0, fabric.robot.dof)
    validate.vector("qd0", qd0, fabric.robot.dof)
    _check_shared(shared, params_seq, "params_seq")
    m = jax.tree.leaves(params_seq)[0].shape[0]
    opts = dict(dt=dt, steps=steps, integrator=integrator, limits=limits, chunk=chunk, patience=patience, via=via, shared=shared)
    init, body, finish, n_chunks = _program(fabric, scene, q0, qd0, reached, m, stop_at_goal=stop_at_goal, **opts)
    cond = lambda s: (s[0] < n_chunks) & ~s[1].done  # noqa: E731
    return finish(jax.lax.while_loop(cond, lambda s: body(params_seq, s), init(params_seq)))


def rollout_population(
    fabric: Fabric,
    params_seqs: Params,
    scene: Scene,
    q0: jax.Array,
    qd0: jax.Array,
    reached: Reached,
    *,
    enough: int | None = None,
    dt: float = 0.01,
    steps: int = 700,
    integrator: str = "second_order",
    limits: bool | str = True,
    chunk: int = 25,
    patience: tuple[Distance, float, float] | None = None,
    via: Reached | None = None,
    shrink: int = 2,
    shared: Params | None = None,
) -> Trajectory:
    """A population of command sequences (`params_seqs`, leading axes (P, m)) from one start in one scene.

    The same as `jax.vmap(rollout_sequence)` except that the loop also stops,
    at a chunk boundary, once `enough` arms have reached the final goal without
    a collision: an optimiser that ranks candidates by time to goal then needs
    no more (CMA-ES weighs only its best half positively). Arms still running
    are returned as not reached, with their unfinished segments charged the
    whole budget. enough=None runs every arm to its end. patience, via: as `rollout_sequence`.
    shrink: once at most 1/shrink of the population still runs, those arms go on alone as a
    smaller batch (`fabrax.shrink`; 1: never), so that finished arms cost no more steps; 2 halves
    the batch (64, 32, 16 arms), with the same costs as 4.
    shared: the parameters common to every arm and segment, unbatched; params_seqs
    then holds only those that vary (as `rollout_sequence`).
    """
    validate.vector("q0", q0, fabric.robot.dof)
    validate.vector("qd0", qd0, fabric.robot.dof)
    if shrink < 1:
        raise ValueError(f"shrink must be at least 1 (1: never shrink), got {shrink}")
    _check_shared(shared, params_seqs, "params_seqs")
    m = jax.tree.leaves(params_seqs)[0].shape[1]
    opts = dict(dt=dt, steps=steps, integrator=integrator, limits=limits, chunk=chunk, patience=patience, via=via, shared=shared)
    init, body, finish, n_chunks = _program(fabric, scene, q0, qd0, reached, m, stop_at_goal=True, **opts)
    enough = jax.tree.leaves(params_seqs)[0].shape[0] + 1 if enough is None else enough

    def running(st):
        i, c, _ = st[1]
        return (i < n_chunks) & ~c.done

    def clean(st):
        c = st[1][1]
        return (c.reached & (c.clearance >= 0.0)).astype(jnp.int32)

    def advance(st):  # each device steps its share; the stop tests above count the whole population
        return st[0], sharding.per_device(jax.vmap(body))(*st)

    params_seqs = sharding.constrain(params_seqs)  # the population over the local devices
    state = (params_seqs, sharding.per_device(jax.vmap(init))(params_seqs))
    state = shrink_loop(advance, running, state, shrink, count=clean, limit=enough)
    return jax.vmap(finish)(state[1])


def rollout(fabric: Fabric, params: Params, scene: Scene, q0, qd0, reached: Reached, **kwargs) -> Trajectory:
    """Integrate toward a single goal: `rollout_sequence` with one segment."""
    return rollout_sequence(fabric, jax.tree.map(lambda a: a[None], params), scene, q0, qd0, reached, **kwargs)


def reach(
    fabric, params: Params, problems, aim: str = "joint", stop: str = "goal", settle: float | None = None, sub_batch: int = 64, **kwargs
) -> Trajectory:
    """Roll the fabric out toward each problem's goal, batched with `jax.vmap`.

    `problems` is a `fabrax.problems.ProblemBatch` (`fabrax.problems.batch`); `fabric` an `ArmFabric`; `aim` as
    `ArmFabric.with_goal`. stop="goal" ends an arm's rollout at its goal test
    (`reached`), stop="posture" only once the null-space posture has arrived too
    (`posture_reached`); with `settle` (rad/s) the test also needs every joint
    slower than that, so that a rollout ends at rest, not passing through the goal.
    Returns a batched `Trajectory`. The problems split over the local devices, and a device's share
    larger than `sub_batch` runs as consecutive sub-batches of that size (`fabrax.sharding.batched`;
    a whole batch overflows the CPU's cache; experiments/bench_fabric_step.py --chunk measures it).
    """
    if stop not in ("goal", "posture"):
        raise ValueError(f"stop must be 'goal' or 'posture', got '{stop}'")
    goal_test = fabric.reached if stop == "goal" else fabric.posture_reached

    def test(p, q, qd):
        hit = goal_test(p, q, qd)
        return hit if settle is None else hit & (jnp.max(jnp.abs(qd)) <= settle)

    def one(start_q, start_qd, joint_goal, goal_q, goal_pos, goal_quat, scene):
        p = fabric.with_goal(params, joint_goal, goal_q, goal_pos, goal_quat, aim)
        return rollout(fabric, p, scene, start_q, start_qd, test, **kwargs)

    b = problems
    args = (b.start_q, b.start_qd, b.joint_goal, b.goal_q, b.goal_pos, b.goal_quat, b.scene)
    return sharding.batched(jax.vmap(one), sub_batch)(*args)
