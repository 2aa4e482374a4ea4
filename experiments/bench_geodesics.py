"""Geodesic batch speed and quality: solvers and quadrature point counts on one trained skill.

For a task-space J/C skill (`--skill`: a skill.msgpack from experiments/skills.py; without it the
J/C skill is trained with configs/skills.yaml's VAE settings and saved under --out), each solver
configuration `method:points` runs:

- a batch of `--batch` random pairs of demonstration codes (wall time, median of `--repeats`
  after compilation; steps mean / max; energy);
- the skills experiment's 16 start/end pairs: the solved energy, the same curves' energy at
  `--resolve` points (a metric whose walls are narrower than the points' spacing lets a curve slip
  between them), and the decoded curves' distance to the demonstrations.

Writes JSON and a markdown table.

    python experiments/bench_geodesics.py --out bench_out/geodesics
    python experiments/bench_geodesics.py --skill docs/results/skills/jc/skill.msgpack --configs newton:20 adam:20 newton:100
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from omegaconf import OmegaConf

import fabrax  # noqa: F401  (XLA flags before jax)
from fabrax import config
from fabrax.skills import geodesic, metric, spline, vae
from fabrax.skills.experiment import demo_pairs, load_demos, nearest
from fabrax.skills.rbf import kmeans


def parse(spec: str) -> dict:
    method, _, points = spec.partition(":")
    if method not in geodesic.METHODS or not points.isdigit():
        raise SystemExit(f"bench_geodesics: --configs entry '{spec}' is not method:points with method in {geodesic.METHODS}")
    return {"method": method, "points": int(points)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skill", type=Path, help="a task-space J/C skill.msgpack (default: train one)")
    ap.add_argument("--configs", nargs="+", default=["adam:20", "newton:20", "newton:100", "newton:200"])
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--resolve", type=int, default=400, help="points for the resolved energy")
    ap.add_argument("--out", type=Path, default=Path("bench_out/geodesics"))
    args = ap.parse_args()
    specs = [parse(s) for s in args.configs]
    args.out.mkdir(parents=True, exist_ok=True)

    skills = OmegaConf.to_container(OmegaConf.load(config.config_dir() / "skills.yaml"))
    d = load_demos({"demo": "jc", "points": skills["points"], "seed": skills["seed"]}, None)
    if args.skill:
        model, _ = vae.load(args.skill)
    else:
        vcfg = vae.VAEConfig(**skills["vae"], seed=skills["seed"])
        model, _ = vae.fit_task(d.x.reshape(-1, 3), d.q.reshape(-1, 4), vcfg)
        vae.save(args.out / "skill.msgpack", model, vcfg, {"demo": "jc"})
    codes = np.asarray(model.encode(jnp.asarray(d.x, jnp.float32), jnp.asarray(d.q, jnp.float32))[0])
    nodes = kmeans(codes.reshape(-1, codes.shape[-1]), skills["graph_nodes"], skills["seed"])[0]
    graphdef, state = nnx.split(model)
    speed2, margs = metric.speed2_fn(graphdef), (state, metric.NONE)
    rng = np.random.default_rng(0)
    flat = codes.reshape(-1, codes.shape[-1])
    a, b = (jnp.asarray(flat[rng.integers(len(flat), size=args.batch)]) for _ in range(2))
    pairs = demo_pairs(d, skills["pairs"], skills["seed"])
    pa, pb = jnp.asarray(codes[pairs[:, 0], 0]), jnp.asarray(codes[pairs[:, 1], -1])
    fine = spline.basis(5, args.resolve)
    resolved = jax.jit(jax.vmap(lambda c: geodesic.curve_energy(speed2, margs, fine, c)))
    decode = jax.jit(jax.vmap(jax.vmap(model.decode_x)))
    demo_pts = d.x.reshape(-1, 3)

    rows = []
    sb20 = spline.basis(5, 20)
    line = jax.vmap(lambda a, b: spline.coefficients(sb20, a, b, spline.straight(sb20, a, b)))(pa, pb)
    dist = nearest(np.asarray(decode(jax.vmap(spline.dense)(line))), demo_pts)
    rows.append(
        {
            "config": "latent line",
            "resolved_median": float(np.median(resolved(line))),
            "dist_mean_cm": 100 * float(dist.mean()),
            "dist_max_cm": 100 * float(dist.max()),
        }
    )
    for spec in specs:
        solve = geodesic.solver(speed2, geodesic.GeodesicConfig(**spec), nodes)
        t = time.perf_counter()
        g = jax.block_until_ready(solve(margs, a, b))
        compile_s = time.perf_counter() - t
        times = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            g = jax.block_until_ready(solve(margs, a, b))
            times.append(time.perf_counter() - t)
        p = solve(margs, pa, pb)
        e, ef = np.asarray(p.energy), np.asarray(resolved(p.coeffs))
        dist = nearest(np.asarray(decode(jax.vmap(spline.dense)(p.coeffs))), demo_pts)
        rows.append(
            {
                "config": f"{spec['method']}, {spec['points']} points",
                **spec,
                "batch_s": float(np.median(times)),
                "compile_s": compile_s,
                "steps_mean": float(jnp.mean(g.iters)),
                "steps_max": int(jnp.max(g.iters)),
                "batch_energy_mean": float(jnp.mean(g.energy)),
                "solved_median": float(np.median(e)),
                "resolved_median": float(np.median(ef)),
                "ratio_median": float(np.median(ef / np.maximum(e, 1e-12))),
                "ratio_max": float(np.max(ef / np.maximum(e, 1e-12))),
                "dist_mean_cm": 100 * float(dist.mean()),
                "dist_max_cm": 100 * float(dist.max()),
            }
        )
        print(json.dumps(rows[-1]), flush=True)

    meta = {"batch": args.batch, "repeats": args.repeats, "resolve": args.resolve, "skill": str(args.skill or args.out / "skill.msgpack")}
    meta |= {"devices": jax.local_device_count(), "platform": jax.local_devices()[0].platform, "machine": platform.platform()}
    (args.out / "geodesics.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    f = lambda r, k, fmt: format(r[k], fmt) if k in r else ""  # noqa: E731
    md = [
        f"| solver | s per batch of {args.batch} | steps mean / max | experiment pairs: energy solved (median) | at {args.resolve} points (median) "
        "| ratio median / max | dist. to demos mean / max (cm) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        steps = f"{r['steps_mean']:.0f} / {r['steps_max']}" if "steps_max" in r else ""
        ratio = f"{r['ratio_median']:.3g} / {r['ratio_max']:.3g}" if "ratio_max" in r else ""
        md.append(
            f"| {r['config']} | {f(r, 'batch_s', '.2f')} | {steps} | {f(r, 'solved_median', '.3g')} | {r['resolved_median']:.4g} | {ratio} "
            f"| {r['dist_mean_cm']:.2f} / {r['dist_max_cm']:.2f} |"
        )
    (args.out / "geodesics.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
