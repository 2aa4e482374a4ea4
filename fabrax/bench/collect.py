"""`fabrax collect DIR...`: one table over many runs (a hydra sweep's job directories, or any run
directories): per run, method and class, success and collision rates and EE path length, with the
overrides that made the run (hydra's .hydra/overrides.yaml) as its label.

    fabrax collect multirun/bench/2026-11-22_12-00-00 --out sweep_table
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import yaml


def runs_under(roots: list[Path]) -> list[Path]:
    """Run directories (holding results.json) at or under the given paths."""
    found = []
    for r in roots:
        if not r.exists():
            raise FileNotFoundError(f"{r}: no such directory")
        found += sorted(p.parent for p in ([r / "results.json"] if (r / "results.json").exists() else r.rglob("results.json")))
    return found


def label(run: Path) -> str:
    f = run / ".hydra" / "overrides.yaml"
    if f.exists():
        overrides = yaml.safe_load(f.read_text()) or []
        return " ".join(o for o in overrides if not o.startswith("hydra")) or "(defaults)"
    return run.name


def collect(roots: list[Path]) -> list[dict]:
    """Rows per run, method and class; a run's label keeps only the overrides that vary across runs."""
    rows = []
    runs = runs_under(roots)
    tokens = [set(label(r).split()) for r in runs]
    common = set.intersection(*tokens) if len(runs) > 1 else set()
    for run in runs:
        data = json.loads((run / "results.json").read_text())
        groups: dict[tuple, list[dict]] = {}
        for r in data["rows"]:
            if r.get("valid_problem", True):
                groups.setdefault((r["method"], r["class"]), []).append(r)
        for (method, cls), sel in sorted(groups.items()):
            ok = [r["ee_length"] for r in sel if r["success"] and math.isfinite(r["ee_length"])]
            rows.append(
                {
                    "run": str(run),
                    "overrides": " ".join(t for t in label(run).split() if t not in common) or label(run),
                    "method": method,
                    "class": cls,
                    "n": len(sel),
                    "success_pct": 100.0 * sum(r["success"] for r in sel) / len(sel),
                    "collision_pct": 100.0 * sum(r["collision"] for r in sel) / len(sel),
                    "ee_length_mean": float(np.mean(ok)) if ok else None,
                }
            )
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| overrides | method | class | n | success % | collision % | EE length (m) |", "|---|---|---|---:|---:|---:|---:|"]
    for r in rows:
        ee = "–" if r["ee_length_mean"] is None else f"{r['ee_length_mean']:.2f}"
        lines.append(f"| {r['overrides']} | {r['method']} | {r['class']} | {r['n']} | {r['success_pct']:.0f} | {r['collision_pct']:.0f} | {ee} |")
    return "\n".join(lines) + "\n"


def write_report(out: Path, result, text: str) -> None:
    """A table's two files: OUT.json (the numbers and their runs' settings) and OUT.md (`text`),
    both printed where they went; the benchmark scripts' common ending."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    out.with_suffix(".md").write_text(text)
    print(text)
    print(f"wrote {out.with_suffix('.md')} and {out.with_suffix('.json')}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="fabrax collect", description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+", type=Path, help="sweep or run directories")
    ap.add_argument("--out", type=Path, default=None, help="write <out>.md and <out>.json (default: collected.md/.json in the first directory)")
    args = ap.parse_args(argv)
    try:
        rows = collect(args.dirs)
    except FileNotFoundError as e:
        raise SystemExit(f"fabrax collect: {e}") from None
    if not rows:
        raise SystemExit(f"fabrax collect: no results.json under {', '.join(map(str, args.dirs))}")
    write_report(args.out or args.dirs[0] / "collected", rows, markdown(rows))
    return 0
