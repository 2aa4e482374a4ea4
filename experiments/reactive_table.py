"""The reactive study's table (gfcs_paper §V, Fig. 4) from `experiments/gfcs.py` runs, one per class.

    python experiments/reactive_table.py bench_out/reactive/* --out docs/results/reactive

Each run re-executed its class's GFCS solutions with one new cuboid blocking the old path (the
paper's re-execution without re-optimising) and, where `reactive.replan_batches` > 0, re-planned
by CMA-ES warm-started at the old solution. One row per class: problems, old path blocked, and
collision-free / reached % of both answers, with the re-plan's mean time per problem. Writes
OUT.md and OUT.json (the rows, each run's settings and machine).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fabrax.bench.collect import write_report
from fabrax.problems.mbm import TABLE_I_CLASSES


def collect(run_dirs: list[Path]) -> dict:
    """{class: the run's reactive summary} and each run's settings, from runs' results.json."""
    classes, runs = {}, {}
    for d in run_dirs:
        path = d / "results.json" if d.is_dir() else d
        if not path.is_file():
            raise SystemExit(f"reactive_table: no results.json at {path}")
        meta = json.loads(path.read_text())["meta"]
        if "reactive" not in meta:
            raise SystemExit(f"reactive_table: {path} has no reactive study (reactive.n_obstacles was 0)")
        name = meta["config"]["class_name"]
        if name in classes:
            raise SystemExit(f"reactive_table: two runs for class {name}")
        classes[name] = meta["reactive"]["summary"]
        runs[name] = {
            "config": {k: meta["config"][k] for k in ("reactive", "seed", "method", "dt", "t_max")},
            **{k: meta.get(k) for k in ("versions", "machine")},
        }
    return {"classes": classes, "runs": runs}


def markdown(result: dict) -> str:
    cell = lambda s, k: "–" if s.get(k) is None else f"{s[k]:.0f}"  # noqa: E731
    lines = [
        "| class | n | old path blocked % | re-executed: collision-free % | reached % "
        "| re-planned: collision-free % | reached % | re-plan time (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    total = {"n": 0}
    for c in TABLE_I_CLASSES:
        s = result["classes"].get(c)
        if s is None:
            continue
        time = "–" if s.get("replan_time_s") is None else f"{s['replan_time_s']:.2f}"
        lines.append(
            f"| {c} | {s['n']} | {cell(s, 'old_path_blocked_pct')} | {cell(s, 'collision_free_pct')} | {cell(s, 'reached_pct')} | "
            f"{cell(s, 'replan_collision_free_pct')} | {cell(s, 'replan_reached_pct')} | {time} |"
        )
        for k in ("old_path_blocked_pct", "collision_free_pct", "reached_pct", "replan_collision_free_pct", "replan_reached_pct", "replan_time_s"):
            if s.get(k) is not None:
                total[k] = total.get(k, 0.0) + s[k] * s["n"]
        total["n"] += s["n"]
    if total["n"]:
        avg = {k: v / total["n"] for k, v in total.items() if k != "n"}
        time = "–" if "replan_time_s" not in avg else f"{avg['replan_time_s']:.2f}"
        lines.append(
            f"| all | {total['n']} | {cell(avg, 'old_path_blocked_pct')} | {cell(avg, 'collision_free_pct')} | {cell(avg, 'reached_pct')} | "
            f"{cell(avg, 'replan_collision_free_pct')} | {cell(avg, 'replan_reached_pct')} | {time} |"
        )
    skipped = sum(s.get("skipped", 0) for s in result["classes"].values())
    if skipped:
        lines.append(f"\n{skipped} solved problem(s) skipped: no blocking cuboid fitted clear of the start and goal.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="experiments/gfcs.py run directories (or their results.json)")
    parser.add_argument("--out", type=Path, default=Path("docs/results/reactive"))
    args = parser.parse_args(argv)
    result = collect(args.runs)
    write_report(args.out, result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
