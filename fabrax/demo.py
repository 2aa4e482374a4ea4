"""`fabrax demo`: the Panda fabric reaches into a shelf; needs no data files.

Prints whether it reached the goal, whether the exact checker found a
collision, the time to goal and the wall time; writes the trajectory to an
.npz file. Exits 0 only if the goal was reached without collision.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fabrax demo", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="write the trajectory to this .npz file (default: not written)")
    parser.add_argument("--robot", default="panda", help="robot config in configs/robot")
    parser.add_argument("--fabric", default="panda", help="fabric config in configs/fabric")
    parser.add_argument("--dt", type=float, default=0.01)
    parser.add_argument("--t-max", type=float, default=7.0)
    args = parser.parse_args(argv)

    import jax

    from fabrax import config
    from fabrax.check.checker import check_path
    from fabrax.problems import batch
    from fabrax.problems.generators import demo_problem
    from fabrax.rollout import reach

    print(
        f"[demo] building {args.robot} and its fabric, then compiling the rollout (about 10 s on a laptop CPU; cached for the next run)...",
        file=sys.stderr,
        flush=True,
    )
    t0 = time.perf_counter()
    robot = config.load_robot(args.robot)
    fabric, params = config.load_fabric(robot, args.fabric)
    problem = demo_problem(robot)
    run = jax.jit(lambda b: reach(fabric, params, b, dt=args.dt, steps=int(round(args.t_max / args.dt))))
    b = batch([problem])
    tr = jax.block_until_ready(run(b))  # compile and run once
    t1 = time.perf_counter()
    tr = jax.block_until_ready(run(b))
    wall = time.perf_counter() - t1
    n = int(tr.length[0])
    q = np.asarray(tr.q[0, :n])
    check = check_path(robot, problem.scene, q)
    reached = bool(tr.reached[0])
    ok = reached and not check.collision and check.limits_ok
    report = {
        "problem": problem.name,
        "reached": reached,
        "collision": check.collision,
        "limits_ok": check.limits_ok,
        "time_to_goal_s": round(float(tr.t_goal[0]), 3),
        "min_clearance_m": round(check.min_clearance, 4),
        "steps": n,
        "plan_wall_time_s": round(wall, 4),
        "setup_and_compile_s": round(t1 - t0, 2),
    }
    out = None if args.out is None else Path(args.out)
    if out is not None:
        np.savez(
            out,
            q=q,
            qd=np.asarray(tr.qd[0, :n]),
            qdd=np.asarray(tr.qdd[0, :n]),
            dt=args.dt,
            joint_names=np.asarray(robot.joint_names),
            goal_q=problem.goal_q,
            report=json.dumps(report),
        )
    for k, v in report.items():
        print(f"{k:>22}: {v}")
    print(f"{'trajectory':>22}: {out if out is not None else 'not written (--out FILE.npz keeps it)'}")
    print("OK" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
