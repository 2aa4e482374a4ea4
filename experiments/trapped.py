"""Where the pure fabric is trapped: what RL guides do on the problems the env's fabric fails.

    python experiments/trapped.py bench_out/t41m/fabric_switch bench_out/t41m/rl_guide_pretrained --out docs/results/trapped

The first run is the environment's pure fabric (`method=rl_guide method.scripted=switch`), the
others guides benchmarked on the same problems (fabrics_guided_rl_thesis §4: the guide exists to
steer the fabric out of local minima). Per problem type, over the valid problems: of those the
fabric ends without reaching the goal and without collision (trapped: a local minimum, or too slow
for the 20 s), how many each guide reaches without collision, and how many it ends in collision; of
those the fabric reaches, how many the guide loses. Writes OUT.md and OUT.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fabrax.bench.collect import write_report

TYPES = ("task_oriented", "neutral_start", "neutral_goal")


def _rows(run: Path) -> tuple[dict[str, dict], str]:
    data = json.loads((run / "results.json").read_text())
    methods = sorted({r["method"] for r in data["rows"]})
    if len(methods) != 1:
        raise SystemExit(f"trapped: {run} holds {len(methods)} methods ({', '.join(methods)}); give one run per method")
    return {r["problem"]: r for r in data["rows"] if r["valid_problem"]}, methods[0]


def _reached(r: dict) -> bool:
    return bool(r["success"]) and not r["collision"]


def compare(fabric: dict[str, dict], guide: dict[str, dict]) -> dict:
    """Per problem type and over all: the fabric's trapped and reached problems and what the guide does on them."""
    missing = sorted(set(fabric) - set(guide))
    if missing:
        raise SystemExit(f"trapped: the guide's run lacks {len(missing)} of the fabric's problems (e.g. {missing[0]})")
    out = {}
    for t in (*TYPES, "all"):
        names = [p for p, r in fabric.items() if t == "all" or r.get("problem_type") == t]
        trapped = [p for p in names if not fabric[p]["success"] and not fabric[p]["collision"]]
        reached = [p for p in names if _reached(fabric[p])]
        out[t] = {
            "n": len(names),
            "fabric_trapped": len(trapped),
            "fabric_reached": len(reached),
            "guide_reached_trapped": sum(_reached(guide[p]) for p in trapped),
            "guide_collided_trapped": sum(bool(guide[p]["collision"]) for p in trapped),
            "guide_lost_reached": sum(not _reached(guide[p]) for p in reached),
        }
    return out


def markdown(result: dict) -> str:
    head = "| guide | " + " | ".join(t.replace("_", " ") for t in (*TYPES, "all")) + " |"
    lines = [head, "|---|" + "---:|" * (len(TYPES) + 1)]
    for name, per in result["guides"].items():
        cells = []
        for t in (*TYPES, "all"):
            c = per[t]
            gained = f"{c['guide_reached_trapped']} / {c['fabric_trapped']} ({c['guide_collided_trapped']})"
            cells.append(f"{gained}; −{c['guide_lost_reached']} / {c['fabric_reached']}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    note = [
        "",
        f"Per cell: trapped problems of `{result['fabric_method']}` (no goal, no collision) the guide reaches without collision",
        "/ all trapped (of them ended in collision); −problems the fabric reaches and the guide does not / all the fabric reaches.",
    ]
    return "\n".join(lines + note) + "\n"


def sentence(result: dict) -> str:
    """docs/results.md's bullet: one per guide, per problem type."""
    names = " / ".join(t.replace("_", " ") for t in TYPES)
    lines = []
    for name, per in result["guides"].items():
        col = lambda key: " / ".join(str(per[t][key]) for t in TYPES)  # noqa: E731
        lines.append(
            f"- Where the env's fabric is trapped (no goal, no collision; {names}), `{name}` reaches "
            f"{col('guide_reached_trapped')} of {col('fabric_trapped')} problems without collision\n"
            f"  ({col('guide_collided_trapped')} collide) and loses {col('guide_lost_reached')} of the "
            f"{col('fabric_reached')} the fabric reaches (`python experiments/reproduce.py trapped`)."
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("fabric", type=Path, help="the pure fabric's run (method.scripted=switch)")
    ap.add_argument("guides", nargs="+", type=Path, help="guides' runs on the same problems")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    for run in (args.fabric, *args.guides):
        if not (run / "results.json").exists():
            raise SystemExit(f"trapped: {run} holds no results.json")
    fabric, fabric_method = _rows(args.fabric)
    guides = {}
    for run in args.guides:
        rows, method = _rows(run)
        guides[method] = compare(fabric, rows)
    result = {"fabric_method": fabric_method, "fabric_run": str(args.fabric), "guides": guides, "runs": [str(r) for r in args.guides]}
    write_report(args.out, result, markdown(result))


if __name__ == "__main__":
    main()
