"""Tune the Panda fabric's gains on generated problems (never on MotionBenchMaker test problems).

Problems: random valid start/goal pairs (within half of each joint's range
around the ready posture) in free space, among 'flying cuboids'
(thesis §3.4.1.2) and in front of randomly placed shelves, with joint goals
and pose goals. Each candidate gain set is scored by success (goal reached,
no collision under the exact checker) and then mean time to goal; a random
search over the ranges below keeps the best. Writes JSON and a table.

    python experiments/tune_fabric.py --problems 48 --candidates 24 --out bench_out/tune
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

import jax
import numpy as np

import fabrax  # noqa: F401
from fabrax import config
from fabrax.bench import check_path
from fabrax.fabrics import build_arm_fabric
from fabrax.problems import batch
from fabrax.problems.generators import flying_cuboids, random_problems, shelf
from fabrax.rollout import reach

# (term, parameter): (low, high), sampled log-uniformly
SPACE = {
    ("goal", "k_force"): (0.8, 6.0),
    ("goal", "b_goal"): (3.0, 12.0),
    ("goal", "k_geometry"): (0.05, 2.0),
    ("obstacles", "reach"): (0.08, 0.4),
    ("ee", "k_force"): (1.0, 6.0),
    ("ee", "alpha_force"): (3.0, 12.0),
    ("ee", "b_goal"): (3.0, 15.0),
    ("posture", "k_force"): (0.01, 0.3),
    ("damping", "b"): (0.1, 2.0),
    ("obstacles", "k_metric"): (0.02, 2.0),
    ("obstacles", "k_barrier"): (0.05, 0.5),
    ("damping", "k_drag"): (1.0, 10.0),
}


def problem_set(robot, n: int, seed: int):
    rng = np.random.default_rng(seed)
    scenes = []
    for k in range(n):
        kind = k % 3
        if kind == 0:
            scenes.append({"obstacles": []})
        elif kind == 1:
            scenes.append(flying_cuboids(rng))
        else:
            yaw = rng.uniform(-1.2, 1.2)
            c = np.array([np.cos(yaw), np.sin(yaw), 0.0]) * rng.uniform(0.6, 0.85)
            scenes.append(shelf(center=tuple(c), yaw=yaw, heights=tuple(np.sort(rng.uniform(0.15, 1.0, 3)))))
    half = n // 2
    # starts and goals around the ready posture (half of each joint's range), as in MPiNets-style data
    near = dict(around=config.load("robot", "panda")["default_q"], spread=0.5)
    return random_problems(robot, scenes[:half], seed, goal="joint", **near) + random_problems(robot, scenes[half:], seed + 1, goal="pose", **near)


def mbm_train_set(robot, per_class: int):
    """MotionBenchMaker problems 1..per_class of each class (train split; never the test split 51-100)."""
    from fabrax.problems.mbm import CLASSES, load_mbm

    if per_class > 50:
        raise ValueError("the MBM train split has 50 problems per class")
    return [p for p in load_mbm(robot, None, CLASSES, "train", per_class) if p.valid]


def evaluate(robot, cfg, problems, dt=0.01, t_max=7.0):
    fabric = build_arm_fabric(robot, cfg, posture=config.load("robot", "panda")["default_q"])
    tr = jax.jit(lambda b: reach(fabric, fabric.init(), b, dt=dt, steps=int(t_max / dt)))(batch(problems))
    ok, times, hit, joint = [], [], [], []
    for k, p in enumerate(problems):
        n = int(tr.length[k])
        check = check_path(robot, p.scene, np.asarray(tr.q[k, :n]))
        ok.append(bool(tr.reached[k]) and not check.collision)
        hit.append(check.collision)
        joint.append(p.goal_q is not None)
        times.append(float(tr.t_goal[k]))
    ok, times, hit, joint = (np.asarray(a) for a in (ok, times, hit, joint))
    return {
        "success": float(ok.mean()),
        "success_joint": float(ok[joint].mean()),
        "success_pose": float(ok[~joint].mean()),
        "collision": float(hit.mean()),
        "reached": float(np.asarray(tr.reached).mean()),
        "mean_t_goal": float(times[ok].mean()) if ok.any() else t_max,
        "n": len(problems),
    }


def apply(cfg, values):
    cfg = copy.deepcopy(cfg)
    for (term, key), v in values.items():
        cfg["terms"][term][key] = float(v)
    return cfg


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", type=int, default=48)
    ap.add_argument("--candidates", type=int, default=24)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="bench_out/tune")
    ap.add_argument("--set", default="generated", choices=["generated", "mbm-train"], help="mbm-train: --problems per class of the MBM train split")
    args = ap.parse_args()

    robot = config.load_robot("panda_mbm" if args.set == "mbm-train" else "panda")
    base = config.load("fabric", "panda")
    problems = problem_set(robot, args.problems, args.seed) if args.set == "generated" else mbm_train_set(robot, args.problems)
    rng = np.random.default_rng(args.seed + 100)
    rows = []
    current = {k: base["terms"][k[0]][k[1]] for k in SPACE}
    for c in range(args.candidates + 1):
        values = current if c == 0 else {k: float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) for k, (lo, hi) in SPACE.items()}
        t0 = time.perf_counter()
        score = evaluate(robot, apply(base, values), problems)
        rows.append({"candidate": c, "values": {f"{t}.{p}": v for (t, p), v in values.items()}, **score, "wall_s": time.perf_counter() - t0})
        print(json.dumps(rows[-1]))
    rows.sort(key=lambda r: (-r["success"], r["mean_t_goal"]))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps({"problems": args.problems, "seed": args.seed, "rows": rows}, indent=2))
    keys = list(rows[0]["values"])
    lines = ["| rank | success | mean t* (s) | " + " | ".join(keys) + " |", "|" + "---:|" * (3 + len(keys))]
    for i, r in enumerate(rows[:10]):
        lines.append(f"| {i + 1} | {r['success']:.2f} | {r['mean_t_goal']:.2f} | " + " | ".join(f"{r['values'][k]:.3g}" for k in keys) + " |")
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
