"""Geodesic batch speed and quality: solvers, discretisation rules and point counts on one trained skill.

For a task-space skill (`--skill`: a skill.msgpack from experiments/skills.py; without it the J/C
skill is trained with configs/skills.yaml's VAE settings, `--demo`, `--latent`, `--bandwidth`, `--hemisphere` and `--seed`, and saved
under --out), each solver configuration `method:rule:points` runs a batch of `--batch` random pairs
of demonstration codes and reports:

- wall time (median of `--repeats` after compilation), steps mean / max;
- the solved energy, and the same curves' energy at `--resolve` points by both rules, the larger
  taken (`fabrax.skills.experiment.resolved_energy`): their ratio is near 1 where the solver's
  points resolve the metric; its percentiles, and the fraction of pairs within 10 %;
- the decoded curves' distance to the demonstrations.

Writes JSON and a markdown table.

    python experiments/bench_geodesics.py --out bench_out/geodesics
    python experiments/bench_geodesics.py --skill docs/results/skills/jc/skill.msgpack --configs newton:chord:20 newton:gauss:20
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
from fabrax.skills.experiment import load_demos, nearest, resolved_energy
from fabrax.skills.rbf import kmeans


def parse(spec: str) -> dict:
    parts = spec.split(":")
    if len(parts) != 3 or parts[0] not in geodesic.METHODS or parts[1] not in spline.RULES or not parts[2].isdigit():
        raise SystemExit(f"bench_geodesics: --configs entry '{spec}' is not method:rule:points (methods {geodesic.METHODS}, rules {spline.RULES})")
    return {"method": parts[0], "rule": parts[1], "points": int(parts[2])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skill", type=Path, help="a task-space skill.msgpack (default: train a J/C skill)")
    ap.add_argument("--demo", default="jc", choices=["jc", "lasa"], help="demonstrations of the trained skill")
    ap.add_argument("--latent", type=int, help="latent dimension of the trained skill (default: configs/skills.yaml)")
    ap.add_argument("--bandwidth", type=float, help="RBF bandwidth of the trained skill (default: configs/skills.yaml)")
    ap.add_argument("--hemisphere", action="store_true", help="train the skill with vae.antipodal=false")
    ap.add_argument("--seed", type=int, help="training seed of the trained skill (default: configs/skills.yaml)")
    ap.add_argument("--configs", nargs="+", default=["newton:chord:20", "newton:gauss:20", "adam:chord:20", "newton:chord:40"])
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--resolve", type=int, default=1000, help="points for the resolved energy")
    ap.add_argument("--out", type=Path, default=Path("bench_out/geodesics"))
    args = ap.parse_args()
    specs = [parse(s) for s in args.configs]
    args.out.mkdir(parents=True, exist_ok=True)

    skills = OmegaConf.to_container(OmegaConf.load(config.config_dir() / "skills.yaml"))
    seed = skills["seed"] if args.seed is None else args.seed
    if args.skill:
        model, head = vae.load(args.skill)
        demo = head.get("demo", "jc")
    else:
        demo = args.demo
        overrides = {k: v for k, v in (("bandwidth", args.bandwidth), ("latent", args.latent)) if v is not None}
        overrides |= {"antipodal": False} if args.hemisphere else {}
        vcfg = vae.VAEConfig(**{**skills["vae"], **overrides}, seed=seed)
    d = load_demos({"demo": demo, "points": skills["points"], "seed": skills["seed"], "lasa_shape": skills["lasa_shape"]}, None)
    if not args.skill:
        model, _ = vae.fit_task(d.x.reshape(-1, 3), d.q.reshape(-1, 4), vcfg)
        vae.save(args.out / "skill.msgpack", model, vcfg, {"demo": demo})
    if not isinstance(model, vae.TaskVAE):
        raise SystemExit("bench_geodesics: --skill must be a task-space skill")
    codes = np.asarray(model.encode(jnp.asarray(d.x, jnp.float32), jnp.asarray(d.q, jnp.float32))[0])
    nodes = kmeans(codes.reshape(-1, codes.shape[-1]), skills["graph_nodes"], skills["seed"])[0]
    graphdef, state = nnx.split(model)
    curve_metric, margs = metric.curve_metric(graphdef), (state, metric.NONE)
    rng = np.random.default_rng(0)
    flat = codes.reshape(-1, codes.shape[-1])
    a, b = (jnp.asarray(flat[rng.integers(len(flat), size=args.batch)]) for _ in range(2))
    decode = jax.jit(jax.vmap(jax.vmap(model.decode_x)))
    demo_pts = d.x.reshape(-1, 3)

    def quality(coeffs, solved=None) -> dict:
        true = np.asarray(resolved_energy(curve_metric, margs, 5, args.resolve, coeffs))
        dist = nearest(np.asarray(decode(jax.vmap(spline.dense)(coeffs))), demo_pts)
        out = {"resolved_median": float(np.median(true)), "dist_mean_cm": 100 * float(dist.mean()), "dist_max_cm": 100 * float(dist.max())}
        if solved is not None:
            ratio = true / np.maximum(np.asarray(solved), 1e-12)
            out |= {"solved_median": float(np.median(solved)), "ratio_pct": [float(v) for v in np.percentile(ratio, [50, 90, 99, 100])]}
            out["within_10pct"] = float(np.mean(ratio <= 1.1))
        return out

    rows = []
    sb20 = spline.basis(5, 20)
    line = jax.vmap(lambda a, b: spline.coefficients(sb20, a, b, spline.straight(sb20, a, b)))(a, b)
    rows.append({"config": "latent line", **quality(line)})
    for spec in specs:
        solve = geodesic.solver(curve_metric, geodesic.GeodesicConfig(**spec, check=0), nodes)
        t = time.perf_counter()
        g = jax.block_until_ready(solve(margs, a, b))
        compile_s = time.perf_counter() - t
        times = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            g = jax.block_until_ready(solve(margs, a, b))
            times.append(time.perf_counter() - t)
        rows.append(
            {
                "config": f"{spec['method']}, {spec['rule']}, {spec['points']} points",
                **spec,
                "batch_s": float(np.median(times)),
                "compile_s": compile_s,
                "steps_mean": float(jnp.mean(g.iters)),
                "steps_max": int(jnp.max(g.iters)),
                **quality(g.coeffs, g.energy),
            }
        )
        print(json.dumps(rows[-1]), flush=True)

    meta = {
        "batch": args.batch,
        "repeats": args.repeats,
        "resolve": args.resolve,
        "skill": str(args.skill or args.out / "skill.msgpack"),
        "demo": demo,
    }
    meta |= {"devices": jax.local_device_count(), "platform": jax.local_devices()[0].platform, "machine": platform.platform()}
    (args.out / "geodesics.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    f = lambda r, k, fmt: format(r[k], fmt) if k in r else ""  # noqa: E731
    md = [
        f"| solver | s per batch of {args.batch} | steps mean / max | energy solved (median) | at {args.resolve} points (median) "
        "| ratio p50 / p90 / p99 / max | within 10 % | dist. to demos mean / max (cm) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        steps = f"{r['steps_mean']:.0f} / {r['steps_max']}" if "steps_max" in r else ""
        ratio = " / ".join(f"{v:.3g}" for v in r["ratio_pct"]) if "ratio_pct" in r else ""
        within = f"{r['within_10pct']:.0%}" if "within_10pct" in r else ""
        md.append(
            f"| {r['config']} | {f(r, 'batch_s', '.2f')} | {steps} | {f(r, 'solved_median', '.3g')} | {r['resolved_median']:.4g} "
            f"| {ratio} | {within} "
            f"| {r['dist_mean_cm']:.2f} / {r['dist_max_cm']:.2f} |"
        )
    (args.out / "geodesics.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
