"""What the learned GFCS sampler learned, and how its warm start pays (gfcs_paper §IV-B, Table II).

    python experiments/gfcs_sampler.py bench_out/gfcs_tu --split test --out docs/results/gfcs_sampler
    python experiments/gfcs_sampler.py RUN --split train --first 41 --last 50 \\
        --variant 'ranked={"oversample": 8}' --variant 'long={"sgld": {"steps": 100, "step": 0.01, "noise": 0.1}}'

RUN is an `experiments/gfcs.py` run directory (its sampler.msgpack and .hydra/config.yaml). On the
chosen problems of the run's class, every sampler (uniform; the run's own warm start, `learned`;
each `--variant NAME=JSON`, a `selfsup.warm` mapping over the run's) gives GFCS's first batch, and
each first batch is scored as in Table II (success, EE and C-space length of its best candidate).
The samples themselves are compared with a reference solution per problem (GFCS from the uniform
sampler after the run's number of batches, or `--reference`, a results.json whose `gfcs` rows carry
their commands): the distance, in joint space normalised to the limits, from each sample to it.
Writes OUT.json, OUT.md and OUT.png (per joint: where uniform samples, learned samples and
reference solutions lie; and the distribution of sample-to-solution distances).

Tune on train problems the run did not learn from (e.g. learn on train 1-40 with `train_limit=40`,
tune on train 41-50); report on the test split.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import re
from pathlib import Path

import fabrax  # noqa: F401  (XLA flags)


def parse_variant(text: str) -> tuple[str, dict]:
    name, sep, body = text.partition("=")
    if not sep or not name:
        raise SystemExit(f"--variant: expected NAME=JSON, got {text!r}")
    try:
        value = json.loads(body)
    except json.JSONDecodeError as e:
        raise SystemExit(f"--variant {name}: not JSON ({e})") from None
    if not isinstance(value, dict):
        raise SystemExit(f"--variant {name}: expected a JSON mapping of selfsup.warm fields")
    return name, value


def index(name: str) -> int:
    m = re.search(r"(\d+)$", name)
    return int(m.group(1)) if m else -1


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path, help="an experiments/gfcs.py run directory")
    ap.add_argument("--split", default="test", choices=("train", "test"))
    ap.add_argument("--first", type=int, default=None, help="first problem number of the split (MBM numbering), inclusive")
    ap.add_argument("--last", type=int, default=None, help="last problem number, inclusive")
    ap.add_argument("--variant", action="append", default=[], type=parse_variant, help="NAME=JSON: a selfsup.warm mapping")
    ap.add_argument("--reference", type=Path, default=None, help="results.json whose gfcs rows give each problem's solution")
    ap.add_argument("--out", type=Path, default=None, help="OUT.json/.md/.png (default: RUN/sampler_<split>)")
    args = ap.parse_args(argv)

    import jax
    import numpy as np
    from omegaconf import OmegaConf

    from fabrax import config
    from fabrax.bench.methods import GFCSMethod
    from fabrax.bench.methods.gfcs import gfcs_config, learned_sampler
    from fabrax.bench.metrics import Goal
    from fabrax.bench.runner import run
    from fabrax.planners.gfcs.selfsup import WarmStart, learned_samples, reduce
    from fabrax.planners.gfcs.solver import uniform_sampler
    from fabrax.problems import ProblemBatch
    from fabrax.settings import from_mapping

    cfg_file = args.run / ".hydra" / "config.yaml"
    if not cfg_file.is_file():
        raise SystemExit(f"gfcs_sampler: {args.run} is not an experiments/gfcs.py run directory (no .hydra/config.yaml)")
    cfg = OmegaConf.to_container(OmegaConf.load(cfg_file), resolve=True)  # data_dir: ${oc.env:FABRAX_DATA,null}
    out = args.out or args.run / f"sampler_{args.split}"
    robot = config.load_robot(config.robot_choice(cfg))
    fabric, params = config.load_fabric(robot, cfg["fabric"])
    gfcs_cfg = gfcs_config(dict(cfg["method"]), cfg)
    try:
        learner, ss_cfg, enc = learned_sampler(args.run, robot, gfcs_cfg.n_commands)
        variants = {"learned": ss_cfg.warm}
        for name, body in args.variant:
            variants[name] = from_mapping(WarmStart, body, f"--variant {name}", base=ss_cfg.warm)
    except ValueError as e:
        raise SystemExit(f"gfcs_sampler: {e}") from None

    from fabrax.bench.cli import load_problems

    sub = {**cfg, "classes": [cfg["class_name"]], "split": args.split, "limit": None}
    problems = [p for p in load_problems(sub, robot) if p.valid]
    lo, hi = args.first or -np.inf, args.last or np.inf
    problems = [p for p in problems if lo <= index(p.name) <= hi]
    if not problems:
        raise SystemExit(f"gfcs_sampler: no valid {args.split} problems numbered {args.first}-{args.last}")
    goal = Goal(**cfg["goal"])
    first = dataclasses.replace(gfcs_cfg, batches=1)

    def rows_of(name: str, method_cfg, **extra) -> list[dict]:
        method = GFCSMethod(fabric, params, method_cfg, name, (1,), cfg["seed"], **extra)
        return run(method, robot, problems, goal=goal, margin=cfg["margin"], frame=cfg["frame"], progress=False)

    rows = rows_of("uniform", first)
    for name, warm in variants.items():
        rows += rows_of(name, first, learner=learner, selfsup=dataclasses.replace(ss_cfg, warm=warm), encoding=enc)

    # each problem's reference solution, normalised to [0, 1] within the limits
    span = np.asarray(robot.upper - robot.lower)
    lower = np.asarray(robot.lower)
    if args.reference is not None:
        saved = json.loads((args.reference / "results.json" if args.reference.is_dir() else args.reference).read_text())["rows"]
        ref = {r["problem"]: np.asarray(r["info"]["commands"]) for r in saved if r["method"] == "gfcs" and r.get("success")}
        ref_source = str(args.reference)
    else:
        ref_rows = rows_of("gfcs", gfcs_cfg)
        ref = {r["problem"]: np.asarray(r["info"]["commands"]) for r in ref_rows if r["method"] == "gfcs" and r.get("success")}
        ref_source = f"gfcs, uniform sampler, {gfcs_cfg.batches} batches"
    ref = {k: ((v - lower) / span).reshape(-1) for k, v in ref.items()}

    samples = {"uniform": [], **{n: [] for n in variants}}
    dist = {n: [] for n in samples}
    for p in problems:
        prob = ProblemBatch.of(p)
        key = jax.random.fold_in(jax.random.PRNGKey(cfg["seed"]), index(p.name))
        x = reduce(learner, enc.context(robot, prob.start_q, prob.start_qd, prob.goal_q, prob.scene))
        draws = {"uniform": uniform_sampler(key, robot, first.population, first.n_commands)}
        for name, warm in variants.items():
            draws[name] = learned_samples(learner, robot, x, key, first.population, first.n_commands, dataclasses.replace(ss_cfg, warm=warm))
        for name, z in draws.items():
            u = np.asarray(jax.nn.sigmoid(z)).reshape(first.population, -1)  # to_commands' map, normalised
            samples[name].append(u)
            if p.name in ref:
                dist[name].append(np.linalg.norm(u - ref[p.name], axis=-1))

    methods = ["uniform", *variants]
    table = {}
    for name in methods:
        rs = [r for r in rows if r["method"] == name]
        ok = [r for r in rs if r["success"]]
        d = np.concatenate(dist[name]) if dist[name] else np.zeros(0)
        table[name] = {
            "n": len(rs),
            "success_pct": 100.0 * len(ok) / len(rs),
            "ee_length": float(np.mean([r["ee_length"] for r in ok])) if ok else None,
            "ee_length_std": float(np.std([r["ee_length"] for r in ok])) if ok else None,
            "cspace_length": float(np.mean([r["cspace_length"] for r in ok])) if ok else None,
            "ee_ldj": float(np.mean([r["ee_ldj"] for r in ok])) if ok else None,
            "plan_time_s": float(np.mean([r["plan_time_s"] for r in rs])),
            "distance_median": float(np.median(d)) if len(d) else None,
            "distance_min_mean": float(np.mean([np.min(x) for x in dist[name]])) if dist[name] else None,
        }
    base = table["uniform"]["ee_length"]
    for name in methods:
        ee = table[name]["ee_length"]
        table[name]["ee_change_pct"] = None if ee is None or base is None else 100.0 * (ee / base - 1.0)

    result = {
        "run": str(args.run),
        "class": cfg["class_name"],
        "split": args.split,
        "problems": [p.name for p in problems],
        "reference": ref_source,
        "variants": {n: dataclasses.asdict(w) for n, w in variants.items()},
        "population": first.population,
        "table": table,
        "rows": [{k: v for k, v in r.items() if k not in ("path", "info")} for r in rows],
        "versions": {"python": platform.python_version(), "jax": jax.__version__},
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    out.with_suffix(".md").write_text(markdown(result))
    plot(out.with_suffix(".png"), samples, ref, robot.dof, first.n_commands, dist, result)
    print(markdown(result))


def markdown(result: dict) -> str:
    f = lambda v, d=2: "–" if v is None else f"{v:.{d}f}"  # noqa: E731
    lines = [
        f"{result['class']}, {result['split']} split, {len(result['problems'])} problems: GFCS's first batch "
        f"({result['population']} candidates) from each sampler; distances to each problem's reference solution "
        f"({result['reference']}) in joint space normalised to the limits.",
        "",
        "| sampler | success % | EE len (m) | vs uniform | C-space len (rad) | EE-LDJ | median distance | nearest sample | time (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, t in result["table"].items():
        change = "–" if t["ee_change_pct"] is None else f"{t['ee_change_pct']:+.0f} %"
        lines.append(
            f"| {name} | {t['success_pct']:.0f} | {f(t['ee_length'])} ± {f(t['ee_length_std'])} | {change} | "
            f"{f(t['cspace_length'])} | {f(t['ee_ldj'])} | {f(t['distance_median'])} | {f(t['distance_min_mean'])} | {f(t['plan_time_s'])} |"
        )
    return "\n".join(lines) + "\n"


def plot(path: Path, samples: dict, ref: dict, dof: int, n_commands: int, dist: dict, result: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    d = dof * n_commands
    fig, axes = plt.subplots(2, d, figsize=(2.2 * d, 5.2), gridspec_kw={"height_ratios": [3, 2]})
    sols = np.stack(list(ref.values())) if ref else np.zeros((0, d))
    bins = np.linspace(0, 1, 21)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for j in range(d):
        ax = axes[0, j]
        for i, (name, u) in enumerate(samples.items()):
            ax.hist(np.concatenate(u)[:, j], bins=bins, density=True, histtype="step", color=colours[i % len(colours)], label=name)
        ax.hist(sols[:, j], bins=bins, density=True, alpha=0.35, color="k", label="solutions")
        ax.set_title(f"command {j // dof + 1}, joint {j % dof + 1}", fontsize=8)
        ax.set_yticks([])
        ax.set_xlabel("position in limits", fontsize=7)
    axes[0, 0].legend(fontsize=6)
    gs = axes[1, 0].get_gridspec()
    for ax in axes[1]:
        ax.remove()
    ax = fig.add_subplot(gs[1, :])
    for i, (name, ds) in enumerate(dist.items()):
        if ds:
            x = np.sort(np.concatenate(ds))
            ax.plot(x, np.linspace(0, 1, len(x)), color=colours[i % len(colours)], label=name)
    ax.set_xlabel("distance from a sample to its problem's solution (joint space, normalised to the limits)")
    ax.set_ylabel("fraction of samples")
    ax.legend(fontsize=7)
    fig.suptitle(f"GFCS samplers on {result['class']} ({result['split']}, {len(result['problems'])} problems)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
