"""Self-supervised GFCS learning (gfcs_paper Algorithm 2) with checkpoint and resume.

Problems are solved one after another with the current sampler (uniform at
first, then SGLD on the energy model); the top-m solutions of each solve that
reached the goal without collision enter a FIFO buffer (MaintainBuffer), and
the model is retrained on the buffer after every `retrain_every` solves, for
`passes` passes over the problems. Every solve ends with a checkpoint (model,
optimiser, buffer, position, in one msgpack file), and all randomness is
derived from (seed, position), so an interrupted run resumes to the same
buffer and model.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx, serialization, traverse_util

from fabrax.planners.gfcs.autoencoder import DistanceAE
from fabrax.planners.gfcs.autoencoder import fit as fit_autoencoder
from fabrax.planners.gfcs.cost import to_commands, to_unconstrained
from fabrax.planners.gfcs.ebm import EnergyModel, SGLDConfig, sgld, train_step
from fabrax.planners.gfcs.encoding import Encoding
from fabrax.planners.gfcs.solver import GFCSConfig, make_step, solve
from fabrax.problems.problem import ProblemBatch
from fabrax.settings import from_mapping
from fabrax.state_io import from_flat, to_flat


@dataclasses.dataclass(frozen=True)
class WarmStart:
    """How the trained model warm-starts CMA-ES (gfcs_paper §IV-B: SGLD particles from uniform
    starts, "used as solutions during inference"). The default runs 100 steps without noise, each
    particle descending to its nearest low-energy mode (chosen on train problems the sampler did
    not learn from; `experiments/gfcs_sampler.py`); `sgld` None runs the training negatives' SGLD.
    `oversample` k > 1 draws k x population particles and keeps the population lowest in energy,
    the model's own ranking of its samples (the paper's "candidate solution with the lowest cost"
    read as the lowest energy). `replay` in [0, 1] is the share of the population drawn instead
    from the buffer's solutions at random, each moved by N(0, replay_noise^2) in the normalised
    joint space: the class's prior over solutions without the model's conditioning (1: no model)."""

    sgld: SGLDConfig | None = SGLDConfig(steps=100, step=0.01, noise=0.0)
    oversample: int = 1
    replay: float = 0.0
    replay_noise: float = 0.1

    def __post_init__(self):
        if not isinstance(self.oversample, int) or self.oversample < 1:
            raise ValueError(f"warm.oversample must be a positive integer, got {self.oversample!r}")
        if not 0.0 <= self.replay <= 1.0:
            raise ValueError(f"warm.replay must be a share in [0, 1], got {self.replay!r}")
        if self.replay_noise < 0.0:
            raise ValueError(f"warm.replay_noise must be >= 0, got {self.replay_noise!r}")


@dataclasses.dataclass(frozen=True)
class SelfSupConfig:
    buffer_size: int = 200
    top_m: int = 4
    retrain_every: int = 25
    passes: int = 2
    train_steps: int = 100
    batch: int = 32
    n_neg: int = 8
    lr: float = 1e-4
    hidden: int = 800
    layers: int = 3
    sgld: SGLDConfig = SGLDConfig(steps=20)
    seed: int = 0
    latent: int | None = None  # compress d_E to this many numbers with an autoencoder (None: use d_E as is)
    ae_steps: int = 500
    warm: WarmStart = WarmStart()


@dataclasses.dataclass
class Learner:
    """The energy model, its optimiser and the buffer of (context, target, cost)."""

    model: EnergyModel
    opt: nnx.Optimizer
    contexts: np.ndarray  # (B, C)
    targets: np.ndarray  # (B, D) in [0, 1]
    costs: np.ndarray  # (B,)
    solved: int = 0  # solves done (position in the schedule)
    trained: bool = False
    losses: list = dataclasses.field(default_factory=list)
    ae: DistanceAE | None = None  # compresses the scene part of contexts (SelfSupConfig.latent)


def reduce(learner: Learner, x: jax.Array) -> jax.Array:
    """A raw encoding x_c = [q0, qd0, q_goal, d_E] as the energy model sees it: d_E through the
    learner's autoencoder when it has one."""
    if learner.ae is None:
        return x
    k = x.shape[-1] - learner.ae.n
    return jnp.concatenate([x[..., :k], learner.ae.encode(x[..., k:])], axis=-1)


def new_learner(context_dim: int, target_dim: int, cfg: SelfSupConfig) -> Learner:
    model = EnergyModel(context_dim, target_dim, cfg.hidden, cfg.layers, rngs=nnx.Rngs(cfg.seed))
    opt = nnx.Optimizer(model, optax.adam(cfg.lr), wrt=nnx.Param)
    return Learner(model, opt, np.zeros((0, context_dim), np.float32), np.zeros((0, target_dim), np.float32), np.zeros(0, np.float32))


def save(learner: Learner, path: Path, settings: dict | None = None) -> None:
    """Write the learner atomically (a crash mid-write never leaves a broken checkpoint), with the
    run's `settings` (see `run`) so that a resume can refuse other ones."""
    data = {
        "model": to_flat(nnx.to_pure_dict(nnx.state(learner.model, nnx.Param))),
        "opt": to_flat(nnx.to_pure_dict(nnx.state(learner.opt, nnx.OptState))),
        "contexts": learner.contexts,
        "targets": learner.targets,
        "costs": learner.costs,
        "solved": learner.solved,
        "trained": learner.trained,
        "losses": np.asarray(learner.losses, np.float32),
    }
    if settings is not None:
        data["settings"] = np.frombuffer(json.dumps(settings, sort_keys=True).encode(), np.uint8)  # msgpack holds arrays, not str
    if learner.ae is not None:
        data["ae"] = to_flat(nnx.to_pure_dict(nnx.state(learner.ae, nnx.Param)))
        data["ae_dims"] = np.asarray([learner.ae.n, learner.ae.latent, learner.ae.width])
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(serialization.msgpack_serialize(jax.tree.map(np.asarray, data)))
    os.replace(tmp, path)


def load(path: Path, context_dim: int, target_dim: int, cfg: SelfSupConfig, expect: dict | None = None) -> Learner:
    """Read a checkpoint; with `expect` (a run's settings), refuse one written with other settings."""
    try:
        data = serialization.msgpack_restore(Path(path).read_bytes())
    except (OSError, ValueError) as e:
        raise ValueError(f"cannot read GFCS checkpoint {path}: {e}") from e
    if expect is not None and "settings" in data:
        old = traverse_util.flatten_dict(json.loads(np.asarray(data["settings"], np.uint8).tobytes().decode()), sep=".")
        new = traverse_util.flatten_dict(json.loads(json.dumps(expect, sort_keys=True)), sep=".")
        show = lambda v: f"{len(v)} items" if isinstance(v, list) and len(v) > 6 else repr(v)  # noqa: E731
        differ = [f"{k} ({show(old.get(k))} -> {show(new.get(k))})" for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]
        if differ:
            raise ValueError(f"GFCS checkpoint {path} was written with other settings: {', '.join(differ)}; use another run directory")
    learner = new_learner(context_dim, target_dim, cfg)
    for obj, key, filt in ((learner.model, "model", nnx.Param), (learner.opt, "opt", nnx.OptState)):
        state = nnx.state(obj, filt)
        nnx.replace_by_pure_dict(state, from_flat(data[key]))
        nnx.update(obj, state)
    learner.contexts, learner.targets, learner.costs = (np.asarray(data[k]) for k in ("contexts", "targets", "costs"))
    learner.solved, learner.trained = int(data["solved"]), bool(data["trained"])
    learner.losses = [float(v) for v in np.asarray(data["losses"]).reshape(-1)]
    if "ae" in data:
        n, latent, width = (int(v) for v in np.asarray(data["ae_dims"]))
        learner.ae = DistanceAE(n, latent, width, rngs=nnx.Rngs(0))
        state = nnx.state(learner.ae, nnx.Param)
        nnx.replace_by_pure_dict(state, from_flat(data["ae"]))
        nnx.update(learner.ae, state)
    return learner


def settings(cfg: dict) -> tuple[SelfSupConfig, Encoding]:
    """SelfSupConfig and Encoding from an experiments/gfcs.py config (its `selfsup`, `encoding`, `seed`)."""
    ss_cfg = from_mapping(SelfSupConfig, {**cfg["selfsup"], "seed": cfg["seed"]}, "selfsup")
    return ss_cfg, from_mapping(Encoding, cfg["encoding"], "encoding")


def load_run(run_dir: str | Path, run_cfg: dict, robot, n_commands: int) -> tuple[Learner, SelfSupConfig, Encoding]:
    """The trained sampler of an experiments/gfcs.py run directory (its sampler.msgpack) with the
    run's resolved config `run_cfg` (the caller reads hydra's .hydra/config.yaml), for evaluating
    it elsewhere (`fabrax bench method=gfcs_learned method.run=DIR`)."""
    run_dir = Path(run_dir)
    ckpt = run_dir / "sampler.msgpack"
    if not ckpt.exists():
        raise FileNotFoundError(f"{run_dir}: not an experiments/gfcs.py run directory (no sampler.msgpack)")
    ss_cfg, enc = settings(run_cfg)
    learner = load(ckpt, 3 * robot.dof + (ss_cfg.latent or enc.n_reference), n_commands * robot.dof, ss_cfg)
    if not learner.trained:
        raise ValueError(f"{ckpt}: the sampler was never trained")
    return learner, ss_cfg, enc


def require_joint_goals(problems: list) -> None:
    """The context x_c holds the joint goal (gfcs_paper §IV-B): a problem given only a pose has none
    to encode, and is refused before any work (the learned sampler is for joint goals)."""
    pose = [p.name for p in problems if p.goal_q is None]
    if pose:
        raise ValueError(f"the learned GFCS sampler encodes the joint goal; {pose[0]} has a pose goal (give it an IK joint goal)")


def learned_samples(learner: Learner, robot, context: jax.Array, key: jax.Array, population: int, n_commands: int, cfg: SelfSupConfig):
    """Warm-start candidates from SGLD on the energy model and, for `cfg.warm.replay`, the buffer,
    in the solver's unconstrained space."""
    warm = cfg.warm
    n_replay = round(warm.replay * population) if len(learner.targets) else 0
    n_model = population - n_replay
    parts = []
    if n_model:
        u = sgld(learner.model, context, key, n_model * warm.oversample, warm.sgld or cfg.sgld)
        if warm.oversample > 1:
            energy = learner.model(jnp.broadcast_to(context, (len(u), context.shape[-1])), u)
            u = u[jnp.argsort(energy)[:n_model]]
        parts.append(u)
    if n_replay:
        k_pick, k_noise = jax.random.split(jax.random.fold_in(key, 1))
        buffer = jnp.asarray(learner.targets)
        u = buffer[jax.random.randint(k_pick, (n_replay,), 0, len(buffer))]
        parts.append(jnp.clip(u + warm.replay_noise * jax.random.normal(k_noise, u.shape), 0.0, 1.0))
    u = jnp.concatenate(parts).reshape(population, n_commands, robot.dof)
    return to_unconstrained(robot.lower + u * (robot.upper - robot.lower), robot.lower, robot.upper, eps=1e-3)


def train(learner: Learner, key: jax.Array, cfg: SelfSupConfig) -> None:
    """`train_steps` Adam steps on InfoNCE over minibatches of the buffer."""
    n = len(learner.targets)
    for s in range(cfg.train_steps):
        k_idx, k_neg = jax.random.split(jax.random.fold_in(key, s))
        idx = np.asarray(jax.random.choice(k_idx, n, (min(cfg.batch, n),), replace=False))
        loss = train_step(
            learner.model, learner.opt, jnp.asarray(learner.contexts[idx]), jnp.asarray(learner.targets[idx]), k_neg, cfg.n_neg, cfg.sgld
        )
        learner.losses.append(float(loss))
    learner.trained = True


def run(
    fabric,
    params,
    problems: list,
    gfcs_cfg: GFCSConfig,
    cfg: SelfSupConfig,
    checkpoint: Path,
    encoding: Encoding = Encoding(),
    log: Callable[[str], None] = print,
    stop_after: int | None = None,
) -> Learner:
    """Algorithm 2 over `problems` (joint goals) for `cfg.passes` passes; resumes from `checkpoint`
    when it exists. stop_after: return after this many solves in this call (to test resumption)."""
    robot = fabric.robot
    require_joint_goals(problems)
    gfcops = [ProblemBatch.of(p) for p in problems]
    raw = np.stack([np.asarray(encoding.context(robot, g.start_q, g.start_qd, g.goal_q, g.scene), np.float32) for g in gfcops])
    target_dim = gfcs_cfg.n_commands * robot.dof
    checkpoint = Path(checkpoint)
    context_dim = raw.shape[1] if cfg.latent is None else raw.shape[1] - encoding.n_reference + cfg.latent
    names = [p.name for p in problems]
    settings = {"selfsup": dataclasses.asdict(cfg), "gfcs": dataclasses.asdict(gfcs_cfg), "encoding": dataclasses.asdict(encoding), "problems": names}
    if checkpoint.exists():
        learner = load(checkpoint, context_dim, target_dim, cfg, expect=settings)
    else:
        learner = new_learner(context_dim, target_dim, cfg)
        if cfg.latent is not None:  # fitted once, on the training scenes, before any solve
            learner.ae, ae_losses = fit_autoencoder(raw[:, -encoding.n_reference :], cfg.latent, steps=cfg.ae_steps, seed=cfg.seed)
            log(f"autoencoder {encoding.n_reference} -> {cfg.latent}: reconstruction MSE {ae_losses[0]:.4f} -> {ae_losses[-1]:.4f}")
    contexts = np.asarray(reduce(learner, jnp.asarray(raw)), np.float32)
    if learner.solved:
        log(f"resuming after {learner.solved} solves ({len(learner.targets)} buffered)")
    fns = make_step(fabric, params, gfcs_cfg)
    base = jax.random.PRNGKey(cfg.seed)
    total = cfg.passes * len(problems)
    done_here = 0
    while learner.solved < total and (stop_after is None or done_here < stop_after):
        i = learner.solved
        k = jax.random.fold_in(base, i)
        k_samp, k_solve, k_train = jax.random.split(k, 3)
        x = jnp.asarray(contexts[i % len(problems)])
        samples = learned_samples(learner, robot, x, k_samp, gfcs_cfg.population, gfcs_cfg.n_commands, cfg) if learner.trained else None
        r = solve(fabric, params, gfcops[i % len(problems)], k_solve, gfcs_cfg, samples=samples, steps_fns=fns)
        good = r.top_cost < gfcs_cfg.penalty  # reached, no collision
        u = (np.asarray(to_commands(jnp.asarray(r.top_z[good]), robot.lower, robot.upper)) - np.asarray(robot.lower)) / np.asarray(
            robot.upper - robot.lower
        )
        learner.contexts = np.concatenate([learner.contexts, np.repeat(contexts[i % len(problems)][None], good.sum(), 0)])[-cfg.buffer_size :]
        learner.targets = np.concatenate([learner.targets, u.reshape(len(u), target_dim).astype(np.float32)])[-cfg.buffer_size :]
        learner.costs = np.concatenate([learner.costs, r.top_cost[good].astype(np.float32)])[-cfg.buffer_size :]
        learner.solved += 1
        done_here += 1
        if learner.solved % cfg.retrain_every == 0 and len(learner.targets):
            train(learner, k_train, cfg)
            log(f"retrained on {len(learner.targets)} buffered solutions, loss {np.mean(learner.losses[-10:]):.3f}")
        save(learner, checkpoint, settings)
        log(f"solve {learner.solved}/{total} {problems[i % len(problems)].name}: best cost {r.best_cost:.2f}, {int(good.sum())} kept")
    return learner
