"""The guide's action distribution across a run's checkpoints: how wide its Gaussian is on the
states it visits, and the KL between successive checkpoints (what PPO's `kl_mean` measures
between successive updates, brax's KL of the pre-tanh Gaussians).

States come from rolling out the first given checkpoint's stochastic policy on the run's training
scenes (curriculum stage 2): `--envs` episodes for `--steps-per-env` policy steps. For each
checkpoint: the scale's minimum and 1 % quantile over those states, per action dimension, the share
of (state, dimension) pairs under 0.01, the largest pre-tanh mean and the share past 3; for each
pair of successive checkpoints: KL(earlier || later) per state, its mean, median, 99 % quantile
and maximum.

    python experiments/rl_spread.py bench_out/rl/thesis_nointr 399360 432640 465920 --out bench_out/spread
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax.bench.collect import write_report


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="an experiments/rl.py run directory")
    ap.add_argument("steps", type=int, nargs="+", help="checkpoints (env steps), the first one collects the states")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--envs", type=int, default=128)
    ap.add_argument("--steps-per-env", dest="horizon", type=int, default=40)
    args = ap.parse_args(argv)

    from fabrax.rl.env import make_env
    from fabrax.rl.networks import ppo_observation
    from fabrax.rl.policy import load_guide
    from fabrax.rl.wrappers import FixedStage

    run = args.run.resolve()
    guides = {}
    for s in args.steps:
        path = run / "checkpoints" / f"{s:012d}"
        if not path.is_dir():
            raise SystemExit(f"rl_spread: no checkpoint {path}")
        guides[s] = load_guide(path)
    first = guides[args.steps[0]]
    settings = first.settings
    env = FixedStage(make_env(settings["env"], settings["robot"], settings["fabric"]), 2)

    dist = first.network.parametric_action_distribution

    def logits(s, obs):
        p = guides[s].params
        return guides[s].network.policy_network.apply(p[0], p[1], ppo_observation(obs))

    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), args.envs))
    step, collect = jax.jit(jax.vmap(env.step)), jax.jit(lambda o: logits(args.steps[0], o))
    key, seen = jax.random.PRNGKey(2), []
    for _ in range(args.horizon):
        key, k = jax.random.split(key)
        seen.append(state.obs)
        state = step(state, dist.postprocess(dist.sample_no_postprocessing(collect(state.obs), k)))
    obs = jax.tree.map(lambda *x: jnp.concatenate(x), *seen)

    dists, rows = {}, []
    for s in args.steps:
        d = dist.create_dist(jax.jit(lambda o, s=s: logits(s, o))(obs))
        scale, loc = np.asarray(d.scale), np.abs(np.asarray(d.loc))
        dists[s] = d
        rows.append(
            {
                "step": s,
                "scale_min": [float(x) for x in scale.min(axis=0)],
                "scale_q01": [float(x) for x in np.quantile(scale, 0.01, axis=0)],
                "scale_median": [float(x) for x in np.median(scale, axis=0)],
                "share_below_0.01": float(np.mean(scale < 0.01)),
                "loc_abs_max": float(loc.max()),
                "share_loc_beyond_3": float(np.mean(loc > 3.0)),  # tanh(3) = 0.995: past it a mean moves no action
            }
        )
    pairs = []
    for a, b in zip(args.steps, args.steps[1:]):
        kl = np.asarray(dists[b].kl_divergence(dists[a]))
        stats = {"mean": kl.mean(), "median": np.median(kl), "q99": np.quantile(kl, 0.99), "max": kl.max()}
        pairs.append({"from": a, "to": b, **{k: float(v) for k, v in stats.items()}})
    result = {"run": str(args.run), "states": int(obs["q"].shape[0]), "std": first.settings["network"]["std"], "checkpoints": rows, "kl": pairs}
    lines = [
        f"States: {result['states']} ({args.envs} episodes x {args.horizon} policy steps of checkpoint {args.steps[0]}); network.std={result['std']}",
        "",
        "| checkpoint | smallest scale (over dims) | smallest 1 % quantile | share under 0.01 | largest mean | share of means past 3 |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r['step']} | {min(r['scale_min']):.4f} | {min(r['scale_q01']):.4f} | {r['share_below_0.01']:.4f} | {r['loc_abs_max']:.2f} "
        f"| {r['share_loc_beyond_3']:.4f} |"
        for r in rows
    ]
    lines += ["", "| KL(earlier ‖ later) | mean | median | 99 % | max |", "|---|---:|---:|---:|---:|"]
    lines += [f"| {p['from']} → {p['to']} | {p['mean']:.3g} | {p['median']:.3g} | {p['q99']:.3g} | {p['max']:.3g} |" for p in pairs]
    write_report(args.out, result, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
