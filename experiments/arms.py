"""The pure fabric (`gf`) and GFCS on generated MBM-like problems for every shipped arm.

    python experiments/arms.py --limit 20 --out docs/results/arms

Each arm gets its own problems: the MBM-like scenes carried into its workspace
(`fabrax.problems.workspace`), from its own ready posture, with the same fabric gains (configs/fabric/
panda.yaml, whose goal frame is each robot's `ee_frame`). Every (arm, method) pair is one `fabrax
bench` run into RUNS/<arm>_<method> (default bench_out/arms; resumable: a finished run is read back, not rerun). Writes
OUT.json (every row's success, collision and EE length, per class, with the runs' configs and
machine) and OUT.md (one table: success % (collision %) and EE length per arm, method and class).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from fabrax.bench.collect import write_report

ARMS = ("panda", "ur5", "xarm7", "kinova")
METHODS = ("gf", "gfcs")
CLASSES = ("table_pick", "table_under_pick", "box", "bookshelf", "cage")


def run(arm: str, method: str, limit: int, split: str, out: Path) -> dict:
    """One `fabrax bench` run (skipped when `out` already holds its results); its results.json."""
    if not (out / "results.json").exists():
        cmd = [sys.executable, "-m", "fabrax", "bench", f"robot={arm}", f"method={method}", "problems=mbm_like", f"split={split}"]
        cmd += [f"limit={limit}", f"out={out}", "progress=false"] + (["resume=true"] if (out / "solutions.pkl").exists() else [])
        print(" ".join(cmd[2:]), flush=True)
        subprocess.run(cmd, check=True)
    return json.loads((out / "results.json").read_text())


def summarise(rows: list[dict]) -> dict:
    valid = [r for r in rows if r.get("valid_problem")]
    ok = [r for r in valid if r.get("success")]
    ee = [r["ee_length"] for r in ok if r.get("ee_length") is not None and math.isfinite(r["ee_length"])]
    return {
        "problems": len(rows),
        "valid": len(valid),
        "errors": sum(1 for r in valid if (r.get("info") or {}).get("error")),
        "success": 100.0 * len(ok) / max(len(valid), 1),
        "collision": 100.0 * sum(bool(r.get("collision")) for r in valid) / max(len(valid), 1),
        "ee_length": float(np.mean(ee)) if ee else None,
        "plan_time_s": float(np.mean([r["plan_time_s"] for r in valid if r.get("plan_time_s") is not None])) if valid else None,
    }


def markdown(result: dict) -> str:
    """One table: success % (collision %) per arm, method and class, EE length, plan time, errors."""
    cell = lambda s: "–" if s["valid"] == 0 else f"{s['success']:.0f} ({s['collision']:.0f})"  # noqa: E731
    length = lambda s: "–" if s["ee_length"] is None else f"{s['ee_length']:.2f}"  # noqa: E731
    cfg = next(iter(result["runs"].values()))["config"]
    lines = [
        f"success % (collision %) on {cfg['limit']} generated MBM-like {cfg['split']} problems per class; EE length (m) over successes",
        "",
        "| arm | method | " + " | ".join(CLASSES) + " | all | EE length | plan time (s) | errors |",
        "|---|---|" + "---:|" * (len(CLASSES) + 4),
    ]
    for arm, methods in result["table"].items():
        for method, s in methods.items():
            t = s["all"]["plan_time_s"]
            lines.append(
                f"| {arm} | {method} | " + " | ".join(cell(s[c]) for c in CLASSES)
                + f" | {cell(s['all'])} | {length(s['all'])} | {'–' if t is None else f'{t:.2f}'} | {s['all']['errors']} |"
            )  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", nargs="+", default=list(ARMS))
    parser.add_argument("--methods", nargs="+", default=list(METHODS))
    parser.add_argument("--limit", type=int, default=20, help="problems per class")
    parser.add_argument("--split", default="test", choices=["test", "train"])
    parser.add_argument("--out", type=Path, default=Path("docs/results/arms"))
    parser.add_argument("--runs", type=Path, default=Path("bench_out/arms"), help="where the bench runs go")
    parser.add_argument("--merge", action="store_true", help="replace only these arms' rows in an existing OUT.json")
    args = parser.parse_args(argv)

    runs_dir = args.runs
    table: dict = {}
    meta: dict = {}
    if args.merge and args.out.with_suffix(".json").exists():  # these (arm, method) entries replace the file's
        old = json.loads(args.out.with_suffix(".json").read_text())
        table, meta = old["table"], old["runs"]
    for arm in args.arms:
        for method in args.methods:
            res = run(arm, method, args.limit, args.split, runs_dir / f"{arm}_{method}")
            rows = [r for r in res["rows"] if r["method"] == method]
            table.setdefault(arm, {})[method] = {"all": summarise(rows), **{c: summarise([r for r in rows if r["class"] == c]) for c in CLASSES}}
            meta[f"{arm}/{method}"] = {k: res["meta"].get(k) for k in ("config", "machine", "versions", "source", "wall_s")}
    order = [a for a in ARMS if a in table] + [a for a in table if a not in ARMS]
    result = {"table": {a: table[a] for a in order}, "runs": meta}
    write_report(args.out, result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
