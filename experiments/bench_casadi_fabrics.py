"""fabrax's fabric step next to the CasADi `fabrics` package (tud-amr, PyPI `fabrics`) on the same Panda
URDF and the same sphere obstacles, in one run.

`fabrics` 0.10 pins numpy 1.x and pytest 6, so it lives in its own environment:

    python -m venv .venv-fabrics && .venv-fabrics/bin/pip install fabrics==0.10.0
    python experiments/bench_casadi_fabrics.py --fabrics-python .venv-fabrics/bin/python --out bench_out/casadi

Per obstacle count, the CasADi planner (its `ParameterizedFabricPlanner` with its defaults: the hand
attracted to a position, a sphere around each of the links it accepts, joint limits; one
`compute_action` per call, as its users call it) and fabrax's full Panda fabric (60 fitted spheres
against the same spheres, 1134 self-collision sphere pairs, joint limits, the attractors, damping and
the acceleration/jerk limiter, one integration step) at random states near the ready posture.
fabrax is timed as one jitted call per step from Python (what a controller loop pays) and per step
inside a scanned rollout. Writes JSON and a markdown table.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax import config
from fabrax import scene as sc
from fabrax.robot import panda_urdf
from fabrax.rollout import integrate

READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
GOAL = [0.5, 0.2, 0.5]  # hand position (m)
RADIUS = 0.1  # obstacle radius (m)

# run by the interpreter that has `fabrics`; JSON settings on stdin; prints one JSON line
CASADI = textwrap.dedent(
    """
    import json, logging, sys, time
    import numpy as np
    logging.disable(logging.WARNING)
    from forwardkinematics.urdfFks.generic_urdf_fk import GenericURDFFk
    from fabrics.planner.parameterized_planner import ParameterizedFabricPlanner
    from mpscenes.goals.goal_composition import GoalComposition

    s = json.loads(sys.stdin.read())
    fk = GenericURDFFk(open(s["urdf"]).read(), root_link="panda_link0", end_links=["panda_hand"])
    planner = ParameterizedFabricPlanner(7, fk)
    goal = GoalComposition(name="goal", content_dict={"subgoal0": {
        "weight": 1.0, "is_primary_goal": True, "indices": [0, 1, 2], "parent_link": "panda_link0",
        "child_link": "panda_hand", "desired_position": s["goal"], "epsilon": 0.05, "type": "staticSubGoal"}})
    t0 = time.perf_counter()
    planner.set_components(collision_links=s["links"], goal=goal, number_obstacles=len(s["obstacles"]), limits=s["limits"])
    planner.concretize()
    build_s = time.perf_counter() - t0
    kw = dict(weight_goal_0=1.0, x_goal_0=np.asarray(s["goal"]))
    for k, c in enumerate(s["obstacles"]):
        kw[f"x_obst_{k}"], kw[f"radius_obst_{k}"] = np.asarray(c), s["radius"]
    used = [l for l in s["links"] if f"radius_body_{l}" in planner._funs.function().name_in()]
    for l in used:
        kw[f"radius_body_{l}"] = s["body_radius"]
    times = []
    for q, qd in zip(s["q"], s["qd"]):
        t = time.perf_counter()
        planner.compute_action(q=np.asarray(q), qdot=np.asarray(qd), **kw)
        times.append(time.perf_counter() - t)
    print(json.dumps({"build_s": build_s, "median_us": 1e6 * float(np.median(times)), "collision_links": used}))
    """
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fabrics-python", default=sys.executable, help="an interpreter that can import `fabrics`")
    ap.add_argument("--obstacles", default="1,3")
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--out", default="bench_out/casadi")
    args = ap.parse_args()

    robot = config.load_robot()
    fabric, params = config.load_fabric(robot)
    p = fabric.with_pose_goal(params, jnp.asarray(GOAL), jnp.asarray([0.0, 1.0, 0.0, 0.0]))
    p = {**p, "ee": {**p["ee"], "point_weights": jnp.asarray([1.0, 0.0, 0.0])}}  # position only, as the CasADi goal
    rng = np.random.default_rng(0)
    qs = np.asarray(READY) + rng.normal(scale=0.1, size=(args.calls, 7))
    qds = rng.normal(scale=0.1, size=(args.calls, 7))
    limits = np.stack([np.asarray(robot.lower), np.asarray(robot.upper)], 1).tolist()
    rows = []
    for n in [int(k) for k in args.obstacles.split(",")]:
        centres = [[0.5, -0.3 + 0.3 * k, 0.4] for k in range(n)]
        scene = sc.from_dict({"obstacles": [{"type": "sphere", "center": c, "radius": RADIUS} for c in centres]})
        step = jax.jit(lambda q, qd, scene=scene: integrate(fabric, p, scene, q, qd, 0.01)[:2])
        q0, qd0 = jnp.asarray(qs[0], jnp.float32), jnp.asarray(qds[0], jnp.float32)
        jax.block_until_ready(step(q0, qd0))
        times = []
        for q, qd in zip(jnp.asarray(qs, jnp.float32), jnp.asarray(qds, jnp.float32)):
            t = time.perf_counter()
            jax.block_until_ready(step(q, qd))
            times.append(time.perf_counter() - t)

        def rollout(q, qd, scene=scene):
            return jax.lax.scan(lambda c, _: (integrate(fabric, p, scene, c[0], c[1], 0.01)[:2], None), (q, qd), None, length=500)[0]

        scan = jax.jit(rollout)
        jax.block_until_ready(scan(q0, qd0))
        best = min(_timed(scan, q0, qd0) for _ in range(5))

        settings = dict(
            urdf=str(panda_urdf()),
            goal=GOAL,
            obstacles=centres,
            radius=RADIUS,
            body_radius=0.08,
            links=["panda_link1", "panda_link2", "panda_link3", "panda_link4", "panda_link5", "panda_link6", "panda_link7", "panda_hand"],
            limits=limits,
            q=qs.tolist(),
            qd=qds.tolist(),
        )
        out = subprocess.run([args.fabrics_python, "-c", CASADI], input=json.dumps(settings), capture_output=True, text=True)
        if out.returncode != 0:
            sys.exit(f"the CasADi side failed with {args.fabrics_python} (is `fabrics` installed there?): {out.stderr.strip().splitlines()[-1]}")
        cas = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(
            {
                "obstacles": n,
                "casadi_us": cas["median_us"],
                "casadi_build_s": cas["build_s"],
                "casadi_collision_links": cas["collision_links"],
                "fabrax_call_us": 1e6 * float(np.median(times)),
                "fabrax_scan_us": 1e6 * best / 500,
            }
        )
        print(json.dumps(rows[-1]))

    meta = {"calls": args.calls, "fabrax_spheres": robot.n_spheres, "fabrax_self_pairs": int(robot.collision.pair_i.shape[0]), "jax": jax.__version__}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    lines = [
        f"Panda, sphere obstacles r = {RADIUS} m, {args.calls} random states, median per call",
        "",
        "| obstacles | CasADi `fabrics` us per action (collision links) | fabrax us per jitted step call | fabrax us per step in a scan |",
        "|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r['obstacles']} | {r['casadi_us']:.0f} ({len(r['casadi_collision_links'])} spheres) | {r['fabrax_call_us']:.0f} "
        f"({meta['fabrax_spheres']} spheres, {meta['fabrax_self_pairs']} self pairs) | {r['fabrax_scan_us']:.1f} |"
        for r in rows
    ]
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def _timed(fn, *args) -> float:
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - t


if __name__ == "__main__":
    main()
