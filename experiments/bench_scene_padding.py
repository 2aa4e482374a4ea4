"""What a scene's padding costs GFCS: one population rollout (`population_cost`, 64 uniform candidates,
the settings of configs/method/gfcs.yaml) on MBM train problem 1 of every class, its scene padded to
`COMMON_CAPACITY` (56 slots: one compiled solver for all) against its own capacity rounded to 8
slots per kind (`ProblemBatch.of`'s default: one compilation per size of scene).

Both are compiled side by side in one process and called alternately (`--pairs` pairs, CPU time):
this VM's speed drifts by 20-50 % within minutes, so only ratios of interleaved calls resolve
changes of 10 %. Pin it to one core for steadier numbers. Needs FABRAX_DATA. Writes JSON and a
markdown table.

    taskset -c 1 python experiments/bench_scene_padding.py --out bench_out/scene_padding
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import jax
import numpy as np

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax import config
from fabrax.planners.gfcs import GFCSConfig
from fabrax.planners.gfcs.cost import population_cost
from fabrax.planners.gfcs.solver import uniform_sampler
from fabrax.problems import ProblemBatch
from fabrax.problems.mbm import CLASSES, load_mbm
from fabrax.scene import COMMON_CAPACITY


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench_out/scene_padding")
    ap.add_argument("--data", default=os.environ.get("FABRAX_DATA"), help="the shared data folder (default: FABRAX_DATA)")
    ap.add_argument("--classes", default=",".join(CLASSES))
    ap.add_argument("--pairs", type=int, default=8, help="alternated calls of each padding per class")
    args = ap.parse_args()
    if not args.data:
        raise SystemExit("bench_scene_padding: set FABRAX_DATA or pass --data (the MotionBenchMaker problems)")

    robot = config.load_robot("panda_mbm")
    fabric, params = config.load_fabric(robot)
    cfg = GFCSConfig(n_commands=1, population=64, via_tolerance=0.5, final_pose=True, length_weight=1.0, patience=1.0, stop_after=0.5)
    z = uniform_sampler(jax.random.PRNGKey(0), robot, cfg.population, cfg.n_commands)
    opts = dict(dt=cfg.dt, steps=cfg.steps, enough=cfg.enough, patience=cfg.patience, via_tolerance=cfg.via_tolerance, final_pose=cfg.final_pose)
    cost = jax.jit(lambda prob, z: population_cost(fabric, params, prob, z, length_weight=cfg.length_weight, **opts)[0])
    compiled: dict = {}  # shape -> executable

    def get(prob):
        key = tuple(prob.scene.capacity.values())
        t0 = time.perf_counter()
        if key not in compiled:
            compiled[key] = cost.lower(prob, z).compile()
        return compiled[key], time.perf_counter() - t0

    rows = []
    for cls in args.classes.split(","):
        problem = next(p for p in load_mbm(robot, args.data, [cls], "train", 5) if p.valid)
        probs = {"common": ProblemBatch.of(problem, COMMON_CAPACITY), "rounded": ProblemBatch.of(problem)}
        fns = {k: get(g) for k, g in probs.items()}
        costs = {k: np.asarray(fns[k][0](probs[k], z)) for k in probs}
        cpu = {k: [] for k in probs}
        for rep in range(args.pairs):
            for k in ("common", "rounded") if rep % 2 == 0 else ("rounded", "common"):
                c0 = time.process_time()
                jax.block_until_ready(fns[k][0](probs[k], z))
                cpu[k].append(time.process_time() - c0)
        ratio = float(np.median(np.asarray(cpu["rounded"]) / np.asarray(cpu["common"])))
        rows.append(
            {
                "problem": problem.name,
                "primitives": {k: v for k, v in problem.scene.capacity.items() if v},
                "rounded_capacity": probs["rounded"].scene.capacity,
                "cpu_s_common": float(np.median(cpu["common"])),
                "cpu_s_rounded": float(np.median(cpu["rounded"])),
                "rounded_over_common": ratio,
                "max_cost_difference_s": float(np.abs(costs["common"] - costs["rounded"]).max()),
                "compile_s": {k: fns[k][1] for k in probs},
            }
        )
        print(json.dumps(rows[-1]), flush=True)

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"population": cfg.population, "pairs": args.pairs, "cores_used": len(os.sched_getaffinity(0)), "jax": jax.__version__}
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    lines = [
        "| problem | primitives | rounded capacity | CPU s, common 56 slots | CPU s, rounded | rounded / common | max cost difference s |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        prims = ", ".join(f"{v} {k}" for k, v in r["primitives"].items())
        cap = "/".join(str(r["rounded_capacity"][k]) for k in ("cuboids", "cylinders", "spheres"))
        lines.append(
            f"| {r['problem']} | {prims} | {cap} | {r['cpu_s_common']:.3f} | {r['cpu_s_rounded']:.3f} | "
            f"{r['rounded_over_common']:.3f} | {r['max_cost_difference_s']:.3f} |"
        )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
