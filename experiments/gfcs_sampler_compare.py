"""Several learned GFCS samplers side by side, class by class, from `gfcs_sampler.py` outputs.

    python experiments/gfcs_sampler_compare.py 'd_E x0.1=bench_out/val40/*_s01_sampler.json' \\
        'd_E x1=bench_out/val40/*_s1_sampler.json' --out docs/results/gfcs_sampler/weight/compare

Each LABEL=GLOB[,GLOB...] names one setting and the `gfcs_sampler.py` JSON files (one per class)
it was measured in; a class's row gives, per setting, the learned first batch's success, EE length and
change against the uniform first batch measured in the same file, and the median sample-to-solution
distance. The uniform column is the first setting's file (each file measures its own). The last row
is the mean over the classes every setting has, the figure a setting shared by all classes is chosen
on (tune on train problems the samplers did not learn from).
Writes OUT.json and OUT.md.
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path


def parse_setting(text: str) -> tuple[str, list[Path]]:
    label, sep, pattern = text.partition("=")
    if not sep or not label or not pattern:
        raise SystemExit(f"expected LABEL=GLOB[,GLOB...], got {text!r}")
    files = []
    for part in pattern.split(","):
        found = sorted(Path(p) for p in glob.glob(part))
        if not found:
            raise SystemExit(f"{label}: no file matches {part!r}")
        files += found
    return label, files


def load(files: list[Path]) -> dict[str, dict]:
    """class -> {uniform, learned, n, split, run} from each file's table."""
    rows, seen = {}, {}
    for f in files:
        try:
            d = json.loads(f.read_text())
            table = d["table"]
            rows[d["class"]] = {
                "uniform": table["uniform"],
                "learned": table["learned"],
                "split": d["split"],
                "problems": d["problems"],
                "run": d["run"],
            }
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise SystemExit(f"{f}: not a gfcs_sampler.py output ({e.__class__.__name__}: {e})") from None
        if seen.setdefault(d["class"], f) != f:
            raise SystemExit(f"{f}: a second file for class {d['class']} (first {seen[d['class']]})")
    return rows


def compare(settings: dict[str, dict[str, dict]]) -> dict:
    classes = sorted(set().union(*settings.values()))
    common = [c for c in classes if all(c in rows for rows in settings.values())]
    splits = sorted({rows[c]["split"] for rows in settings.values() for c in rows})
    out = {"settings": list(settings), "splits": splits, "classes": {}, "mean_over": common, "mean": {}}
    for c in classes:
        out["classes"][c] = {
            label: {
                "success_pct": rows[c]["learned"]["success_pct"],
                "ee_length": rows[c]["learned"]["ee_length"],
                "uniform_ee_length": rows[c]["uniform"]["ee_length"],
                "uniform_success_pct": rows[c]["uniform"]["success_pct"],
                "ee_change_pct": rows[c]["learned"]["ee_change_pct"],
                "distance_median": rows[c]["learned"]["distance_median"],
                "uniform_distance_median": rows[c]["uniform"]["distance_median"],
                "n": rows[c]["learned"]["n"],
                "run": rows[c]["run"],
            }
            for label, rows in settings.items()
            if c in rows
        }
    for label in settings:
        cells = [out["classes"][c][label] for c in common]
        if cells:
            out["mean"][label] = {k: sum(x[k] for x in cells) / len(cells) for k in ("success_pct", "ee_change_pct", "distance_median")}
    return out


def markdown(result: dict) -> str:
    labels = result["settings"]
    head = "| class | uniform: success %, EE (m) | " + " | ".join(f"{s}: success %, EE (m), change, median distance" for s in labels) + " |"
    caption = (
        f"GFCS's first batch (its best candidate) from each learned sampler and from the uniform one, on the "
        f"{'/'.join(result['splits'])} problems of each `gfcs_sampler.py` file; change: EE length against uniform's; "
        "median distance: sample to solution, joint space normalised to the limits.\n"
    )
    lines = [caption, head, "|---|---:|" + "---:|" * len(labels)]
    for c, cells in result["classes"].items():
        first = next(iter(cells.values()))
        row = [c, f"{first['uniform_success_pct']:.0f}, {first['uniform_ee_length']:.2f}"]
        for s in labels:
            x = cells.get(s)
            row.append("–" if x is None else f"{x['success_pct']:.0f}, {x['ee_length']:.2f}, {x['ee_change_pct']:+.0f} %, {x['distance_median']:.2f}")
        lines.append("| " + " | ".join(row) + " |")
    if result["mean"]:
        row = [f"mean over {len(result['mean_over'])} classes", ""]
        for s in labels:
            m = result["mean"].get(s)
            row.append("–" if m is None else f"{m['success_pct']:.0f}, –, {m['ee_change_pct']:+.1f} %, {m['distance_median']:.2f}")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("settings", nargs="+", type=parse_setting, help="LABEL=GLOB of gfcs_sampler.py JSON files")
    ap.add_argument("--out", type=Path, required=True, help="OUT.json / OUT.md")
    args = ap.parse_args(argv)
    labels = [label for label, _ in args.settings]
    if len(set(labels)) != len(labels):
        raise SystemExit("each setting needs its own LABEL")
    result = compare({label: load(files) for label, files in args.settings})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    text = markdown(result)
    args.out.with_suffix(".md").write_text(text)
    print(text, end="")


if __name__ == "__main__":
    main()
