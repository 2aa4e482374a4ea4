"""Where the RL guide's reaction time goes (fabrics_guided_rl_thesis §4.1: the time to produce an
action for the arm given a new obstacle scene), on this host.

Each piece is compiled alone and timed over `--calls` calls, each on the next of a set of generated
MPiNets-like scenes (train seeds: no data needed), padded to the bench's common capacity:

- `static BPS`: the new scene's basis point set (eq. 3.16, 16^3 points);
- `observation`: the rest of Table 3.2's observation (keypoints, dynamic basis points, the map);
- `policy`: the guide's network and its deterministic action;
- `targets + fabric step`: the fabric goal the action commands and one fabric step toward it;
- `reaction`: all of them in one compiled call, as `fabrax bench method=rl_guide` reports it in
  every row (`RLGuideMethod.reaction_ms`);
- `pure fabric`: the env's fabric alone (`method.scripted=switch`), its reaction.

    python experiments/bench_reaction.py --out bench_out/reaction [--checkpoint pretrained] [--calls 200]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax.bench.collect import write_report
from fabrax.bench.methods.rl_guide import build
from fabrax.config import load, load_robot
from fabrax.problems import procedural
from fabrax.rollout.rollout import integrate


def timed(fn, args: list, calls: int) -> dict:
    """Mean, std and median (ms) of `calls` calls of jitted `fn`, each on the next of `args`, after compiling."""
    fn = jax.jit(fn)
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args[0]))
    compile_s = time.perf_counter() - t0
    times = []
    for k in range(calls):
        a = jax.block_until_ready(args[(k + 1) % len(args)])
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*a))
        times.append(time.perf_counter() - t0)
    ms = np.asarray(times) * 1e3
    return {"mean_ms": float(ms.mean()), "std_ms": float(ms.std()), "median_ms": float(np.median(ms)), "compile_s": round(compile_s, 2)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench_out/reaction")
    ap.add_argument("--checkpoint", default="pretrained", help="a guide: run directory, checkpoint directory or `pretrained`")
    ap.add_argument("--calls", type=int, default=200)
    ap.add_argument("--scenes", type=int, default=8, help="generated scenes per MPiNets-like class")
    args = ap.parse_args(argv)
    if args.calls < 1 or args.scenes < 1:
        raise SystemExit("bench_reaction: --calls and --scenes must be positive")

    robot = load_robot("panda")
    cfg = {"fabric": load("fabric", "panda"), "frame": "panda_hand"}
    guide = build({"name": "rl_guide", "checkpoint": args.checkpoint, "scripted": None, "batch_size": 1}, cfg, robot)
    fabric = build({"name": "fabric_switch", "checkpoint": None, "scripted": "switch", "batch_size": 1}, cfg, robot)
    env = guide.env
    problems = procedural.generate(robot, "mpinets_like", None, args.scenes, 0, frame=env.fabric.goal_frame)
    stacked = guide.arguments(robot, problems)
    each = [jax.tree.map(lambda a: a[k], stacked) for k in range(len(problems))]  # (scene, start, goal pos, quat, keypoints)
    two = jnp.asarray(2)

    def fabric_step(ep, action):
        params, _ = env.targets(ep, action, two)
        return integrate(env.fabric, params, ep.scene, ep.fabric_q, ep.fabric_qd, env.cfg.fabric_dt, env.cfg.integrator)[0]

    # each piece timed (and its compile measured) before its outputs feed the next piece's inputs
    rows = {"static BPS": timed(env.static_bps, [(a[0],) for a in each], args.calls)}
    bps = [jax.jit(env.static_bps)(a[0]) for a in each]
    states = [jax.jit(guide._begin)(*a) for a in each]
    rows["observation"] = timed(env.observe, [(s.pipeline_state, b) for s, b in zip(states, bps)], args.calls)
    rows["policy"] = timed(guide.act, [(s.obs,) for s in states], args.calls)
    actions = [jax.jit(guide.act)(s.obs) for s in states]
    rows["targets + fabric step"] = timed(fabric_step, [(s.pipeline_state, a) for s, a in zip(states, actions)], args.calls)
    for name, method in (("reaction", guide), ("pure fabric", fabric)):
        mean, std = method.reaction_ms(stacked, args.calls)
        rows[name] = {"mean_ms": mean, "std_ms": std}
    result = {
        "checkpoint": str(args.checkpoint),
        "calls": args.calls,
        "scenes": len(problems),
        "host": {"machine": platform.machine(), "processor": platform.processor(), "devices": [str(d) for d in jax.devices()]},
        "versions": {"jax": jax.__version__},
        "rows": rows,
    }
    lines = ["| piece | mean ± std (ms) | median (ms) | compile (s) |", "|---|---:|---:|---:|"]
    for name, r in rows.items():
        median = f"{r['median_ms']:.3f}" if "median_ms" in r else "–"
        compile_s = f"{r['compile_s']:.1f}" if "compile_s" in r else "–"
        lines.append(f"| {name} | {r['mean_ms']:.3f} ± {r['std_ms']:.3f} | {median} | {compile_s} |")
    write_report(Path(args.out), result, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
