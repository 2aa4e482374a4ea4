"""Merge `fabrax bench` runs into one table per problem class, laid out like gfcs_paper Table I.

    python experiments/bench_table.py bench_out/mbm/* --out docs/results/bench_mbm
    python experiments/bench_table.py bench_out/mbm/gfcs_hand --out docs/results/mbm --merge   # add one run

Reads each run's results.json and writes OUT.md (a markdown section per class:
success %, collision %, and mean ± std over successful problems of EE length,
C-space length, planning time, EE-LDJ, C-space-LDJ and duration) and OUT.json
(the same numbers plus each run's config and machine).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

COLUMNS = (("ee_length", "EE len (m)"), ("cspace_length", "C-space len (rad)"), ("plan_time_s", "plan time (s)"),
           ("ee_ldj", "EE-LDJ"), ("cspace_ldj", "C-space-LDJ"), ("duration_s", "duration (s)"))  # fmt: skip


def label(meta: dict, row_method: str) -> str:
    """Row label: OMPL methods carry their budget; other rows (and variants such as 'gfcs (1 b)') their name."""
    method = meta["config"]["method"]
    if method.get("type") == "ompl" and row_method == method["name"]:
        return f"{method['name']} ({method['budget_s']:g} s)"
    return row_method


def stats(values: list[float]) -> dict | None:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], float)
    return None if len(v) == 0 else {"mean": float(v.mean()), "std": float(v.std()), "n": len(v)}


def collect(runs: list[Path]) -> dict:
    table: dict = {}
    meta_out = {}
    for run in runs:
        data = json.loads((run / "results.json").read_text())
        meta_out[str(run)] = {k: data["meta"].get(k) for k in ("config", "machine", "versions", "wall_s")}
        for name, cls in sorted({(label(data["meta"], r["method"]), r["class"]) for r in data["rows"]}):
            rows = [r for r in data["rows"] if r["class"] == cls and label(data["meta"], r["method"]) == name]
            valid = [r for r in rows if r["valid_problem"]]
            ok = [r for r in valid if r["success"]]
            entry = {
                "problems": len(rows),
                "valid": len(valid),
                "success_pct": 100.0 * len(ok) / len(valid) if valid else None,
                "reached_pct": 100.0 * sum(r["reached"] for r in valid) / len(valid) if valid else None,
                "collision_pct": 100.0 * sum(r["collision"] for r in valid) / len(valid) if valid else None,
            }
            entry.update({key: stats([r[key] for r in ok]) for key, _ in COLUMNS})
            entry["compile_s"] = max((r.get("compile_s", 0.0) for r in valid), default=0.0)
            table.setdefault(cls, {})[name] = entry
    return {"runs": meta_out, "classes": table}


def merge(old: dict, new: dict) -> dict:
    """`old` with `new`'s runs and methods added, a method of the same name in a class replaced."""
    classes = {c: dict(m) for c, m in old["classes"].items()}
    for c, methods in new["classes"].items():
        classes.setdefault(c, {}).update(methods)
    return {"runs": {**old["runs"], **new["runs"]}, "classes": classes}


def markdown(result: dict) -> str:
    fmt = lambda s: "NA" if s is None else f"{s['mean']:.2f} ± {s['std']:.2f}"  # noqa: E731
    classes = list(result["classes"])
    names = list(dict.fromkeys(n for c in classes for n in result["classes"][c]))
    out = ["Success % (collision %) per class:\n", "| method | " + " | ".join(classes) + " |", "|---|" + "---:|" * len(classes)]
    for name in names:
        cells = []
        for c in classes:
            e = result["classes"][c].get(name)
            cells.append("–" if e is None or e["success_pct"] is None else f"{e['success_pct']:.0f} ({e['collision_pct']:.0f})")
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    out.append("")
    for cls, methods in result["classes"].items():
        out.append(f"#### {cls}\n")
        out.append("| method | valid | success % | reached % | collision % | " + " | ".join(h for _, h in COLUMNS) + " |")
        out.append("|---|---:|---:|---:|---:|" + "---:|" * len(COLUMNS))
        for name, e in methods.items():
            pct = lambda x: "–" if x is None else f"{x:.0f}"  # noqa: E731
            cells = [fmt(e[key]) for key, _ in COLUMNS]
            out.append(
                f"| {name} | {e['valid']}/{e['problems']} | {pct(e['success_pct'])} | {pct(e['reached_pct'])} | "
                f"{pct(e['collision_pct'])} | " + " | ".join(cells) + " |"
            )
        out.append("")
    out.append("Means ± std over the successful problems of each method; success, reach and collision over valid problems.\n")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path, help="run directories holding results.json")
    ap.add_argument("--out", type=Path, required=True, help="output path without suffix")
    ap.add_argument("--merge", action="store_true", help="add these runs' methods to an existing OUT.json, replacing same-named ones")
    args = ap.parse_args()
    runs = [r for r in args.runs if (r / "results.json").exists()]
    if not runs:
        raise SystemExit("no results.json in the given run directories")
    result = collect(runs)
    if args.merge:
        result = merge(json.loads(args.out.with_suffix(".json").read_text()), result)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    args.out.with_suffix(".md").write_text(markdown(result))
    print(markdown(result))
    print(f"written: {args.out.with_suffix('.md')}, {args.out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
