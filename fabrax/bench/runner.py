"""Run a method on problems, judge every result with the same checker and metrics, write reports.

Outputs in the run directory: `results.json` (one row per problem: `problem`,
`class`, `method`, `valid_problem`, the metrics of `metrics.evaluate`,
`plan_time_s`, `compile_s`), `paths.npz` (the joint paths, for `fabrax view results`), `summary.md` (per class, like gfcs_paper Table I)
and PNG plots (success per class, end-effector path lengths). While it runs, `solutions.pkl`
(the solutions so far and the settings they were made with) lets a stopped run resume.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pickle
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from fabrax.bench.methods import Method, Solution
from fabrax.bench.metrics import Goal, evaluate
from fabrax.problems.problem import Problem
from fabrax.robot.robot import Robot


class CheckpointMismatch(ValueError):
    """A run asked to resume from solutions made with other settings."""


METRICS = ("ee_length", "cspace_length", "ee_ldj", "cspace_ldj", "plan_time_s", "duration_s")


def run(
    method: Method,
    robot: Robot,
    problems: list[Problem],
    *,
    goal: Goal = Goal(),
    margin: float = 0.0,
    frame: str | None = None,
    progress: bool = True,
    checkpoint: Path | None = None,
    settings: dict | None = None,
    resume: bool = False,
    save_every_s: float = 30.0,
) -> list[dict]:
    """Rows of metrics, one per problem; invalid problems are reported (valid_problem false), not run.
    With goal.criterion "auto", a method's own `criterion` (e.g. "pose" for a pose-aimed fabric)
    decides `success`. With `checkpoint`, the solutions are saved there with `settings` after the
    last batch and after any batch that ends `save_every_s` or more after the previous save (a
    planner that solves in a millisecond would otherwise spend its run pickling). resume=True
    first loads them (refused if their settings differ) and solves only the problems still missing."""
    if goal.criterion == "auto" and getattr(method, "criterion", "auto") != "auto":
        goal = dataclasses.replace(goal, criterion=method.criterion)
    valid = [p for p in problems if p.valid]
    chunk = getattr(method, "batch_size", 1)
    solutions = _resumed(checkpoint, settings) if resume else {}
    todo = [p for p in valid if p.name not in solutions]
    saved = time.monotonic()
    with tqdm(total=len(valid), initial=len(valid) - len(todo), desc=method.name, disable=not progress, unit="problem") as bar:
        for start in range(0, len(todo), chunk):
            part = todo[start : start + chunk]
            if start == 0:  # the first call compiles: say so while the bar cannot move
                bar.set_postfix_str(f"compiling and solving the first {len(part)}", refresh=True)
            for p, s in zip(part, _solve(method, robot, part), strict=True):
                solutions[p.name] = s
            if checkpoint is not None and (start + chunk >= len(todo) or time.monotonic() - saved >= save_every_s):
                _save(checkpoint, settings, solutions)
                saved = time.monotonic()
            if start == 0:
                bar.set_postfix_str("", refresh=False)
            bar.update(len(part))
    rows = []
    for p in problems:
        s = solutions.get(p.name)
        # a method may also report intermediate results (e.g. GFCS after its first batch) as variants
        named = {method.name: s, **(s.info.pop("variants", {}) if s is not None else {})}
        for name, sol in sorted(named.items()):
            row = {"problem": p.name, "class": p.kind, "method": name, "valid_problem": p.valid, "invalid_reason": p.reason}
            if "problem_type" in p.meta:
                row["problem_type"] = p.meta["problem_type"]
            if p.valid:
                row.update(evaluate(robot, p, sol.q, sol.dt, goal=goal, frame=frame, margin=margin))
                row.update({"plan_time_s": sol.plan_time_s, "compile_s": sol.compile_s, "dt": sol.dt, "info": sol.info})
                row["path"] = np.asarray(sol.q, np.float32)  # written to paths.npz, not results.json
            rows.append(row)
    return rows


def _save(path: Path, settings: dict | None, solutions: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps({"settings": settings, "solutions": solutions}))
    os.replace(tmp, path)  # never a half-written checkpoint


def _resumed(path: Path | None, settings: dict | None) -> dict:
    """The solutions of an earlier run with the same settings (none if it left no checkpoint)."""
    if path is None or not path.exists():
        return {}
    saved = pickle.loads(path.read_bytes())
    if saved["settings"] != settings:
        keys = sorted(k for k in set(saved["settings"] or {}) | set(settings or {}) if (saved["settings"] or {}).get(k) != (settings or {}).get(k))
        raise CheckpointMismatch(f"{path} was written with other settings ({', '.join(keys)}); use another out= or resume=false")
    return saved["solutions"]


def _solve(method: Method, robot: Robot, part: list[Problem]) -> list:
    """The method's solutions of `part`; a problem it refuses (ValueError, e.g. a pose goal for a
    joint-space planner) fails alone, staying at its start with the error in its info."""
    try:
        return method.solve(robot, part)
    except ValueError as e:
        if len(part) > 1:
            return [s for p in part for s in _solve(method, robot, [p])]
        return [Solution(np.asarray(part[0].start_q)[None], getattr(method, "dt", 0.01), 0.0, 0.0, {"error": str(e)})]


def _mean_std(values: list[float]) -> str:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)])
    if len(v) == 0:
        return "–"
    fmt = lambda x: f"{x:.2f}" if abs(x) >= 0.01 or x == 0 else f"{x:.1e}"  # noqa: E731  (sub-10 ms planning times stay visible)
    return f"{fmt(v.mean())} ± {fmt(v.std())}"


def _table(rows: list[dict], by: str) -> list[str]:
    """Markdown lines: per method and value of `by` (a row key; "all" for one row per method),
    success and collision rates over valid problems and the mean ± std of every metric over the
    successful ones."""
    group = (lambda r: "all") if by == "all" else (lambda r: r.get(by, "–"))  # noqa: E731
    keys = sorted({(r["method"], group(r)) for r in rows})
    head = f"| method | {'class' if by == 'all' else by.replace('_', ' ')} | valid | success % | collision % | joint % | pose % | keypoints % | "
    lines = [head + " | ".join(METRICS) + " |", "|" + "---|" * 2 + "---:|" * (6 + len(METRICS))]
    for method, key in keys:
        mine = [r for r in rows if r["method"] == method and group(r) == key]
        sel = [r for r in mine if r["valid_problem"]]
        ok = [r for r in sel if r["success"]]
        n = len(sel)
        pct = lambda k: "–" if not n or any(r.get(k) is None for r in sel) else f"{100.0 * sum(bool(r[k]) for r in sel) / n:.0f}"  # noqa: E731
        cells = [_mean_std([r[m] for r in ok]) for m in METRICS]
        by_criterion = " | ".join(pct(k) for k in ("success_joint", "success_pose", "success_keypoints"))
        lines.append(f"| {method} | {key} | {n}/{len(mine)} | {pct('success')} | {pct('collision')} | {by_criterion} | " + " | ".join(cells) + " |")
    return lines


def summary_table(rows: list[dict]) -> str:
    """Markdown: per class and method (and, where rows carry one, per problem type and over all
    problems), success and collision rates over valid problems, and the mean ± std of every metric
    over the successful ones."""
    lines = _table(rows, "class")
    if any("problem_type" in r for r in rows):
        lines += ["", *_table(rows, "problem_type"), "", *_table(rows, "all")]
    note = "success by the run's criterion; joint / pose / keypoints: success by each criterion (joint tolerance, pose tolerance, "
    note += "mean keypoint distance). Metrics are means ± std over successful problems; lengths in m (EE) and rad (C-space), times in s."
    return "\n".join(lines) + "\n\n" + note + "\n" + problems_report(rows)


def errors(rows: list[dict]) -> list[dict]:
    """Rows of valid problems whose method raised (the reason in `info.error`): counted as failures."""
    return [r for r in rows if r.get("valid_problem") and (r.get("info") or {}).get("error")]


def problems_report(rows: list[dict]) -> str:
    """Markdown lines counting the rows that errored and the invalid problems, by reason (empty when
    there are none): a failure for a reason other than the motion never hides behind a success rate."""
    out = []
    for title, sel, reason in (
        ("errors (the method raised; counted as failures)", errors(rows), lambda r: r["info"]["error"]),
        ("invalid problems (not run)", [r for r in rows if not r.get("valid_problem")], lambda r: r.get("invalid_reason") or "?"),
    ):
        if not sel:
            continue
        counts: dict[str, int] = {}
        for r in sel:
            key = f"{r['method']}: {reason(r)}"
            counts[key] = counts.get(key, 0) + 1
        out.append(f"\n**{len(sel)} {title}**\n")
        out += [f"- {n} x {key}" for key, n in sorted(counts.items(), key=lambda kv: -kv[1])]
    return "\n".join(out) + ("\n" if out else "")


def write(rows: list[dict], out: Path, meta: dict | None = None) -> None:
    """results.json, paths.npz (every motion, keyed 'method|problem'), summary.md and plots in `out`."""
    out.mkdir(parents=True, exist_ok=True)
    paths = {f"{r['method']}|{r['problem']}": r["path"] for r in rows if "path" in r}
    if paths:
        np.savez_compressed(out / "paths.npz", **paths)
    plain = [{k: v for k, v in r.items() if k != "path"} for r in rows]
    text = json.dumps(strict_json({"meta": meta or {}, "rows": plain}), indent=1, allow_nan=False)
    (out / "results.json").write_text(text)
    (out / "summary.md").write_text(summary_table(rows))
    plots(rows, out)


def strict_json(x):
    """`x` as standard JSON values: NaN and infinities become null (strict parsers such as
    JavaScript's JSON.parse and jq reject bare NaN), numpy scalars and arrays plain numbers and
    lists, anything else its string."""
    if isinstance(x, dict):
        return {str(k): strict_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [strict_json(v) for v in x]
    if isinstance(x, np.ndarray):
        return strict_json(x.tolist())
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        x = x.item()
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if x is None or isinstance(x, (bool, int, str)):
        return x
    return str(x)


def plots(rows: list[dict], out: Path) -> None:
    if not rows:  # e.g. an experiment that only re-executes saved solutions
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    classes = sorted({r["class"] for r in rows})
    methods = sorted({r["method"] for r in rows})
    fig, ax = plt.subplots(figsize=(1.2 + 1.1 * len(classes), 3.2))
    width = 0.8 / len(methods)
    for k, m in enumerate(methods):
        rates = []
        for c in classes:
            sel = [r for r in rows if r["method"] == m and r["class"] == c and r["valid_problem"]]
            rates.append(100.0 * sum(r["success"] for r in sel) / len(sel) if sel else 0.0)
        ax.bar(np.arange(len(classes)) + k * width, rates, width, label=m)
    ax.set_xticks(np.arange(len(classes)) + 0.4 - width / 2, classes, rotation=30, ha="right")
    ax.set_ylabel("success %")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "success.png", dpi=120)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(1.2 + 1.1 * len(classes), 3.2))
    data = [[r["ee_length"] for r in rows if r["class"] == c and r["valid_problem"] and r["success"]] or [np.nan] for c in classes]
    ax.boxplot(data, tick_labels=classes)
    ax.set_ylabel("end-effector path length (m)")
    ax.tick_params(axis="x", rotation=30)
    fig.tight_layout()
    fig.savefig(out / "ee_length.png", dpi=120)
    plt.close(fig)
