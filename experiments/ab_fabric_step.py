"""Interleaved A/B of the fabric step: this checkout's fabrax against an older commit, in one process.

The older commit's `fabrax/` and `configs/` are extracted with `git archive` into a temporary folder
and imported as the package `fabrax_old`. Both steps are compiled for the same arms, scene, start
and goal (the fabric-step bench's), then called alternately, old-new, new-old, ...; each call's CPU
time is taken, and the figure is the median of the new/old ratios of the pairs. On a shared VM whose
speed drifts by 20-50 % within an hour this resolves changes of a few percent, where separate runs
do not (docs/results.md). Pin it to one core for steady figures:

    taskset -c 1 python experiments/ab_fabric_step.py --against ff0cb19 --robot panda_mbm --batches 1,64,256 --out bench_out/ab_s33_mbm
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def extract(commit: str, into: Path) -> None:
    """`fabrax/` and `configs/` of `commit`, the package renamed to `fabrax_old`."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", commit, "fabrax", "configs"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    (into / "fabrax").rename(into / "fabrax_old")
    for f in (into / "fabrax_old").rglob("*.py"):
        text = re.sub(r"\bfabrax\.", "fabrax_old.", f.read_text())
        text = re.sub(r"from fabrax import", "from fabrax_old import", text)
        f.write_text(re.sub(r"^import fabrax$", "import fabrax_old", text, flags=re.M))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", required=True, help="the older commit")
    ap.add_argument("--robot", default="panda")
    ap.add_argument("--batches", default="1,64,256", help="arms per call; 1 runs one arm unbatched")
    ap.add_argument("--pairs", type=int, default=12, help="old/new call pairs per batch size (fewer for large batches)")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--out", type=Path, required=True, help="writes OUT/results.json and OUT/summary.md")
    args = ap.parse_args()
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", args.against], check=True, capture_output=True, text=True).stdout.strip()
    tmp = Path(tempfile.mkdtemp(prefix="fabrax_ab_"))
    extract(commit, tmp)
    sys.path.insert(0, str(tmp))
    sys.path.insert(0, str(ROOT / "experiments"))
    import fabrax_old.rollout
    import fabrax_old.scene
    import jax
    import jax.numpy as jnp
    from bench_fabric_step import GOAL, READY, bookshelf_scene
    from fabrax_old import config as config_old

    import fabrax.rollout
    import fabrax.scene
    from fabrax import config as config_new

    rows = []
    for batch in [int(b) for b in args.batches.split(",")]:
        q0 = jnp.asarray(np.asarray(READY) + np.random.default_rng(batch).normal(scale=0.05, size=(batch, 7)), jnp.float32)
        q0 = q0[0] if batch == 1 else q0
        qd0 = jnp.zeros_like(q0)
        fns, finals = {}, {}
        for name, pkg, cfg in (("old", fabrax_old, config_old), ("new", fabrax, config_new)):
            fabric, params = cfg.load_fabric(cfg.load_robot(args.robot))
            scene = pkg.scene.from_dict(bookshelf_scene())
            p = fabric.with_joint_goal(params, jnp.asarray(GOAL))

            def run(q, qd, fabric=fabric, p=p, scene=scene, integrate=pkg.rollout.integrate):
                def body(c, _):
                    return integrate(fabric, p, scene, c[0], c[1], 0.01)[:2], None

                return jax.lax.scan(body, (q, qd), None, length=args.steps)[0]

            fns[name] = jax.jit(run if batch == 1 else jax.vmap(run)).lower(q0, qd0).compile()
            finals[name] = jax.block_until_ready(fns[name](q0, qd0))[0]
        cpu = {"old": [], "new": []}
        for k in range(args.pairs):
            for name in ("old", "new") if k % 2 == 0 else ("new", "old"):
                start = time.process_time()
                jax.block_until_ready(fns[name](q0, qd0))
                cpu[name].append((time.process_time() - start) / args.steps / batch * 1e6)
        old, new = np.asarray(cpu["old"]), np.asarray(cpu["new"])
        row = {
            "arms": batch,
            "old_cpu_us_per_arm_step": float(np.median(old)),
            "new_cpu_us_per_arm_step": float(np.median(new)),
            "new_over_old": float(np.median(new / old)),
            "max_abs_q_difference": float(jnp.max(jnp.abs(finals["new"] - finals["old"]))),
        }
        print(json.dumps(row), flush=True)
        rows.append(row)
    meta = {"against": commit, "robot": args.robot, "steps": args.steps, "pairs": args.pairs, "jax": jax.__version__}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    lines = [
        f"{args.robot}: this checkout against {commit}, {args.pairs} interleaved pairs of {args.steps}-step calls",
        "",
        "| arms | old CPU us per arm-step | new | new / old (median of pairs) | max abs q difference |",
        "|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        times = f"{r['old_cpu_us_per_arm_step']:.2f} | {r['new_cpu_us_per_arm_step']:.2f}"
        lines.append(f"| {r['arms']} | {times} | {r['new_over_old']:.3f} | {r['max_abs_q_difference']:.2g} |")
    (args.out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
