"""Table 4.1 of fabrics_guided_rl_thesis from `fabrax bench` runs on `problems=mpinets`.

    python experiments/table_4_1.py bench_out/t41/* --out docs/results/table_4_1
    python experiments/table_4_1.py bench_out/t41/gfcs_pose --out docs/results/table_4_1 --merge   # add one run

One row per method: success % (collision %) per family, per problem type and over all valid
problems, with the thesis' figures (MπNets test set, 1,800 problems) beside them, and each method's
time: reaction time (mean ± std of `info.reaction_ms` for the RL env's methods) or planning time
(mean ± std over all problems). Writes OUT.md and OUT.json (the numbers, each run's settings and
its problem set's counts).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from fabrax.bench.collect import write_report

FAMILIES = ("cubby", "merged_cubby", "dresser", "tabletop")
TYPES = ("task_oriented", "neutral_start", "neutral_goal")
THESIS = {  # Table 4.1: success %, collision %, reaction time (s)
    "AIT*": (100.0, 0.0, "16.46 ± 0.90 s"),
    "Geometric Fabrics": (38.44, 8.61, "0.24 ± 0.03 ms"),
    "MπNets": (75.78, 13.78, "6.8 ± 0.07 ms"),
    "cuRobo": (99.92, 0.0, "89 ± 122 ms"),
    "RL guide": (99.15, 0.64, "2.79 ± 0.1 ms"),
}


def label(meta: dict, method: str) -> str:
    m = meta["config"]["method"]
    if m.get("type") == "ompl" and method == m["name"]:
        return f"{m['name']} ({m['budget_s']:g} s{', first solution' if m.get('first_solution') else ''})"
    return method


def rates(rows: list[dict], key: str = "success") -> dict:
    valid = [r for r in rows if r["valid_problem"]]
    if not valid:
        return {"n": 0}
    return {
        "n": len(valid),
        "success_pct": 100.0 * sum(bool(r.get(key)) for r in valid) / len(valid),
        "collision_pct": 100.0 * sum(bool(r["collision"]) for r in valid) / len(valid),
        "errors": sum(1 for r in valid if (r.get("info") or {}).get("error")),
    }


def timing(rows: list[dict]) -> dict:
    valid = [r for r in rows if r["valid_problem"]]
    react = [r["info"]["reaction_ms"] for r in valid if (r.get("info") or {}).get("reaction_ms") is not None]
    if react:
        std = [r["info"].get("reaction_ms_std") for r in valid if r["info"].get("reaction_ms_std") is not None]
        return {"reaction_ms": float(np.mean(react)), "reaction_ms_std": float(np.mean(std)) if std else None}
    plan = np.asarray([r["plan_time_s"] for r in valid if r.get("plan_time_s") is not None and math.isfinite(r["plan_time_s"])])
    return {"plan_s": float(plan.mean()), "plan_s_std": float(plan.std()), "plan_s_median": float(np.median(plan))} if len(plan) else {}


def collect(runs: list[Path]) -> dict:
    methods, meta = {}, {}
    for run in runs:
        data = json.loads((run / "results.json").read_text())
        meta[str(run)] = {k: data["meta"].get(k) for k in ("config", "versions", "machine", "wall_s", "problem_set", "source")}
        for name in sorted({label(data["meta"], r["method"]) for r in data["rows"]}):
            rows = [r for r in data["rows"] if label(data["meta"], r["method"]) == name]
            entry = {"all": rates(rows), "time": timing(rows), "run": str(run)}
            entry["family"] = {f: rates([r for r in rows if r["class"] == f]) for f in FAMILIES}
            entry["type"] = {t: rates([r for r in rows if r.get("problem_type") == t]) for t in TYPES}
            # MπNets' criterion (within 1 cm and 15°, no collision); not for the RL env's methods, whose
            # episodes end once the keypoints are within 0.08 m (thesis §3.4.5)
            entry["pose"] = {}
            if data["meta"]["config"]["method"].get("type") != "rl_guide":
                entry["pose"] = {"all": rates(rows, "success_pose")}
                entry["pose"] |= {t: rates([r for r in rows if r.get("problem_type") == t], "success_pose") for t in TYPES}
            methods[name] = entry
    return {"methods": methods, "runs": meta, "thesis": THESIS}


def _cell(r: dict) -> str:
    return "–" if not r.get("n") else f"{r['success_pct']:.1f} ({r['collision_pct']:.1f})"


def _time(t: dict) -> str:
    if "reaction_ms" in t:
        std = f" ± {t['reaction_ms_std']:.2f}" if t.get("reaction_ms_std") is not None else ""
        return f"{t['reaction_ms']:.2f}{std} ms reaction"
    if "plan_s" in t:
        return f"{t['plan_s']:.2f} ± {t['plan_s_std']:.2f} s (median {t['plan_s_median']:.2f})"
    return "–"


def markdown(result: dict) -> str:
    head = "| method | " + " | ".join(f.replace("_", " ") for f in FAMILIES) + " | " + " | ".join(t.replace("_", " ") for t in TYPES)
    head += " | all | all, 1 cm / 15° | n | time |"
    lines = [head, "|---|" + "---:|" * (len(FAMILIES) + len(TYPES) + 4)]
    for name, e in result["methods"].items():
        cells = [_cell(e["family"][f]) for f in FAMILIES] + [_cell(e["type"][t]) for t in TYPES]
        errors = f", {e['all']['errors']} errors" if e["all"].get("errors") else ""
        cells += [f"**{_cell(e['all'])}**", _cell(e["pose"].get("all", {}))]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {e['all'].get('n', 0)}{errors} | {_time(e['time'])} |")
    for name, (s, c, t) in THESIS.items():
        lines.append(f"| *thesis: {name}* | " + " | ".join([""] * (len(FAMILIES) + len(TYPES))) + f" | *{s:.2f} ({c:.2f})* | | *1,800* | *{t}* |")
    sets = {json.dumps(m.get("problem_set"), sort_keys=True) for m in result["runs"].values() if m.get("problem_set")}
    note = ["", "Success % (collision %) over valid problems, by each method's own criterion (keypoints for the fabric and the guide,"]
    note += ["the joint goal for planners); 'all, 1 cm / 15°': MπNets' criterion on the hand pose ('–' for the RL env's methods, whose"]
    note += ["episodes end at 0.08 m). Collisions by the exact checker."]
    note += [f"Problem set: {s}" for s in sorted(sets)]
    return "\n".join(lines + note) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--merge", action="store_true", help="add these runs' methods to an existing OUT.json, replacing same-named ones")
    args = ap.parse_args(argv)
    runs = [r for r in args.runs if (r / "results.json").exists()]
    if not runs:
        raise SystemExit("table_4_1: none of the given folders holds a results.json")
    result = collect(runs)
    old = args.out.with_suffix(".json")
    if args.merge and old.exists():
        prev = json.loads(old.read_text())
        result["methods"] = {**prev["methods"], **result["methods"]}
        result["runs"] = {**prev["runs"], **result["runs"]}
    write_report(args.out, result, markdown(result))


if __name__ == "__main__":
    main()
