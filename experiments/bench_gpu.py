"""Throughput of every batched part of fabrax on this machine's accelerator, within a wall budget.

One command measures, each with its compile time apart:

- fabric: arm-steps/s of the full Panda fabric (`bench_fabric_step.py`'s scene), 1 arm to 65,536;
- rl_env, mjx_env: RL guide env steps/s (kinematic and MJX backends, `bench_rl_env.py`'s pool);
- ppo: brax PPO env steps/s with the thesis network (conv encoders, MLP 512-256-128) at 4,096 envs;
- gfcs: GFCS (configs/method/gfcs.yaml) on K MotionBenchMaker train problems solved together
  (`fabrax.planners.gfcs.solve_batch`), time per batch and per problem; generated MBM-like problems
  where `FABRAX_DATA` is not set; `--gfcs method.shrink=1` (repeatable) overrides the method;
- geodesics: batches of 256 and 4,096 spline geodesics on a J/C task-space skill (a short VAE fit:
  the timing needs a trained decoder, not a good one).

Each section runs in its own process with a time slice of what is left of `--budget` (its share by
weight), so a compile that hangs costs one section, not the run: a section stopped at its slice keeps
the rows it finished and is reported as timed out. `--sizes gpu` holds the sizes above, `--sizes cpu`
small ones (the CI test runs it), `auto` picks by jax's default backend. Writes results.json and
summary.md to --out.

    python experiments/bench_gpu.py --budget 420 --out bench_out/gpu
    python experiments/bench_gpu.py --sizes cpu --sections fabric,gfcs --budget 120 --out bench_out/gpu_cpu
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

SECTIONS = ("fabric", "rl_env", "mjx_env", "ppo", "gfcs", "geodesics")
WEIGHTS = {"fabric": 3.0, "rl_env": 1.5, "mjx_env": 1.5, "ppo": 3.0, "gfcs": 3.0, "geodesics": 1.0}
SIZES = {
    "gpu": {
        "fabric": [1, 1024, 8192, 65536],
        "rl_env": [4096, 1024, 16384],  # the thesis' 4,096 first: a section stopped at its slice keeps the rows it finished
        "mjx_env": [4096, 1024, 16384],
        "ppo": {"num_envs": 4096, "batch_size": 1024, "num_minibatches": 4, "unroll_length": 16, "network": "conv", "iterations": 3},
        "gfcs": [64, 1, 16],
        "geodesics": [256, 4096],
    },
    "cpu": {
        "fabric": [1, 64],
        "rl_env": [16],
        "mjx_env": [16],
        "ppo": {"num_envs": 16, "batch_size": 16, "num_minibatches": 4, "unroll_length": 4, "network": "mlp", "iterations": 1},
        "gfcs": [1, 2],
        "geodesics": [32],
    },
}
UNITS = {
    "fabric": "arm-steps/s",
    "rl_env": "env steps/s",
    "mjx_env": "env steps/s",
    "ppo": "env steps/s",
    "gfcs": "problems/s",
    "geodesics": "geodesics/s",
}


def _emit(rows_file: Path, row: dict) -> None:
    with open(rows_file, "a") as f:
        f.write(json.dumps(row) + "\n")
    print(json.dumps(row), flush=True)


# ---- sections (each runs in a child process) ----


def section_fabric(sizes, emit) -> None:
    from bench_fabric_step import measure, setup

    _, fabric, p, scene = setup("panda")
    for b in sizes:
        r = measure(fabric, p, scene, b, steps=200, repeats=3)
        emit({"size": b, "rate": r["arm_steps_per_s"], "compile_s": r["compile_s"], "us_per_step": r["us_per_step"]})


def section_env(sizes, emit, backend: str) -> None:
    from bench_rl_env import generated_env, step_rate

    t0 = time.perf_counter()
    env = generated_env(backend)
    setup_s = time.perf_counter() - t0
    for b in sizes:
        r = step_rate(env, b, steps=4, repeats=2)
        emit({"size": b, "rate": r["env_steps_per_s"], "compile_s": r["compile_s"], "ms_per_step": r["ms_per_step"], "setup_s": setup_s})


def section_ppo(spec, emit, run_dir: Path) -> None:
    from fabrax.rl.train import train

    per_iteration = spec["batch_size"] * spec["num_minibatches"] * spec["unroll_length"]
    hidden = [512, 256, 128] if spec["network"] == "conv" else [32, 32]
    from fabrax import config

    settings = {
        "robot": config.load("robot", "panda"),
        "fabric": config.load("fabric", "panda"),
        "env": {"scenes": {"generated": {"cuboid_forest": 8, "shelves": 8, "flying_cuboids": 8}}},
        "eval_scenes": {"seed": 1},
        "network": {"variant": spec["network"], "hidden": hidden},
        "ppo": {
            "num_timesteps": 2 * spec["iterations"] * per_iteration,  # two epochs: the first compiles, the second is timed
            "num_envs": spec["num_envs"],
            "batch_size": spec["batch_size"],
            "num_minibatches": spec["num_minibatches"],
            "unroll_length": spec["unroll_length"],
            "num_evals": 3,
            "num_eval_envs": min(spec["num_envs"], 128),
        },
    }
    t0 = time.perf_counter()
    train(settings, run_dir)
    wall = time.perf_counter() - t0
    evals = [json.loads(line) for line in (run_dir / "progress.jsonl").read_text().splitlines() if '"eval"' in line]
    walls = [e["wall_s"] for e in evals]
    first, second = walls[1] - walls[0], walls[2] - walls[1]  # each epoch: training, then one evaluation
    emit(
        {
            "size": spec["num_envs"],
            "rate": evals[-1]["eval"]["sps"],  # brax's training/sps of the second epoch
            "compile_s": max(first - second, 0.0),  # the first epoch less the second: compilation
            "network": spec["network"],
            "env_steps_per_epoch": spec["iterations"] * per_iteration,
            "epoch_wall_s": [first, second],
            "wall_s": wall,
        }
    )


def section_gfcs(sizes, emit, overrides: list[str] = ()) -> None:
    import jax
    import numpy as np

    from fabrax import config
    from fabrax.bench import cli
    from fabrax.planners.gfcs import solve_batch
    from fabrax.planners.gfcs.solver import make_step
    from fabrax.problems import ProblemBatch
    from fabrax.scene import common_capacity

    kind = "mbm" if os.environ.get("FABRAX_DATA") else "mbm_like"
    cfg = cli.compose(["method=gfcs", f"problems={kind}", "split=train", f"limit={max(1, -(-max(sizes) // 6))}", "progress=false", *overrides])
    robot = config.load_robot(config.robot_choice(cfg))
    t0 = time.perf_counter()
    problems = [p for p in cli.load_problems(cfg, robot) if p.valid and p.goal_q is not None]
    method = cli.make_method(cfg, robot)
    setup_s = time.perf_counter() - t0
    gfcops = [ProblemBatch.of(p) for p in problems]
    cap = common_capacity([q.scene for q in gfcops])
    gfcops = [q.replace(scene=q.scene.pad(**cap)) for q in gfcops]
    gcfg = method.config
    for k in sizes:
        chosen = [gfcops[i % len(gfcops)] for i in range(k)]
        keys = jax.random.split(jax.random.PRNGKey(0), k)
        fns = make_step(method.fabric, method.params, gcfg, problems=True)
        results = solve_batch(method.fabric, method.params, ProblemBatch.stack(chosen), keys, gcfg, steps_fns=fns)
        walls = [b["wall_s"] for b in results[0].per_batch]
        clean = sum(r.best_cost < gcfg.penalty for r in results)
        emit(
            {
                "size": k,
                "rate": k / sum(walls),
                "compile_s": results[0].compile_s,
                "problems": kind,
                "batch_s": float(np.mean(walls)),
                "per_problem_ms": 1e3 * sum(walls) / k,
                "batches": len(walls),
                "population": gcfg.population,
                "shrink": gcfg.shrink,
                "arrived_clean": f"{clean}/{k}",
                "setup_s": setup_s,
            }
        )


def section_geodesics(sizes, emit) -> None:
    import jax
    import jax.numpy as jnp
    import numpy as np
    from flax import nnx

    from fabrax.skills import demos, geodesic, metric, vae
    from fabrax.skills.rbf import kmeans

    t0 = time.perf_counter()
    x, q = demos.jc(points=100, seed=0)
    model, _ = vae.fit_task(x.reshape(-1, 3), q.reshape(-1, 4), vae.VAEConfig(steps=300, rbf_steps=50))
    codes = np.asarray(model.encode(jnp.asarray(x, jnp.float32), jnp.asarray(q, jnp.float32))[0]).reshape(-1, 2)
    nodes = kmeans(codes, 96, 0)[0]
    graphdef, state = nnx.split(model)
    curve_metric, margs = metric.curve_metric(graphdef), (state, metric.NONE)
    solve = geodesic.solver(curve_metric, geodesic.GeodesicConfig(check=0), nodes)
    setup_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    for b in sizes:
        a, z = (jnp.asarray(codes[rng.integers(len(codes), size=b)]) for _ in range(2))
        t = time.perf_counter()
        jax.block_until_ready(solve(margs, a, z))
        first = time.perf_counter() - t
        times = []
        for _ in range(3):
            t = time.perf_counter()
            g = jax.block_until_ready(solve(margs, a, z))
            times.append(time.perf_counter() - t)
        best = float(np.median(times))
        row = {"size": b, "rate": b / best, "compile_s": max(first - best, 0.0), "batch_s": best, "steps_max": int(jnp.max(g.iters))}
        emit({**row, "setup_s": setup_s})


def child(section: str, sizes_name: str, rows_file: Path, work: Path, gfcs: list[str] = ()) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import fabrax  # noqa: F401  (XLA flags before jax)

    sizes = SIZES[sizes_name][section]
    emit = lambda row: _emit(rows_file, {"section": section, "unit": UNITS[section], **row})  # noqa: E731
    if section == "fabric":
        section_fabric(sizes, emit)
    elif section in ("rl_env", "mjx_env"):
        section_env(sizes, emit, "kinematic" if section == "rl_env" else "mjx")
    elif section == "ppo":
        section_ppo(sizes, emit, work / "ppo_run")
    elif section == "gfcs":
        section_gfcs(sizes, emit, gfcs)
    elif section == "geodesics":
        section_geodesics(sizes, emit)


# ---- the parent: budget, one process per section, the report ----


def _backend() -> dict:
    """jax's default backend, its first device and versions, asked of a child process: the parent
    never starts a backend (on a GPU it would hold the memory the sections need)."""
    code = (
        "import json, os, fabrax, jax; d = jax.devices()[0]; "
        "print(json.dumps({'backend': jax.default_backend(), 'device': d.device_kind, 'devices': jax.device_count(), "
        "'jax': jax.__version__, 'compile_cache': os.environ.get('JAX_COMPILATION_CACHE_DIR')}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    if out.returncode != 0:
        raise SystemExit(f"bench_gpu: jax did not start: {(out.stderr.strip().splitlines() or ['?'])[-1]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def slices(remaining: float, sections: list[str]) -> float:
    """The first section's share of `remaining` seconds, by weight among `sections`."""
    return remaining * WEIGHTS[sections[0]] / sum(WEIGHTS[s] for s in sections)


def run_sections(sections: list[str], sizes: str, budget: float, out: Path, gfcs: list[str] = ()) -> list[dict]:
    """Run each section in a child process within its slice of the budget; one status row each."""
    statuses = []
    deadline = time.monotonic() + budget
    for i, section in enumerate(sections):
        remaining = deadline - time.monotonic()
        limit = slices(remaining, sections[i:])
        rows_file = out / f"rows_{section}.jsonl"
        rows_file.unlink(missing_ok=True)
        work = out / "work"
        work.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, str(Path(__file__).resolve()), "--child", section, "--sizes", sizes, "--rows", str(rows_file), "--work", str(work)]
        cmd += [f"--gfcs={o}" for o in gfcs]
        t0 = time.monotonic()
        status = "ok"
        if limit < 1.0:
            status = "skipped: budget spent"
        else:
            with open(out / f"log_{section}.txt", "w") as log:
                proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
                try:
                    rc = proc.wait(timeout=limit)
                    if rc != 0:
                        tail = (out / f"log_{section}.txt").read_text().strip().splitlines()[-1:] or [""]
                        status = f"failed (exit {rc}): {tail[0][:200]}"
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, 9)
                    proc.wait()
                    status = f"timed out after {limit:.0f} s"
        rows = [json.loads(line) for line in rows_file.read_text().splitlines()] if rows_file.exists() else []
        statuses.append({"section": section, "status": status, "slice_s": limit, "wall_s": time.monotonic() - t0, "rows": rows})
        print(f"{section}: {status}, {len(rows)} rows in {statuses[-1]['wall_s']:.0f} s", flush=True)
    return statuses


def summary(statuses: list[dict], meta: dict) -> str:
    lines = [
        f"fabrax throughput on {meta['device']} (jax {meta['jax']}), budget {meta['budget_s']:.0f} s, sizes `{meta['sizes']}`",
        "",
        "| section | size | rate | unit | compile s | details |",
        "|---|---:|---:|---|---:|---|",
    ]
    skip = {"section", "size", "rate", "unit", "compile_s"}
    for s in statuses:
        for r in s["rows"]:
            details = ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items() if k not in skip)
            rate = f"{r['rate']:,.0f}" if r["rate"] >= 100 else f"{r['rate']:.3g}"
            lines.append(f"| {r['section']} | {r['size']:,} | {rate} | {r['unit']} | {r['compile_s']:.1f} | {details} |")
        if s["status"] != "ok":
            lines.append(f"| {s['section']} | | | | | **{s['status']}** |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("bench_out/gpu"))
    ap.add_argument("--budget", type=float, default=420.0, help="wall seconds for all sections together")
    ap.add_argument("--sizes", default="auto", choices=["auto", "gpu", "cpu"])
    ap.add_argument("--sections", default=",".join(SECTIONS), help=f"comma-separated, from {', '.join(SECTIONS)}")
    ap.add_argument("--gfcs", action="append", default=[], help="an override of the gfcs section's method (repeatable), e.g. --gfcs method.shrink=1")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--rows", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--work", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.sizes, args.rows, args.work, args.gfcs)
        return
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = [s for s in sections if s not in SECTIONS]
    if unknown or not sections:
        raise SystemExit(f"bench_gpu: unknown sections {unknown} (known: {', '.join(SECTIONS)})")
    if args.budget <= 0:
        raise SystemExit(f"bench_gpu: --budget must be positive seconds, got {args.budget}")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SystemExit(f"bench_gpu: cannot write --out {args.out}: {e.strerror}") from None
    t0 = time.monotonic()
    info = _backend()
    sizes = args.sizes if args.sizes != "auto" else ("cpu" if info["backend"] == "cpu" else "gpu")
    cache = Path(info["compile_cache"]) if info["compile_cache"] else None
    cached = sum(1 for _ in cache.iterdir()) if cache and cache.is_dir() else 0
    statuses = run_sections(sections, sizes, args.budget - (time.monotonic() - t0), args.out, args.gfcs)
    meta = {
        **info,
        "device": info["device"] if info["backend"] != "cpu" else f"CPU ({os.cpu_count()} cores, {info['devices']} devices)",
        "budget_s": args.budget,
        "wall_s": time.monotonic() - t0,
        "sizes": sizes,
        "gfcs_overrides": args.gfcs,
        "machine": platform.platform(),
        "compile_cache_entries_at_start": cached,  # 0: every compile_s is a cold compile
    }
    (args.out / "results.json").write_text(json.dumps({"meta": meta, "sections": statuses}, indent=1))
    md = summary(statuses, meta)
    (args.out / "summary.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
