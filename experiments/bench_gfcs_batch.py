"""GFCS time per batch: the wall time of every CMA-ES batch (population rollouts, ask, tell) in
`fabrax bench method=gfcs` runs, summarised per run. Writes JSON and a markdown table.

    fabrax bench method=gfcs problems=mbm split=train limit=2 progress=false out=bench_out/gfcs_batch/d1
    FABRAX_CPU_DEVICES=2 fabrax bench method=gfcs problems=mbm split=train limit=2 progress=false out=bench_out/gfcs_batch/d2
    python experiments/bench_gfcs_batch.py bench_out/gfcs_batch/d1 bench_out/gfcs_batch/d2 --out docs/results/gfcs_batch
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def summary(run: Path) -> dict:
    """Per-batch wall times of one run's GFCS rows (results.json), with its success count."""
    data = json.loads((run / "results.json").read_text())
    rows = [r for r in data["rows"] if r.get("valid_problem", True) and "batch_wall_s" in (r.get("info") or {})]
    if not rows:
        raise SystemExit(f"{run}/results.json: no GFCS rows with batch_wall_s")
    walls = np.concatenate([r["info"]["batch_wall_s"] for r in rows])
    return {
        "run": str(run),
        "problems": len(rows),
        "success": int(sum(bool(r["success"]) for r in rows)),
        "batches": int(walls.size),
        "mean_s": float(walls.mean()),
        "median_s": float(np.median(walls)),
        "min_s": float(walls.min()),
        "max_s": float(walls.max()),
        "first_batch_mean_s": float(np.mean([r["info"]["batch_wall_s"][0] for r in rows])),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="`fabrax bench method=gfcs` output directories")
    ap.add_argument("--out", type=Path, required=True, help="writes OUT.json and OUT.md")
    args = ap.parse_args()
    rows = [summary(r) for r in args.runs]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps({"runs": rows}, indent=1))
    lines = ["| run | batches | mean s | median s | min-max s | success |", "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        spread = f"{r['min_s']:.2f}-{r['max_s']:.2f}"
        lines.append(f"| {r['run']} | {r['batches']} | {r['mean_s']:.2f} | {r['median_s']:.2f} | {spread} | {r['success']}/{r['problems']} |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
