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
from fabrax.planners.gfcs.cost import GOALS, population_cost, to_commands, to_unconstrained
from fabrax.problems.problem import ProblemBatch
from fabrax.rollout.trajectory import Trajectory


@dataclasses.dataclass(frozen=True)
class GFCSConfig:
    """GFCS solver settings. The defaults are the `gfcs` method preset (configs/method/gfcs.yaml,
    checked equal by tests/test_gfcs.py): `GFCSConfig()` is the planner of the README's tables;
    `length_weight=0, direct=False, via_tolerance=None` is gfcs_paper's eq. 4 as written."""

    n_commands: int = 1  # intermediate commands; the goal is appended ("length two" = 1)
    population: int = 64  # N_samp
    batches: int = 5  # N_iters
    top_m: int = 4  # candidates returned (the self-supervised buffer keeps these)
    std_init: float = 1.0  # CMA-ES step size in the unconstrained space
    dt: float = 0.01
    t_max: float = 7.0  # per command
    penalty: float = 100.0  # M: final goal not reached
    collision_penalty: float = 100.0
    via_tolerance: float | None = 0.5  # rad: an intermediate command counts as passed within this (None: the goal tolerance)
    patience: float | None = 1.0  # s without progress toward a command ends its segment, charged t_max (None: off)
    stop_after: float | None = 0.5  # stop a batch once this fraction of it arrived cleanly (None: run all to the end)
    final_pose: bool = True  # the goal segment also attracts the hand to its pose at the goal (`population_cost`)
    length_weight: float = 1.0  # s per metre of goal-frame path added to the cost (0: gfcs_paper eq. 4)
    direct: bool = True  # the first batch's first candidate commands the start: the fabric aimed straight at the goal
    hand_mass: float | None = None  # the hand attractor's far mass in the rollouts (`with_hand_mass`; None: the fabric's)
    goal: str = "joint"  # "pose": the last segment aims the hand at the goal pose (pose goals need no IK; `population_cost`)
    shrink: int = 4  # the rollout's batch shrinks to 1/shrink of the population once at most that many still run (1: never)

    def __post_init__(self):
        if self.goal not in GOALS:
            raise ValueError(f"GFCS goal must be one of {GOALS}, got {self.goal!r}")
        if self.hand_mass is not None and not self.hand_mass > 0:
            raise ValueError(f"GFCS hand_mass must be a positive mass (or null), got {self.hand_mass!r}")
        if isinstance(self.shrink, bool) or not isinstance(self.shrink, int) or self.shrink < 1:
            raise ValueError(f"GFCS shrink must be a positive integer (1: never shrink), got {self.shrink!r}")

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


def _evaluate(fabric, params: Params, problem: ProblemBatch, pop: jax.Array, cfg: GFCSConfig):
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
        goal=cfg.goal,
        hand_mass=cfg.hand_mass,
        shrink=cfg.shrink,
    )
    k = jnp.argmin(costs)
    return costs, jax.tree.map(lambda a: a[k], trajs)


@dataclasses.dataclass(frozen=True)
class BatchFns:
    """The batch's functions, each a `Compiled`: the population rollout, compiled once per problem
    shape (the scene's capacity), and CMA-ES's, once per solver. One jitted batch (ask, roll out,
    tell) compiled the rollout twice, for the first batch and the later ones. With `problems`, every
    function takes a leading axis of problems solved together (`solve_batch`)."""

    evaluate: Compiled  # (problem, pop) -> (costs, best candidate's trajectory)
    start: Compiled  # (samples, costs, key) -> CMA-ES state, its mean at the samples' weighted elite
    ask: Compiled  # (state, key) -> (pop, state)
    tell: Compiled  # (pop, costs, state, key) -> state
    problems: bool = False  # the functions are vmapped over a leading axis of problems


def make_step(fabric, params: Params, cfg: GFCSConfig, problems: bool = False) -> BatchFns:
    """The batch functions; build them once and pass them to `solve` (or, with `problems=True`, to
    `solve_batch`) for many problems."""
    dof = fabric.robot.dof
    es = CMA_ES(population_size=cfg.population, solution=jnp.zeros((cfg.n_commands, dof)))
    es_params = es.default_params.replace(std_init=cfg.std_init)

    def start(samples, costs, key):
        k_init, k_tell = jax.random.split(key)
        state = es.init(k_init, jnp.mean(samples, axis=0), es_params)
        return es.tell(k_tell, samples, costs, state, es_params)[0]

    fns = {
        "evaluate": lambda problem, pop: _evaluate(fabric, params, problem, pop, cfg),
        "start": start,
        "ask": lambda state, key: es.ask(key, state, es_params),
        "tell": lambda pop, costs, state, key: es.tell(key, pop, costs, state, es_params)[0],
    }
    wrap = jax.vmap if problems else (lambda f: f)
    return BatchFns(**{k: Compiled(jax.jit(wrap(f))) for k, f in fns.items()}, problems=problems)


def _check_samples(samples, shape: tuple) -> jax.Array:
    if samples.shape != shape:
        raise ValueError(f"samples: expected shape {shape}, got {samples.shape}")
    return jnp.asarray(samples)


def solve(fabric, params: Params, problem: ProblemBatch, key: jax.Array, cfg: GFCSConfig = GFCSConfig(), samples=None, steps_fns=None) -> GFCSResult:
    """Algorithm 1 on one problem. samples: (population, n, dof) warm-start candidates in the
    unconstrained space (default: uniform). steps_fns: reuse `make_step(...)` across problems."""
    robot = fabric.robot
    _check_goals(problem, cfg)
    fns = steps_fns or make_step(fabric, params, cfg)
    if fns.problems:
        raise ValueError("solve: steps_fns were made for batches of problems (make_step(problems=True)); use solve_batch")
    key, k_samp = jax.random.split(key)
    if samples is None:
        samples = uniform_sampler(k_samp, robot, cfg.population, cfg.n_commands)
    samples = _check_samples(samples, (cfg.population, cfg.n_commands, robot.dof))
    if cfg.direct:  # every command at the start is passed at once: the rollout is the fabric alone
        samples = samples.at[0].set(to_unconstrained(problem.start_q, robot.lower, robot.upper))
    return _optimise(fns, robot, problem, samples, jax.random.split(key, cfg.batches), cfg, 1)[0]


def solve_batch(
    fabric, params: Params, problems: ProblemBatch, keys: jax.Array, cfg: GFCSConfig = GFCSConfig(), samples=None, steps_fns=None
) -> list[GFCSResult]:
    """Algorithm 1 on K problems at once: `problems` is a `ProblemBatch` whose leaves have a leading axis of
    K (scenes padded to one capacity, e.g. `fabrax.scene.stack`), `keys` (K,) one key per problem.
    Every batch rolls out all K populations in one call and runs K CMA-ES updates in one `vmap`, so
    an accelerator steps K x population arms together; each problem's result is the one `solve`
    gives it with its key (float rounding aside). samples: (K, population, n, dof) or None (uniform).
    Per-batch wall times are the whole batch's, shared by its problems."""
    robot = fabric.robot
    _check_goals(problems, cfg)
    fns = steps_fns or make_step(fabric, params, cfg, problems=True)
    if not fns.problems:
        raise ValueError("solve_batch: steps_fns were made for one problem; use make_step(..., problems=True)")
    k = int(problems.start_q.shape[0])
    if keys.shape[0] != k:
        raise ValueError(f"solve_batch: {k} problems but {keys.shape[0]} keys")
    split = jax.vmap(jax.random.split)(keys)  # as `solve` splits each problem's key
    keys, k_samp = split[:, 0], split[:, 1]
    if samples is None:
        samples = jax.vmap(lambda kk: uniform_sampler(kk, robot, cfg.population, cfg.n_commands))(k_samp)
    samples = _check_samples(samples, (k, cfg.population, cfg.n_commands, robot.dof))
    if cfg.direct:
        samples = samples.at[:, 0].set(to_unconstrained(problems.start_q, robot.lower, robot.upper)[:, None])
    batch_keys = jax.vmap(lambda kk: jax.random.split(kk, cfg.batches))(keys)  # (K, batches)
    return _optimise(fns, robot, problems, samples, jnp.swapaxes(batch_keys, 0, 1), cfg, k)


def _check_goals(problems: ProblemBatch, cfg: GFCSConfig) -> None:
    """With goal="joint" the last command is the joint goal: a pose goal fails here, before any work."""
    if not isinstance(problems, ProblemBatch):
        raise ValueError(f"GFCS takes a fabrax.problems.ProblemBatch (ProblemBatch.of(problem)), got {type(problems).__name__}")
    if cfg.goal == "joint" and not np.all(np.asarray(problems.joint_goal)):
        raise ValueError("GFCS with goal=joint needs joint goals; a problem has a pose goal (method.goal=pose, or give it an IK joint goal)")


def _optimise(fns: BatchFns, robot, problem, samples, keys, cfg: GFCSConfig, k: int) -> list[GFCSResult]:
    """The batches of Algorithm 1 for one problem (k = 1, unbatched functions) or k problems
    (functions vmapped over problems); keys[b] is batch b's key (of each problem)."""
    evaluate, compile_s = fns.evaluate.get(problem, samples)
    costs_s = evaluate.out_info[0]  # with its sharding: the population splits over the local devices
    start, c1 = fns.start.get(samples, costs_s, keys[0])
    compile_s += c1
    if cfg.batches > 1:
        (ask, c0), (tell, c1) = fns.ask.get(start.out_info, keys[0]), fns.tell.get(samples, costs_s, start.out_info, keys[0])
        compile_s += c0 + c1
    split = jax.vmap(jax.random.split) if fns.problems else jax.random.split
    many = (lambda x: x) if fns.problems else (lambda x: x[None])  # results with a leading problem axis

    all_z, all_cost, walls, trajs = [], [], [], []
    state = None
    for b in range(cfg.batches):
        t0 = time.perf_counter()
        if b == 0:
            pop = samples
            costs, traj = run(evaluate, problem, pop)
            state = run(start, pop, costs, keys[0])
        else:
            sub = split(keys[b])
            k_ask, k_tell = (sub[:, 0], sub[:, 1]) if fns.problems else (sub[0], sub[1])
            pop, state = run(ask, state, k_ask)
            costs, traj = run(evaluate, problem, pop)
            state = run(tell, pop, costs, state, k_tell)
        costs = np.asarray(jax.block_until_ready(costs))
        walls.append(time.perf_counter() - t0)
        all_z.append(np.asarray(many(pop)))
        all_cost.append(many(costs))
        trajs.append(jax.tree.map(many, traj))

    results = []
    for i in range(k):
        best_cost, best_traj, best_z, per_batch = np.inf, None, None, []
        for b in range(cfg.batches):
            j = int(np.argmin(all_cost[b][i]))
            if all_cost[b][i][j] < best_cost:
                best_cost, best_z = float(all_cost[b][i][j]), all_z[b][i][j]
                best_traj = jax.tree.map(lambda a: a[i], trajs[b])
            per_batch.append({"batch": b + 1, "best_cost": best_cost, "trajectory": best_traj, "z": best_z, "wall_s": walls[b]})
        zs, cs = np.concatenate([z[i] for z in all_z]), np.concatenate([c[i] for c in all_cost])
        order = np.argsort(cs)[: cfg.top_m]
        results.append(
            GFCSResult(
                best_z=best_z,
                best_commands=np.asarray(to_commands(jnp.asarray(best_z), robot.lower, robot.upper)),
                best_cost=best_cost,
                trajectory=best_traj,
                top_z=zs[order],
                top_cost=cs[order],
                per_batch=per_batch,
                compile_s=compile_s,
            )
        )
    return results
