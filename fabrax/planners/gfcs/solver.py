"""SolveGFCOP with warm-started CMA-ES (gfcs_paper Algorithm 1), on evosax 0.3.

Batch 1 evaluates the sampler's candidates (uniform in the joint limits, or an
energy-based model's samples); CMA-ES starts from them (its mean at their
weighted elite after one `tell`) and proposes batches 2..N_iters. A batch is
three compiled calls that stay on the device: `ask`, the population rolled
out in one `vmap` (`population_cost`), `tell`. Results after every batch are
kept so that a benchmark can report "1 b" and "5 b" from one run.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
from evosax.algorithms import CMA_ES

from fabrax.compiled import Compiled, run
from fabrax.fabrics.fabric import Params
from fabrax.planners.gfcs.cost import GFCOP, population_cost, to_commands, to_unconstrained
from fabrax.rollout.trajectory import Trajectory


@dataclasses.dataclass(frozen=True)
class GFCSConfig:
    n_commands: int = 1  # intermediate commands; the goal is appended ("length two" = 1)
    population: int = 64  # N_samp
    batches: int = 5  # N_iters
    top_m: int = 4  # candidates returned (the self-supervised buffer keeps these)
    std_init: float = 1.0  # CMA-ES step size in the unconstrained space
    dt: float = 0.01
    t_max: float = 7.0  # per command
    penalty: float = 100.0  # M: final goal not reached
    collision_penalty: float = 100.0
    via_tolerance: float | None = None  # rad: an intermediate command counts as passed within this (None: the goal tolerance)
    patience: float | None = 1.0  # s without progress toward a command ends its segment, charged t_max (None: off)
    stop_after: float | None = 0.5  # stop a batch once this fraction of it arrived cleanly (None: run all to the end)
    final_pose: bool = True  # the goal segment also attracts the hand to its pose at the goal (`population_cost`)
    length_weight: float = 0.0  # s per metre of goal-frame path added to the cost (0: gfcs_paper eq. 4)
    direct: bool = False  # the first batch's first candidate commands the start: the fabric aimed straight at the goal

    @property
    def enough(self) -> int | None:
        return None if self.stop_after is None else max(self.top_m, int(round(self.stop_after * self.population)))

    @property
    def steps(self) -> int:
        return int(round(self.t_max / self.dt))


@dataclasses.dataclass
class GFCSResult:
    best_z: np.ndarray  # (n, dof) unconstrained
    best_commands: np.ndarray  # (n, dof) joint commands
    best_cost: float
    trajectory: Trajectory  # of the best candidate so far, after the last batch
    top_z: np.ndarray  # (m, n, dof) best candidates over all batches
    top_cost: np.ndarray  # (m,)
    per_batch: list[dict]  # after each batch: best cost so far, reached, its trajectory, wall time
    compile_s: float


def uniform_sampler(key: jax.Array, robot, population: int, n_commands: int) -> jax.Array:
    """Candidates uniform in the joint limits, as unconstrained z (population, n, dof)."""
    u = jax.random.uniform(key, (population, n_commands, robot.dof), minval=1e-4, maxval=1.0 - 1e-4)
    return jnp.log(u) - jnp.log1p(-u)


def _evaluate(fabric, params: Params, problem: GFCOP, pop: jax.Array, cfg: GFCSConfig):
    costs, trajs = population_cost(
        fabric,
        params,
        problem,
        pop,
        dt=cfg.dt,
        steps=cfg.steps,
        penalty=cfg.penalty,
        collision_penalty=cfg.collision_penalty,
        enough=cfg.enough,
        patience=cfg.patience,
        via_tolerance=cfg.via_tolerance,
        final_pose=cfg.final_pose,
        length_weight=cfg.length_weight,
    )
    k = jnp.argmin(costs)
    return costs, jax.tree.map(lambda a: a[k], trajs)


@dataclasses.dataclass(frozen=True)
class BatchFns:
    """The batch's functions, each a `Compiled`: the population rollout, compiled once per problem
    shape (the scene's capacity), and CMA-ES's, once per solver. One jitted batch (ask, roll out,
    tell) compiled the rollout twice, for the first batch and the later ones."""

    evaluate: Compiled  # (problem, pop) -> (costs, best candidate's trajectory)
    start: Compiled  # (samples, costs, key) -> CMA-ES state, its mean at the samples' weighted elite
    ask: Compiled  # (state, key) -> (pop, state)
    tell: Compiled  # (pop, costs, state, key) -> state


def make_step(fabric, params: Params, cfg: GFCSConfig) -> BatchFns:
    """The batch functions; build them once and pass them to `solve` for many problems."""
    dof = fabric.robot.dof
    es = CMA_ES(population_size=cfg.population, solution=jnp.zeros((cfg.n_commands, dof)))
    es_params = es.default_params.replace(std_init=cfg.std_init)

    def start(samples, costs, key):
        k_init, k_tell = jax.random.split(key)
        state = es.init(k_init, jnp.mean(samples, axis=0), es_params)
        return es.tell(k_tell, samples, costs, state, es_params)[0]

    return BatchFns(
        evaluate=Compiled(jax.jit(lambda problem, pop: _evaluate(fabric, params, problem, pop, cfg))),
        start=Compiled(jax.jit(start)),
        ask=Compiled(jax.jit(lambda state, key: es.ask(key, state, es_params))),
        tell=Compiled(jax.jit(lambda pop, costs, state, key: es.tell(key, pop, costs, state, es_params)[0])),
    )


def solve(fabric, params: Params, problem: GFCOP, key: jax.Array, cfg: GFCSConfig = GFCSConfig(), samples=None, steps_fns=None) -> GFCSResult:
    """Algorithm 1 on one problem. samples: (population, n, dof) warm-start candidates in the
    unconstrained space (default: uniform). steps_fns: reuse `make_step(...)` across problems."""
    robot = fabric.robot
    fns = steps_fns or make_step(fabric, params, cfg)
    key, k_samp = jax.random.split(key)
    if samples is None:
        samples = uniform_sampler(k_samp, robot, cfg.population, cfg.n_commands)
    if samples.shape != (cfg.population, cfg.n_commands, robot.dof):
        raise ValueError(f"samples: expected shape {(cfg.population, cfg.n_commands, robot.dof)}, got {samples.shape}")
    if cfg.direct:  # every command at the start is passed at once: the rollout is the fabric alone
        samples = jnp.asarray(samples).at[0].set(to_unconstrained(problem.start_q, robot.lower, robot.upper))
    keys = jax.random.split(key, cfg.batches)
    evaluate, compile_s = fns.evaluate.get(problem, samples)
    costs_s = evaluate.out_info[0]  # with its sharding: the population splits over the local devices
    start, c1 = fns.start.get(samples, costs_s, keys[0])
    compile_s += c1
    if cfg.batches > 1:
        (ask, c0), (tell, c1) = fns.ask.get(start.out_info, keys[0]), fns.tell.get(samples, costs_s, start.out_info, keys[0])
        compile_s += c0 + c1

    all_z, all_cost, per_batch = [], [], []
    best_cost, best_traj, best_z = np.inf, None, None
    state = None
    for b in range(cfg.batches):
        t0 = time.perf_counter()
        if b == 0:
            pop = samples
            costs, traj = run(evaluate, problem, pop)
            state = run(start, pop, costs, keys[0])
        else:
            k_ask, k_tell = jax.random.split(keys[b])
            pop, state = run(ask, state, k_ask)
            costs, traj = run(evaluate, problem, pop)
            state = run(tell, pop, costs, state, k_tell)
        costs = np.asarray(jax.block_until_ready(costs))
        wall = time.perf_counter() - t0
        pop = np.asarray(pop)
        all_z.append(pop)
        all_cost.append(costs)
        k = int(np.argmin(costs))
        if costs[k] < best_cost:
            best_cost, best_traj, best_z = float(costs[k]), traj, pop[k]
        per_batch.append({"batch": b + 1, "best_cost": best_cost, "trajectory": best_traj, "z": best_z, "wall_s": wall})
    all_z, all_cost = np.concatenate(all_z), np.concatenate(all_cost)
    order = np.argsort(all_cost)[: cfg.top_m]
    return GFCSResult(
        best_z=best_z,
        best_commands=np.asarray(to_commands(jnp.asarray(best_z), robot.lower, robot.upper)),
        best_cost=best_cost,
        trajectory=best_traj,
        top_z=all_z[order],
        top_cost=all_cost[order],
        per_batch=per_batch,
        compile_s=compile_s,
    )
