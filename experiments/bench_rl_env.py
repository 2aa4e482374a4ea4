"""RL guide environment throughput: env steps per second for batches of envs, compile time, and
where a step's time goes (fabric substeps, the exact checker on every substep, observations).

Each timed call is a `lax.scan` over `--steps` policy steps of the vmapped env with random
actions (no auto-reset), after a warm-up call. The scene pool is generated (cuboid forests,
surrounding shelves, flying cuboids), so it needs no data. Writes JSON and a markdown table.

    python experiments/bench_rl_env.py --out bench_out/rl_env
    python experiments/bench_rl_env.py --backend mjx --batches 64,256 --out bench_out/rl_env_mjx
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax import config
from fabrax.check.clearance import state_clearances
from fabrax.rl import make_env
from fabrax.rl.scripted import episode


def timed(fn, *args, repeats: int):
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - t
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return compile_s, best


def generated_env(backend: str = "kinematic", substeps: int = 30, scenes: int = 8):
    """The bench's env: a pool of `scenes` generated scenes of each kind (no data needed)."""
    pool = {"cuboid_forest": scenes, "shelves": scenes, "flying_cuboids": scenes}
    return make_env(
        {"backend": backend, "substeps": substeps, "scenes": {"generated": pool}}, config.load("robot", "panda"), config.load("fabric", "panda")
    )


def step_rate(env, b: int, steps: int = 4, repeats: int = 2) -> dict:
    """Env steps per second of `b` envs (a scan of `steps` vmapped steps with random actions, best of
    `repeats` after a warm-up call) and the compile time (the warm-up less one timed call)."""
    keys = jax.random.split(jax.random.PRNGKey(0), b)
    t = time.perf_counter()
    state = jax.block_until_ready(jax.jit(jax.vmap(env.reset))(keys))
    reset_s = time.perf_counter() - t

    @jax.jit
    def rollout(state, key):
        def body(s, k):
            a = jax.random.uniform(k, (b, env.action_size), minval=-1.0, maxval=1.0)
            s = jax.vmap(env.step)(s, a)
            return s, s.reward

        return jax.lax.scan(body, state, jax.random.split(key, steps))[1]

    compile_s, step_s = timed(rollout, state, jax.random.PRNGKey(1), repeats=repeats)
    per_step = step_s / steps
    return {"envs": b, "env_steps_per_s": b / per_step, "ms_per_step": 1e3 * per_step, "compile_s": compile_s - step_s, "reset_s": reset_s}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench_out/rl_env")
    ap.add_argument("--batches", default="64,256,1024")
    ap.add_argument("--steps", type=int, default=4, help="policy steps per timed call")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--scenes", type=int, default=8, help="generated scenes of each kind in the pool")
    ap.add_argument("--substeps", type=int, default=30)
    ap.add_argument("--backend", default="kinematic", help="kinematic | mjx")
    ap.add_argument("--episodes", type=int, default=128, help="episodes of each scripted policy for the baseline rows (0: skip)")
    args = ap.parse_args()

    env = generated_env(args.backend, args.substeps, args.scenes)
    cfg = env.cfg
    rows = []
    for b in [int(x) for x in args.batches.split(",")]:
        row = step_rate(env, b, args.steps, args.repeats)
        state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), b))
        ep = state.pipeline_state
        a0 = jnp.zeros((b, env.action_size))
        params, _ = jax.vmap(env.targets, in_axes=(0, 0, None))(ep, a0, jnp.ones((), jnp.int32))

        substeps = jax.jit(jax.vmap(lambda p, e: env.substeps(e, p)[1]))  # the fabric and the arm following it
        qs = substeps(params, ep)
        checker = jax.jit(jax.vmap(lambda s, q: state_clearances(env.robot, s, q)))
        observe = jax.jit(jax.vmap(env.observe))
        _, fabric_s = timed(substeps, params, ep, repeats=args.repeats)
        _, check_s = timed(checker, ep.scene, qs, repeats=args.repeats)
        _, obs_s = timed(observe, ep, state.obs["bps"], repeats=args.repeats)
        rows.append({**row, "fabric_ms": 1e3 * fabric_s, "checker_ms": 1e3 * check_s, "observe_ms": 1e3 * obs_s})
        print(json.dumps(rows[-1]), flush=True)

    baselines = []
    for policy in ("switch", "random") if args.episodes else ():
        run = jax.jit(jax.vmap(lambda k: episode(env, policy, k)[1]))
        _, _, _, metrics, alive = run(jax.random.split(jax.random.PRNGKey(2), args.episodes))
        last = jnp.maximum(jnp.sum(alive, axis=1) - 1, 0)
        final = {k: jnp.take_along_axis(v, last[:, None], 1)[:, 0] for k, v in metrics.items()}
        baselines.append(
            {
                "policy": policy,
                "episodes": args.episodes,
                "success_pct": 100 * float(final["success"].mean()),
                "collision_pct": 100 * float(final["collision"].mean()),
                "within_0.08_pct": 100 * float((final["keypoint_distance"] < cfg.success_distance).mean()),
                "final_keypoint_distance": float(jnp.median(final["keypoint_distance"])),
                "unique_cells": float(final["unique_cells"].mean()),
            }
        )
        if "tracking_error" in final:  # mjx: MJX's contacts and how closely the arm tracked the fabric
            seen = jnp.where(alive, metrics["mjx_contacts"] > 0, False).any(axis=1)
            baselines[-1].update(
                mjx_contact_pct=100 * float(seen.mean()),
                max_tracking_error=float(jnp.where(alive, metrics["tracking_error"], 0.0).max()),
                median_tracking_error=float(jnp.median(metrics["tracking_error"][alive])),
            )
        print(json.dumps(baselines[-1]), flush=True)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {
        "backend": cfg.backend,
        "substeps": cfg.substeps,
        "fabric_dt": cfg.fabric_dt,
        "pool": env.pool.size,
        "capacity": env.pool.scene.capacity,
        "spheres": env.robot.n_spheres,
        "cpus": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "jax": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
    }
    (out / "rl_env.json").write_text(json.dumps({"meta": meta, "rows": rows, "baselines": baselines}, indent=2))
    lines = [
        f"backend {cfg.backend}, {cfg.substeps} fabric substeps per policy step, pool of {env.pool.size} generated scenes "
        f"(capacity {env.pool.scene.capacity}), {meta['cpus']} CPUs",
        "",
        "| envs | env steps/s | ms per step | compile s | substeps (fabric + arm) ms | checker ms | observations ms |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['envs']} | {r['env_steps_per_s']:,.0f} | {r['ms_per_step']:.1f} | {r['compile_s']:.1f} | "
            f"{r['fabric_ms']:.1f} | {r['checker_ms']:.1f} | {r['observe_ms']:.1f} |"
        )
    if baselines:
        lines += [
            "",
            f"Scripted policies, {args.episodes} episodes each from resets of the pool (20 s; switch: stage 2, the switch on at the first step;",
            "random: uniform actions, stage 1, so no success is counted):",
            "",
            "| policy | success % | collision % | final keypoint distance < 0.08 % | median final keypoint distance (m) | unique cells |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for r in baselines:
            lines.append(
                f"| {r['policy']} | {r['success_pct']:.1f} | {r['collision_pct']:.1f} | {r['within_0.08_pct']:.1f} | "
                f"{r['final_keypoint_distance']:.3f} | {r['unique_cells']:.1f} |"
            )
        if "max_tracking_error" in baselines[0]:
            lines += ["", "| policy | episodes with MJX contacts % | median / max tracking error (rad) |", "|---|---:|---:|"]
            lines += [
                f"| {r['policy']} | {r['mjx_contact_pct']:.1f} | {r['median_tracking_error']:.4f} / {r['max_tracking_error']:.4f} |"
                for r in baselines
            ]
    (out / "rl_env.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
