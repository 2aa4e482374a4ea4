"""The straight start-to-goal line of the hand per MotionBenchMaker class: the floor under every EE length.

    python experiments/mbm_straight_line.py --out docs/results/mbm_straight_line

For each class of the chosen split, the distance between the start's and the joint goal's position
of each frame (`--frames`, default the links from the wrist to the hand), mean ± std over the
class's valid problems. No motion between start and goal is shorter, so a method's mean EE length
(gfcs_paper §VI's metric, measured on the robot's `ee_frame`) can only match a figure below this
floor on other problems or at another point of the arm. The paper's pure-fabric (GF) EE lengths
are written beside it. Writes OUT.json and OUT.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax.bench.collect import write_report
from fabrax.config import load_robot
from fabrax.problems.mbm import TABLE_I_CLASSES, load_mbm
from fabrax.robot.kinematics import frame_path

# gfcs_paper Table I: the pure fabric's (GF) EE length (m), None where it solved nothing; GFCS's
# figures are beside ours in docs/results.md's Table I
PAPER_GF = {"table_under_pick": None, "box": 0.92, "bookshelf_tall": 0.70, "cage": 0.66, "bookshelf_thin": 0.68, "bookshelf_small": 0.69}


def straight_lines(robot, problems, frames) -> dict[str, np.ndarray]:
    """Per frame, the (P,) start-to-goal distances of its origin."""
    start = jnp.asarray(np.stack([p.start_q for p in problems]), jnp.float32)
    goal = jnp.asarray(np.stack([p.goal_q for p in problems]), jnp.float32)
    return {f: np.linalg.norm(np.asarray(frame_path(robot, start, f)[0]) - np.asarray(frame_path(robot, goal, f)[0]), axis=-1) for f in frames}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("bench_out/mbm_straight_line"))
    ap.add_argument("--split", default="test", choices=("train", "test", "all"))
    ap.add_argument("--robot", default="panda_mbm")
    ap.add_argument("--frames", nargs="+", default=None, help="frames of the robot (default: panda_link5 .. the ee_frame)")
    ap.add_argument("--classes", nargs="+", default=list(TABLE_I_CLASSES), choices=TABLE_I_CLASSES)
    ap.add_argument("--limit", type=int, default=None, help="problems per class")
    args = ap.parse_args(argv)
    robot = load_robot(args.robot)
    frames = args.frames or ["panda_link5", "panda_link7", robot.ee_frame]
    unknown = [f for f in frames if f not in robot.frame_names]
    if unknown:
        raise SystemExit(f"mbm_straight_line: --frames: {', '.join(unknown)} not a frame of {args.robot}")
    rows = {}
    for c in args.classes:
        problems = [p for p in load_mbm(robot, classes=[c], split=args.split, limit=args.limit) if p.valid and p.goal_q is not None]
        lines = straight_lines(robot, problems, frames)
        rows[c] = {"n": len(problems), **{f: {"mean": float(d.mean()), "std": float(d.std())} for f, d in lines.items()}}
        rows[c]["paper_gf"] = PAPER_GF[c]
    result = {"split": args.split, "robot": args.robot, "ee_frame": robot.ee_frame, "frames": frames, "classes": rows}
    lines = [
        "| straight line (m) | n | " + " | ".join(frames) + " | paper GF EE length |",
        "|---|---:|" + "---:|" * len(frames) + "---:|",
    ]
    for c, r in rows.items():
        paper = "–" if r["paper_gf"] is None else f"{r['paper_gf']:.2f}"
        lines.append(f"| {c} | {r['n']} | " + " | ".join(f"{r[f]['mean']:.2f} ± {r[f]['std']:.2f}" for f in frames) + f" | {paper} |")
    write_report(args.out, result, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
