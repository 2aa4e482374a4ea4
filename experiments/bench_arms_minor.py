"""The batched fabric step with self-collision run arms-minor and per arm, compiled side by side.

The self-collision term's batching rule (the term's static `arms_minor` option) puts the arms on the
minor axis under `jax.vmap`. This bench compiles the step of `bench_fabric_step.py` (the full Panda
fabric on its 20-cuboid bookshelf, 200 steps in a `lax.scan`) twice, with the rule on and off, and
calls the two alternately, so that the VM's drift hits both alike; it reports the median of the
per-call CPU-time ratios and checks that both give the same trajectories (to float rounding).
Pin it to one core for stable CPU times. Writes JSON and a markdown table.

    taskset -c 1 python experiments/bench_arms_minor.py --out bench_out/arms_minor
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from bench_fabric_step import bookshelf_scene

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax import config
from fabrax import scene as sc
from fabrax.rollout import integrate


def with_layout(robot, arms_minor: bool):
    """The robot's fabric with the self-collision term's batched layout set (`arms_minor`)."""
    cfg = config.load("fabric", "panda")
    terms = {k: ({**t, "arms_minor": arms_minor} if t.get("type") == "self_collision" else t) for k, t in cfg["terms"].items()}
    return config.load_fabric(robot, {**cfg, "terms": terms})


def compiled_step(fabric, params, scene, q0, qd0, steps: int):
    """The scanned step over a batch of arms, compiled."""

    def run(q, qd):
        def body(c, _):
            qn, qdn, _, _ = integrate(fabric, params, scene, c[0], c[1], 0.01)
            return (qn, qdn), None

        return jax.lax.scan(body, (q, qd), None, length=steps)[0]

    return jax.jit(jax.vmap(run)).lower(q0, qd0).compile()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench_out/arms_minor")
    ap.add_argument("--robots", default="panda,panda_mbm")
    ap.add_argument("--batches", default="64,256")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--pairs", type=int, default=10, help="alternating calls of each variant")
    args = ap.parse_args()

    scene = sc.from_dict(bookshelf_scene())
    ready = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
    rows = []
    for name in args.robots.split(","):
        robot = config.load_robot(name)
        fabrics = {v: with_layout(robot, v) for v in (False, True)}
        goal = jnp.asarray([0.0, 0.5, 0.0, -1.6, 0.0, 3.1, 0.785])
        for b in [int(x) for x in args.batches.split(",")]:
            q0 = jnp.asarray(ready + np.random.default_rng(b).normal(scale=0.05, size=(b, 7)), jnp.float32)
            qd0 = jnp.zeros_like(q0)
            fns = {v: compiled_step(f, f.with_joint_goal(p, goal), scene, q0, qd0, args.steps) for v, (f, p) in fabrics.items()}
            outs = {v: jax.block_until_ready(f(q0, qd0)) for v, f in fns.items()}
            cpu = {False: [], True: []}
            for k in range(args.pairs):
                for v in (False, True) if k % 2 == 0 else (True, False):
                    c0 = time.process_time()
                    jax.block_until_ready(fns[v](q0, qd0))
                    cpu[v].append((time.process_time() - c0) / args.steps / b * 1e6)
            off, on = np.asarray(cpu[False]), np.asarray(cpu[True])
            rows.append(
                {
                    "robot": name,
                    "arms": b,
                    "cpu_us_per_arm_step_per_arm": float(np.median(off)),
                    "cpu_us_per_arm_step_arms_minor": float(np.median(on)),
                    "ratio_median_of_pairs": float(np.median(on / off)),
                    "max_abs_q_difference": float(jnp.abs(outs[True][0] - outs[False][0]).max()),
                }
            )
            print(json.dumps(rows[-1]))

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"steps_per_call": args.steps, "pairs": args.pairs, "scene": "bench_fabric_step bookshelf, 20 cuboids", "backend": jax.default_backend()}
    (out / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    lines = [
        "| robot | arms | CPU us per arm-step, per arm | arms minor | ratio (median of pairs) | max abs q difference |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['robot']} | {r['arms']} | {r['cpu_us_per_arm_step_per_arm']:.2f} | {r['cpu_us_per_arm_step_arms_minor']:.2f} | "
            f"{r['ratio_median_of_pairs']:.3f} | {r['max_abs_q_difference']:.1e} |"
        )
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
