"""Train the RL guide with brax's PPO (thesis §3.4.4-3.4.6): one entry, `train(settings, run_dir)`.

`settings` is a mapping (configs/rl.yaml through experiments/rl.py, or a dict):

    robot, fabric          robot and fabric config mappings (`fabrax.config.load("robot", "panda")`; the
                           experiment script composes them from configs/robot and configs/fabric)
    env                    `EnvConfig` fields of the training scenes (fabrax/rl/config.py)
    eval_scenes            `env.scenes` overrides of the held-out scenes of the learning curves
    network                variant (conv | mlp), hidden (the MLP widths of Table 3.4), std (global:
                           one learned action scale per dimension | state: the network's output),
                           loc_bound (the pre-tanh mean's soft bound; null: none)
    curriculum             cells: mean unique cells per finished episode that start stage 2 (<= 0: no curriculum);
                           max_steps: env steps after which stage 2 starts at the latest (null: none)
    ppo                    `PPOConfig` fields (brax's `ppo.train` arguments)

The run directory gets `settings.json`, a brax checkpoint after every evaluation
(`checkpoints/<env steps>/`, with brax's network config, so `fabrax.rl.policy.load_guide` restores
the policy), `progress.jsonl` (one line per evaluation on the held-out scenes and per training log:
success, collisions, keypoint error, unique cells, reward terms, stage, wall time) and
`curves.png`. `resume=True` continues from the newest checkpoint (networks and observation
normaliser; brax does not checkpoint the optimiser state, so Adam restarts) in the stage it
reached, and refuses a run directory whose settings differ.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import time
from pathlib import Path
from typing import Any, Literal

import jax

from fabrax.rl.config import env_config
from fabrax.rl.env import make_env
from fabrax.rl.memory import check_rollout_fits
from fabrax.rl.networks import make_guide_networks, network_settings, ppo_observation
from fabrax.rl.policy import read_settings
from fabrax.rl.wrappers import FixedStage, wrap_for_training
from fabrax.settings import check_keys, from_mapping

log = logging.getLogger("fabrax.rl")
SECTIONS = ("robot", "fabric", "env", "eval_scenes", "network", "curriculum", "ppo")
CURVES = ("success", "collision", "keypoint_distance", "unique_cells", "r_sparse", "r_intrinsic", "stage_per_step")
PPO_CURVES = ("kl_mean", "entropy_loss")  # PPO's health (brax's training/* figures in the train rows)


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    num_timesteps: int = 200_000
    num_envs: int = 64
    unroll_length: int = 10
    batch_size: int = 64
    num_minibatches: int = 4
    num_updates_per_batch: int = 4
    learning_rate: float = 5e-4  # §3.4.6
    entropy_cost: float = 1e-3
    discounting: float = 0.99
    gae_lambda: float = 0.95
    clipping_epsilon: float = 0.2
    reward_scaling: float = 1.0
    max_grad_norm: float | None = 1.0
    normalize_observations: bool = True
    # FIXED: a fixed rate, the observation normaliser moved after each update. NONE: brax's own
    # fixed rate, which moves the normaliser *before* the update, so the update re-scores the
    # rollout's actions on other inputs while the statistics move (a large early KL). ADAPTIVE_KL:
    # rl-games' schedule (the rate divided by 1.5 while the KL exceeds twice desired_kl, times 1.5
    # below half), normaliser after the update. docs/results.md, "PPO's KL", compares them.
    learning_rate_schedule: Literal["FIXED", "NONE", "ADAPTIVE_KL"] = "FIXED"
    desired_kl: float = 0.008
    num_evals: int = 10
    num_eval_envs: int = 64
    seed: int = 0


def brax_kwargs(p: PPOConfig) -> dict[str, Any]:
    """`brax.training.agents.ppo.train`'s keyword arguments for `p` (all but num_timesteps). FIXED
    is brax's ADAPTIVE_KL with the rate clamped to `learning_rate`: the rate never moves, and brax
    updates the normaliser after the step as it does for its adaptive schedule."""
    kwargs = {k: v for k, v in dataclasses.asdict(p).items() if k != "num_timesteps"}
    if p.learning_rate_schedule == "FIXED":
        kwargs.update(
            learning_rate_schedule="ADAPTIVE_KL", learning_rate_schedule_min_lr=p.learning_rate, learning_rate_schedule_max_lr=p.learning_rate
        )
    return kwargs


def ppo_config(cfg: dict | None) -> PPOConfig:
    """A `PPOConfig` from a mapping (the `ppo` section), its ranges and batch shapes checked."""
    p = from_mapping(PPOConfig, cfg, "ppo")
    for f in dataclasses.fields(PPOConfig):
        v = getattr(p, f.name)
        if isinstance(v, bool) or v is None:
            continue
        if isinstance(v, int) and v < (0 if f.name == "seed" else 1):
            raise ValueError(f"ppo.{f.name} must be a positive integer, got {v!r}")
        if isinstance(v, float) and v < 0:
            raise ValueError(f"ppo.{f.name} must be a non-negative number, got {v!r}")
    if p.batch_size * p.num_minibatches % p.num_envs:
        raise ValueError(
            f"ppo.batch_size x ppo.num_minibatches ({p.batch_size * p.num_minibatches}) must be a multiple of ppo.num_envs ({p.num_envs})"
        )
    if p.num_envs % jax.local_device_count():
        raise ValueError(f"ppo.num_envs ({p.num_envs}) must be divisible by the {jax.local_device_count()} local devices")
    return p


def normalise(settings: dict[str, Any]) -> dict[str, Any]:
    """The settings with every section checked and defaults filled (what `settings.json` records)."""
    s = dict(settings)
    check_keys(s, SECTIONS, "rl settings")
    env = _plain(dataclasses.asdict(env_config(s.get("env"))))  # every field, validated
    env_config(eval_settings(env, s.get("eval_scenes")))
    net = network_settings(s.get("network"))
    cur = {"cells": 0.0, "max_steps": None, **dict(s.get("curriculum") or {})}
    check_keys(cur, ("cells", "max_steps"), "rl curriculum")
    cur["cells"] = float(cur["cells"])
    if cur["max_steps"] is not None:
        cur["max_steps"] = int(cur["max_steps"])
    ppo = dataclasses.asdict(ppo_config(s.get("ppo")))
    for key in ("robot", "fabric"):
        if not isinstance(s.get(key), dict):
            got = "nothing" if s.get(key) is None else repr(s[key])
            raise ValueError(f"rl settings.{key} must be a {key} config mapping, got {got}: read a preset with fabrax.config.load('{key}', NAME)")
    return {
        "robot": dict(s["robot"]),
        "fabric": dict(s["fabric"]),
        "env": env,
        "eval_scenes": dict(s.get("eval_scenes") or {}),
        "network": net,
        "curriculum": cur,
        "ppo": ppo,
    }


def _plain(x):
    """JSON's view of a value (tuples become lists), as settings.json stores it."""
    return json.loads(json.dumps(x))


def eval_settings(env: dict, eval_scenes: dict | None) -> dict:
    """The env settings of the held-out evaluation: `env` with `eval_scenes` overriding its scenes."""
    return {**env, "scenes": {**dict(env.get("scenes") or {}), **dict(eval_scenes or {})}}


def _comparable(settings: dict) -> dict:
    """What a resumed run must share with its checkpoint (the step budget may grow)."""
    s = _plain(normalise(settings))
    s["ppo"].pop("num_timesteps")
    return s


def _differences(a, b, prefix="") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b)) for d in _differences(a.get(k), b.get(k), f"{prefix}{k}.")]
    return [] if a == b else [prefix.rstrip(".")]


def latest_checkpoint(run_dir: Path) -> Path | None:
    ckpts = sorted(p for p in (Path(run_dir) / "checkpoints").glob("[0-9]" * 12) if p.is_dir())
    return ckpts[-1] if ckpts else None


def _progress(run_dir: Path) -> list[dict]:
    path = Path(run_dir) / "progress.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []


def plot_curves(run_dir: Path) -> Path | None:
    """curves.png: the held-out evaluation's and the training episodes' curves against env steps,
    and PPO's KL and entropy loss."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = _progress(run_dir)
    if not rows:
        return None
    fig, axes = plt.subplots(2, 5, figsize=(20, 7))
    for ax, name in zip(axes.flat, CURVES + ("sps",) + PPO_CURVES):
        for kind, style, color in (("eval", "o-", "C0"), ("train", ".-", "C1")):  # train rows carry brax's training/* too
            pts = [(r["step"], r[kind][name]) for r in rows if kind in r and name in r[kind]]
            if pts:
                ax.plot(*zip(*pts), style, label=kind, ms=3, color=color)
        if name == "kl_mean":
            ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    axes.flat[0].legend()
    fig.tight_layout()
    out = Path(run_dir) / "curves.png"
    fig.savefig(out, dpi=80)
    plt.close(fig)
    return out


def _not_brax_metrics(record: logging.LogRecord) -> bool:
    """Root-logger filter: drop brax's per-iteration metric dumps (`brax.training.logger`)."""
    return not record.pathname.replace("\\", "/").endswith("brax/training/logger.py")


def train(settings: dict[str, Any], run_dir: str | Path, resume: bool = False, data_dir=None):
    """Train (or, with `resume`, continue) a guide; returns (make_policy, params, final metrics)."""
    from brax.training.agents.ppo import checkpoint as ppo_checkpoint

    from fabrax.compat import brax_ppo

    ppo = brax_ppo()

    settings = normalise(settings)
    run_dir = Path(run_dir).resolve()  # orbax takes absolute paths only
    run_dir.mkdir(parents=True, exist_ok=True)
    settings_path = run_dir / "settings.json"
    offset, restore, start_stage, wall_before, evaluated = 0, None, 1, 0.0, set()
    if settings_path.exists():
        old = read_settings(settings_path)
        diff = _differences(_comparable(old), _comparable(settings))
        if diff:
            raise ValueError(f"{run_dir}: its checkpoint was trained with other settings ({', '.join(diff)}); use a new run directory")
        if not resume and latest_checkpoint(run_dir) is not None:
            raise ValueError(f"{run_dir} already holds a run; pass resume=True (experiments/rl.py resume=true) or use a new directory")
    if resume:
        restore = latest_checkpoint(run_dir)
        if restore is not None:
            offset = int(restore.name)
            rows = _progress(run_dir)
            trained = [r for r in rows if "train" in r and "stage_per_step" in r["train"]]
            start_stage = 2 if trained and trained[-1]["train"]["stage_per_step"] > 1.5 else 1
            wall_before = max((r["wall_s"] for r in rows), default=0.0)  # wall_s goes on from the stopped run's
            evaluated = {r["step"] for r in rows if "eval" in r}  # brax evaluates again at the resume step
    settings = _plain(settings)
    settings_path.write_text(json.dumps(settings, indent=2))
    p = PPOConfig(**settings["ppo"])
    remaining = p.num_timesteps - offset
    if remaining <= 0:
        raise ValueError(f"{run_dir} has already trained {offset} of ppo.num_timesteps={p.num_timesteps} env steps")

    env = make_env(settings["env"], settings["robot"], settings["fabric"], data_dir)
    check_rollout_fits(p, env.observation_size)  # a clear error now, not an allocation failure in the first compile
    eval_env = FixedStage(make_env(eval_settings(settings["env"], settings["eval_scenes"]), settings["robot"], settings["fabric"], data_dir), 2)
    factory = functools.partial(make_guide_networks, **{**settings["network"], "hidden": tuple(settings["network"]["hidden"])})
    cur = settings["curriculum"]
    per_device = None if cur["max_steps"] is None else cur["max_steps"] / jax.local_device_count()
    wrap = functools.partial(wrap_for_training, cells=cur["cells"], start_stage=start_stage, max_steps=per_device)
    ckpt_dir = run_dir / "checkpoints"
    obs_size = ppo_observation(env.observation_size)
    t0 = time.time()

    def record(step: int, metrics: dict):
        kind = "eval" if any(k.startswith("eval/") for k in metrics) else "train"
        prefix = "eval/episode_" if kind == "eval" else "episode/"
        row = {k[len(prefix) :]: float(v) for k, v in metrics.items() if k.startswith(prefix) and not k.endswith("_std")}
        if kind == "eval":
            row["sps"] = float(metrics.get("training/sps", float("nan")))
        if kind == "eval" and offset + int(step) in evaluated:
            return  # the same parameters, evaluated when the stopped run saved them
        line = {"step": offset + int(step), "wall_s": round(wall_before + time.time() - t0, 1), "devices": jax.local_device_count(), kind: row}
        losses = {k[len("training/") :]: float(v) for k, v in metrics.items() if k.startswith("training/") and k != "training/sps"}
        if losses:  # PPO's own health: kl_mean, the losses, the action distribution's spread
            line["ppo"] = losses
        with open(run_dir / "progress.jsonl", "a") as f:
            f.write(json.dumps(line) + "\n")
        shown = ", ".join(f"{k} {row[k]:.3g}" for k in CURVES if k in row)
        if kind == "eval" and "kl_mean" in losses:
            shown += f", kl_mean {losses['kl_mean']:.3g}"
        if shown:  # a training log before any episode finished has nothing to show
            # one console line per evaluation; the training episodes' rows stay in progress.jsonl
            log.log(logging.INFO if kind == "eval" else logging.DEBUG, "step %d %s: %s", line["step"], kind, shown)
        if kind == "eval":
            plot_curves(run_dir)

    def save(step: int, make_policy, params):
        if step == 0:
            return
        cfg = ppo_checkpoint.network_config(obs_size, env.action_size, p.normalize_observations, factory)
        ppo_checkpoint.save(ckpt_dir, offset + int(step), params, cfg)

    kwargs = brax_kwargs(p)
    # brax logs every metric after each training iteration (about 20 lines, through the root logger
    # from brax/training/logger.py, and absl at INFO); progress.jsonl and the lines above carry them,
    # so while it trains the console keeps brax's warnings only
    absl_log, root = logging.getLogger("absl"), logging.getLogger()
    absl_level = absl_log.level
    absl_log.setLevel(max(absl_level, logging.WARNING))
    root.addFilter(_not_brax_metrics)
    try:
        make_policy, params, metrics = ppo.train(
            env,
            num_timesteps=remaining,
            episode_length=env.cfg.episode_steps,
            wrap_env_fn=wrap,
            network_factory=factory,
            eval_env=eval_env,
            deterministic_eval=True,
            log_training_metrics=True,
            training_metrics_steps=p.batch_size * p.num_minibatches * p.unroll_length,
            progress_fn=record,
            policy_params_fn=save,
            restore_checkpoint_path=None if restore is None else str(restore),
            **kwargs,
        )
    finally:
        absl_log.setLevel(absl_level)
        root.removeFilter(_not_brax_metrics)
    plot_curves(run_dir)
    return make_policy, params, metrics
