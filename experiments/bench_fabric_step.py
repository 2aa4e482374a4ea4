"""Fabric step throughput: arm-steps per second for batches of arms, and single-arm latency.

The full Panda fabric (all collision spheres, self-collision pairs, joint
limits, both attractors, damping, the acceleration/jerk limiter and the
second-order integrator) steps inside a `lax.scan`, vmapped over arms, on a
bookshelf-like scene of ~20 cuboids. The arms split over the local devices
(`fabrax.sharding`; on a CPU, FABRAX_CPU_DEVICES=<cores> gives one device per core);
--chunk runs a device's share as consecutive sub-batches (`fabrax.sharding.batched`),
which keeps each kernel's working set in cache. Writes JSON and a markdown table.

    python experiments/bench_fabric_step.py --out bench_out/fabric_step
    FABRAX_CPU_DEVICES=2 python experiments/bench_fabric_step.py --out bench_out/fabric_step_2dev
    taskset -c 0 python experiments/bench_fabric_step.py --batches 1 --out bench_out/fabric_step_1core

On one core XLA runs the step's kernels on one thread: a single arm steps faster there than with
two cores, where its small kernels are handed between threads (docs/results.md).

Besides wall time the bench reports the process's CPU time per arm-step (best of the repeats). On
one core (`taskset -c 0`) that is the figure to compare between versions on a shared VM: time
the hypervisor gives to other guests (steal) counts in wall time but not in CPU time. It also
records XLA's count of floating-point operations per arm-step, and the rate the step reaches.
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
import numpy as np

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax import config, sharding
from fabrax import scene as sc
from fabrax.problems.generators import shelf
from fabrax.rollout import integrate

READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]  # the arms start near this posture
GOAL = [0.0, 0.5, 0.0, -1.6, 0.0, 3.1, 0.785]  # and are attracted to this joint goal


def bookshelf_scene() -> dict:
    """Two shelves side by side plus clutter: 20 cuboids."""
    left = shelf(center=(0.7, -0.45, 0.0), width=0.6, depth=0.35, heights=(0.2, 0.5, 0.8))
    right = shelf(center=(0.7, 0.45, 0.0), width=0.6, depth=0.35, heights=(0.3, 0.65))
    obs = left["obstacles"] + right["obstacles"]
    rng = np.random.default_rng(0)
    while len(obs) < 20:
        obs.append({"type": "cuboid", "center": [float(rng.uniform(0.55, 0.8)), float(rng.uniform(-0.6, 0.6)), 0.55], "size": [0.06, 0.06, 0.1]})
    return {"obstacles": obs[:20]}


def setup(robot_name: str = "panda"):
    """(robot, fabric, params aimed at GOAL, scene) of the bench."""
    robot = config.load_robot(robot_name)
    fabric, params = config.load_fabric(robot)
    return robot, fabric, fabric.with_joint_goal(params, jnp.asarray(GOAL)), sc.from_dict(bookshelf_scene())


def measure(fabric, p, scene, b: int, steps: int = 200, repeats: int = 3, chunk: int = 0, dt: float = 0.01) -> dict:
    """One row: `b` arms near READY stepped `steps` times in a scan (vmapped, split over the local
    devices, a device's share in sub-batches of `chunk` arms), best of `repeats` after compiling."""

    def run(q0, qd0):
        def body(c, _):
            q, qd, _, _ = integrate(fabric, p, scene, c[0], c[1], dt)
            return (q, qd), None

        return jax.lax.scan(body, (q0, qd0), None, length=steps)[0]

    rng = np.random.default_rng(b)
    q0 = jnp.asarray(np.asarray(READY) + rng.normal(scale=0.05, size=(b, 7)), jnp.float32)
    qd0 = jnp.zeros((b, 7), jnp.float32)
    share = b // jax.local_device_count() if b % jax.local_device_count() == 0 else b
    chunk = chunk if 0 < chunk < share and share % chunk == 0 else share
    fn = jax.jit(sharding.batched(jax.vmap(run), chunk))
    t0 = time.perf_counter()
    compiled = fn.lower(q0, qd0).compile()
    compile_s = time.perf_counter() - t0
    cost = compiled.cost_analysis()
    # one device's program, whose loops' bodies count once: one step of one sub-batch
    flops = (cost[0] if isinstance(cost, list) else cost).get("flops", float("nan")) / chunk
    jax.block_until_ready(compiled(q0, qd0))
    best, best_cpu = np.inf, np.inf
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(compiled(q0, qd0))
        best, best_cpu = min(best, time.perf_counter() - t0), min(best_cpu, time.process_time() - c0)
    return {
        "batch": b,
        "devices": jax.local_device_count(),
        "chunk": chunk,
        "arm_steps_per_s": b * steps / best,
        "us_per_step": best / steps * 1e6,
        "us_per_arm_step": best / steps / b * 1e6,
        "cpu_us_per_arm_step": best_cpu / steps / b * 1e6,
        "flops_per_arm_step": flops,  # XLA's count (one round of the limiter's loop)
        "gflops_per_s": flops * b * steps / best / 1e9,
        "compile_s": compile_s,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench_out/fabric_step")
    ap.add_argument("--batches", default="1,64,256,1024")
    ap.add_argument("--steps", type=int, default=200, help="scanned steps per timed call")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--robot", default="panda", help="robot config (panda_mbm: the MotionBenchMaker sphere set GFCS plans with)")
    ap.add_argument("--chunk", type=int, default=0, help="arms per sub-batch on each device (0: the whole batch at once)")
    args = ap.parse_args()

    robot, fabric, p, scene = setup(args.robot)
    dt = 0.01
    rows = []
    for b in [int(x) for x in args.batches.split(",")]:
        rows.append(measure(fabric, p, scene, b, args.steps, args.repeats, args.chunk, dt))
        print(json.dumps(rows[-1]))

    meta = {
        "spheres": robot.n_spheres,
        "self_pairs": int(robot.collision.pair_i.shape[0]),
        "primitives": scene.n_primitives,
        "steps_per_call": args.steps,
        "dt": dt,
        "machine": {
            "cpus": os.cpu_count(),
            "cores_used": len(os.sched_getaffinity(0)),  # fewer under taskset
            "processor": platform.processor() or platform.machine(),
            "jax": jax.__version__,
            "devices": str(jax.devices()),
        },
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    lines = [
        f"Panda fabric step: {meta['spheres']} spheres x {meta['primitives']} cuboids, "
        f"{meta['self_pairs']} self pairs, {meta['machine']['cores_used']} of {meta['machine']['cpus']} CPUs",
        "",
        "| arms | devices | arms per sub-batch | arm-steps/s | us per step | us per arm-step | CPU us per arm-step"
        " | kflop per arm-step | GFLOP/s | compile s |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r['batch']} | {r['devices']} | {r['chunk']} | {r['arm_steps_per_s']:,.0f} | {r['us_per_step']:.1f} | "
        f"{r['us_per_arm_step']:.2f} | {r['cpu_us_per_arm_step']:.2f} | {r['flops_per_arm_step'] / 1e3:.0f} | "
        f"{r['gflops_per_s']:.1f} | {r['compile_s']:.1f} |"
        for r in rows
    ]
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
