"""Validity-check speed for sampling planners: the exact checker through JAX against its numba copy
(`fabrax.check.native`), per single state (an OMPL state callback), per motion of ~30
states (an OMPL edge at 1/32 rad) and per large batch, on generated MPiNets-like and MBM-like scenes
(train seeds: no data needed); then states checked per second inside OMPL's RRTConnect loop when
OMPL is installed. Writes JSON and a markdown table.

    python experiments/bench_checker.py --out bench_out/checker
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax.check.clearance import state_clearances
from fabrax.check.native import NativeChecker
from fabrax.config import load_robot
from fabrax.problems import procedural
from fabrax.scene import COMMON_CAPACITY
from fabrax.scene.sdf import primitive_mask


def best_of(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench_out/checker")
    ap.add_argument("--states", type=int, default=200, help="single-state calls per timing")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ompl", type=int, default=5, help="problems per class planned with OMPL RRTConnect (0: skip)")
    args = ap.parse_args()

    robot = load_robot("panda")
    rng = np.random.default_rng(0)
    rows = []
    scenes = [("mpinets_like", c) for c in ("cubby", "tabletop")] + [("mbm_like", c) for c in ("cage", "bookshelf")]
    for family, cls in scenes:
        problem = procedural.generate(robot, family, [cls], 1, 10_000)[0]
        scene = problem.scene
        padded = scene.pad(**COMMON_CAPACITY)
        native = NativeChecker(robot, scene)
        qs = rng.uniform(np.asarray(robot.lower), np.asarray(robot.upper), (4096, robot.dof))
        edge = problem.start_q + np.linspace(0.0, 0.3, 32)[:, None]  # every joint 0.3 rad from the start
        jax_check = lambda q: np.asarray(state_clearances(robot, padded, jnp.asarray(q, jnp.float32))[0])  # noqa: E731
        for q in (qs[:1], edge, qs):
            jax_check(q)
            native.clearances(q)
            native.all_valid(q)
        n = args.states
        single_jax = best_of(lambda: [jax_check(qs[k : k + 1]) for k in range(n)], args.repeats) / n
        single_native = best_of(lambda: [native.all_valid(qs[k]) for k in range(n)], args.repeats) / n
        edge_jax = best_of(lambda: jax_check(edge), args.repeats)
        edge_native = best_of(lambda: native.clearances(edge), args.repeats)
        batch_jax = best_of(lambda: jax_check(qs), args.repeats)
        batch_native = best_of(lambda: native.clearances(qs), args.repeats)
        rows.append(
            {
                "scene": f"{family}/{cls}",
                "primitives": int(np.asarray(primitive_mask(scene)).sum()),
                "single_us": {"jax": single_jax * 1e6, "native": single_native * 1e6},
                "edge32_us": {"jax": edge_jax * 1e6, "native": edge_native * 1e6},
                "batch4096_states_per_s": {"jax": len(qs) / batch_jax, "native": len(qs) / batch_native},
            }
        )
        print(rows[-1], flush=True)

    ompl_rows = []
    if args.ompl:
        from fabrax.bench import ompl

        if "RRTConnect" in ompl.available():
            from fabrax.problems.load import with_ik_goal

            for cls in ("cubby", "dresser", "tabletop"):
                for p in procedural.generate(robot, "mpinets_like", [cls], args.ompl, 10_000):
                    p = with_ik_goal(robot, p, "panda_hand")
                    if not p.valid:
                        continue
                    path, info = ompl.plan(robot, p, "RRTConnect", 1.2, True, 1.0 / 32.0)
                    spent = info["solve_s"] + info["simplify_s"]
                    ompl_rows.append({"problem": p.name, "solved": path is not None, "s": spent, "states": info["states_checked"]})
            print(f"OMPL: {sum(r['states'] for r in ompl_rows) / sum(r['s'] for r in ompl_rows):.0f} states/s", flush=True)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    summary = {"machine": platform.processor() or platform.machine(), "rows": rows, "ompl_rrtconnect": ompl_rows}
    if ompl_rows:
        summary["ompl_states_per_s"] = sum(r["states"] for r in ompl_rows) / sum(r["s"] for r in ompl_rows)
    (out / "checker.json").write_text(json.dumps(summary, indent=1))
    lines = [
        "| scene | primitives | single state µs (JAX / native, early exit) | 32-state edge, all clearances µs (JAX / native) "
        "| 4096 states: states/s (JAX / native) |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        s, e, b = r["single_us"], r["edge32_us"], r["batch4096_states_per_s"]
        lines.append(
            f"| {r['scene']} | {r['primitives']} | {s['jax']:.0f} / {s['native']:.1f} | {e['jax']:.0f} / {e['native']:.0f} "
            f"| {b['jax']:.0f} / {b['native']:.0f} |"
        )
    if ompl_rows:
        solved = sum(r["solved"] for r in ompl_rows)
        lines.append(
            f"\nOMPL RRTConnect (1.2 s, simplified) on {len(ompl_rows)} MPiNets-like train problems: {summary['ompl_states_per_s']:.0f} "
            f"states checked per second of planning, {solved} solved."
        )
    (out / "checker.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    import os
    import sys

    main()
    if "ompl" in sys.modules:
        os._exit(0)  # OMPL 1.7.0's Python module crashes while the interpreter shuts down
