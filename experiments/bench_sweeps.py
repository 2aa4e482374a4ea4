"""Full-speed sweeps toward walls, thin boards and box edges (`fabrax.problems.sweeps`): how many
penetrate, for the committed fabric and with each of its two safety choices undone (the thesis'
eq. 3.9 limiter instead of the metric box solve; eq. 2.26 energization instead of max(alpha, 0)).

Two sets: the test's (`share` 0.5 of the start's braking deceleration, obstacle 0.05-0.5 m ahead)
and a harder one (`share` 1, 0-0.3 m ahead, where some sweeps are only just stoppable). Every motion
is judged by the exact checker. Writes results.json and results.md to --out.

    python experiments/bench_sweeps.py --n 150 --out bench_out/sweeps
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

import fabrax  # noqa: F401
from fabrax import config
from fabrax.bench import check_path
from fabrax.problems import batch
from fabrax.problems.sweeps import sweeps
from fabrax.rollout import reach

VARIANTS = {
    "fabrax (metric box solve, dissipative)": ("dissipative", True),
    "eq. 2.26 energization": ("conservative", True),
    "eq. 3.9 limiter": ("dissipative", "shrink"),
    "eq. 3.9 limiter and eq. 2.26 energization": ("conservative", "shrink"),
}
SETS = {
    "test set (share 0.5, 0.05-0.5 m)": dict(share=0.5, distance=(0.05, 0.5)),
    "hard set (share 1, 0-0.3 m)": dict(share=1.0, distance=(0.0, 0.3)),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=150)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--robot", default="panda_mbm")
    ap.add_argument("--fabric", default="panda")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--out", default="bench_out/sweeps")
    args = ap.parse_args()
    robot = config.load_robot(args.robot)
    default_q = config.load("robot", "panda")["default_q"]
    rows = []
    for set_name, kw in SETS.items():
        t0 = time.perf_counter()
        problems = sweeps(robot, args.n, args.seed, default_q=default_q, **kw)
        speeds = [float(np.max(np.abs(p.start_qd) / np.asarray(robot.velocity))) for p in problems]
        fastest = f"{min(speeds):.2f}-{max(speeds):.2f}"
        print(f"{set_name}: {len(problems)} sweeps in {time.perf_counter() - t0:.0f} s (fastest joint at {fastest} of its limit)")
        for name, (energization, limits) in VARIANTS.items():
            fab, params = config.load_fabric(robot, {**config.load("fabric", args.fabric), "energization": energization})
            steps = int(round(args.seconds / 0.01))
            tr = jax.jit(lambda b: reach(fab, params, b, "joint", dt=0.01, steps=steps, stop_at_goal=False, limits=limits))(batch(problems))
            q = np.asarray(tr.q)
            checks = [check_path(robot, p.scene, q[k]) for k, p in enumerate(problems)]
            for kind in ("sweep_wall", "sweep_board", "sweep_edge", "all"):
                sel = [c for c, p in zip(checks, problems) if kind == "all" or p.kind == kind]
                pen = [-c.min_clearance for c in sel if c.scene_collision]
                rows.append(
                    {
                        "set": set_name,
                        "variant": name,
                        "kind": kind.removeprefix("sweep_"),
                        "n": len(sel),
                        "penetrating": len(pen),
                        "max_depth_mm": 1000 * max(pen) if pen else 0.0,
                        "self_collisions": sum(c.self_collision for c in sel),
                        "closest_mm": 1000 * min(c.min_clearance for c in sel),
                    }
                )
            print(f"  {name}: {rows[-1]['penetrating']} of {rows[-1]['n']} penetrate (max {rows[-1]['max_depth_mm']:.1f} mm)", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"args": vars(args), "jax": jax.__version__}
    (out / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    lines = ["| set | variant | wall | board | edge | all | deepest (mm) | self-collisions |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for set_name in SETS:
        for name in VARIANTS:
            sel = {r["kind"]: r for r in rows if r["set"] == set_name and r["variant"] == name}
            cells = " | ".join(f"{sel[k]['penetrating']}/{sel[k]['n']}" for k in ("wall", "board", "edge", "all"))
            lines.append(f"| {set_name} | {name} | {cells} | {sel['all']['max_depth_mm']:.1f} | {sel['all']['self_collisions']} |")
    (out / "results.md").write_text("\n".join(lines) + "\n\nPenetrating sweeps (scene collisions under the exact checker) / sweeps.\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
