"""One command per results table: rerun it, or re-render README.md and docs/results.md from its JSON.

    python experiments/reproduce.py --list          # the tables, their JSON and their commands
    python experiments/reproduce.py mbm             # rerun the table's commands, then render it
    python experiments/reproduce.py --render        # re-render every table from its JSON (no rerun)
    python experiments/reproduce.py --check         # exit 1 when a rendered table differs from its JSON

Every table lives in docs/results/<name>.json, written by the table's last command. README.md and
docs/results.md hold each table between `<!-- reproduce:NAME[:VIEW] -->` and `<!-- /reproduce -->`
markers, rendered from that JSON, so that the two files can never disagree with it or with each
other. Paper figures are constants here, cited to their seed table.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
FILES = (ROOT / "README.md", ROOT / "docs" / "results.md")
MARKER = re.compile(r"(<!-- reproduce:(?P<name>[\w]+)(?::(?P<view>\w+))? -->\n)(?P<body>.*?)(<!-- /reproduce -->)", re.S)


def _script(name: str):
    """A sibling experiment script as a module (its `markdown` renderers)."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ------------------------------------------------------------------------ MotionBenchMaker (gfcs_paper Table I)

# fabrax.problems.mbm.TABLE_I_CLASSES, written out: this script imports nothing of fabrax
MBM_CLASSES = ("table_under_pick", "box", "bookshelf_tall", "cage", "bookshelf_thin", "bookshelf_small")
PAPER_TABLE_I = {  # gfcs_paper Table I: success % per class (GF; GFCS after 5 batches and after 1)
    "*paper GF*": (0, 100, 88, 88, 80, 94),
    "*paper GFCS, 5 batches*": (98, 100, 100, 100, 100, 100),
    "*paper GFCS, 1 batch*": (96, 100, 100, 98, 100, 100),
}
PAPER_EE_LENGTH = (1.32, 0.97, 1.00, 0.73, 0.92, 0.91)  # gfcs_paper Table I: GFCS EE path length (m) after 5 batches
MBM_ROWS = {  # row label in the table -> method label in the JSON (experiments/bench_table.py)
    "gf (the fabric alone, pose aim + posture; success by pose)": "gf",
    "gf_joint (the fabric alone, joint aim)": "gf_joint",
    "GFCS, 5 batches of 64": "gfcs",
    "GFCS, 1 batch": "gfcs (1 b)",
    "GFCS, 5 batches, constant hand metric (`method.hand_mass=5.304`)": "gfcs_hand",
    "GFCS, learned sampler (Algorithm 2 on train 1–50), hand metric, 5 batches": "gfcs_learned",
    "GFCS, learned sampler, hand metric, 1 batch": "gfcs_learned (1 b)",
    "RRTConnect 1.2 s": "rrtconnect (1.2 s)",
    "Bi-EST 1.2 s": "biest (1.2 s)",
    "BIT* 1.2 s": "bitstar (1.2 s)",
    "AIT* 1.2 s": "aitstar (1.2 s)",
}


def _mbm_rows(result: dict, cell) -> list[str]:
    """One line per method of MBM_ROWS that ran, `cell(entry)` per class ('–' where it did not)."""
    classes, lines = result["classes"], []
    for label, name in MBM_ROWS.items():
        entries = [classes.get(c, {}).get(name) for c in MBM_CLASSES]
        if any(e is not None for e in entries):
            lines.append((name, f"| {label} | " + " | ".join("–" if e is None else cell(e) for e in entries) + " |"))
    return lines


def _header(first: str) -> list[str]:
    return ["| " + first + " | " + " | ".join(MBM_CLASSES) + " |", "|---|" + "---:|" * len(MBM_CLASSES)]


def _paper(label: str, row) -> str:
    return f"| {label} | " + " | ".join(f"*{v}*" for v in row) + " |"


def mbm_success(result: dict) -> str:
    """Success % (collision %) per class, the paper's Table I rows beside them."""
    cell = lambda e: "–" if e["success_pct"] is None else f"{e['success_pct']:.0f} ({e['collision_pct']:.0f})"  # noqa: E731
    lines = _header("method")
    for name, line in _mbm_rows(result, cell):
        lines.append(line)
        if name == "gf_joint":
            lines += [_paper(p, row) for p, row in PAPER_TABLE_I.items() if "GF*" in p]
    lines += [_paper(p, row) for p, row in PAPER_TABLE_I.items() if "GFCS" in p]
    return "\n".join(lines) + "\n"


def mbm_detail(result: dict) -> str:
    """EE path length and planning time of the successful motions, per class, beside the paper's."""
    cell = lambda e: "–" if e["ee_length"] is None else f"{e['ee_length']['mean']:.2f} / {e['plan_time_s']['mean']:.2f}"  # noqa: E731
    lines = _header("EE length (m) / plan time (s)") + [line for _, line in _mbm_rows(result, cell)]
    lines.append(_paper("*paper GFCS, 5 batches (EE length)*", [f"{v:.2f}" for v in PAPER_EE_LENGTH]))
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------ Table 4.1 (fabrics_guided_rl_thesis)

T41_ROWS = {  # row label -> method label in docs/results/table_4_1.json
    "pure fabric (`gf`)": "gf",
    "pure fabric in the guide's env": "fabric_switch",
    "RL guide, 128k env steps on MPiNets-like scenes (64 envs)": "rl_guide_mpinets",
    "RL guide, 128k env steps, in distribution (MπNets train seed)": "rl_guide_mpinets_train",
    "RL guide, pretrained: 166k env steps on MBM + procedural scenes": "rl_guide_pretrained",
    "GFCS, 1 batch (IK joint goal)": "gfcs",
    "GFCS, 1 batch (pose goal, no IK)": "gfcs_pose (1 b)",
    "OMPL RRTConnect, 20 s, first solution": "rrtconnect (20 s, first solution)",
    "OMPL AIT*, 20 s, first solution": "aitstar (20 s, first solution)",
}


def _by_type(result: dict, rows: dict[str, str], first: str, time: bool) -> list[str]:
    """Markdown lines of table_4_1.py JSON: one row per (label, method) of `rows` present in it,
    success % (collision %) per problem type and over all, then (`time`) reaction or planning time."""
    t41 = _script("table_4_1")
    head = f"| {first} | task oriented | neutral start | neutral goal | all |" + (" time |" if time else "")
    lines = [head, "|---|---:|---:|---:|---:|" + ("---:|" if time else "")]
    for label, name in rows.items():
        e = result["methods"].get(name)
        if e is None:
            continue
        cells = [t41._cell(e["type"][t]) for t in t41.TYPES] + [t41._cell(e["all"])]
        if time:
            t = e["time"]
            cells.append(f"{t['reaction_ms']:.2f} ms reaction" if "reaction_ms" in t else f"{t['plan_s']:.2f} s")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def t41_readme(result: dict) -> str:
    lines = _by_type(result, T41_ROWS, "method", time=True)
    thesis = result["thesis"]
    lines.append(
        "| *thesis (1,800 problems): pure fabric / AIT\\* / guide* | | | | "
        + " / ".join(f"*{thesis[k][0]:.2f} ({thesis[k][1]:.2f})*" for k in ("Geometric Fabrics", "AIT*", "RL guide"))
        + " | "
        + " / ".join(f"*{thesis[k][2]}*" for k in ("Geometric Fabrics", "AIT*", "RL guide"))
        + " |"
    )
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------ arms


def arms_readme(result: dict) -> str:
    names = {"panda": "Panda", "ur5": "UR5", "xarm7": "xArm7", "kinova": "Kinova JACO2"}
    cell = lambda s: f"{s['success']:.0f} ({s['collision']:.0f})"  # noqa: E731
    length = lambda s: "–" if s["ee_length"] is None else f"{s['ee_length']:.2f}"  # noqa: E731
    lines = ["| arm | gf | GFCS | gf / GFCS EE length (m) | GFCS plan time (s) |", "|---|---:|---:|---:|---:|"]
    for arm, m in result["table"].items():
        gf, gfcs = m["gf"]["all"], m["gfcs"]["all"]
        lines.append(f"| {names.get(arm, arm)} | {cell(gf)} | {cell(gfcs)} | {length(gf)} / {length(gfcs)} | {gfcs['plan_time_s']:.2f} |")
    return "\n".join(lines) + "\n"


PRETRAINED_ROWS = {  # row label -> method label in docs/results/rl_pretrained.json
    "env's pure fabric (`fabric_switch`)": "fabric_switch",
    "thesis rewards (intrinsic + curriculum), 166.4k": "rl_guide_thesis",
    "intrinsic reward only, 166.4k": "rl_guide_thesis_intr",
    "curriculum only, 166.4k": "rl_guide_thesis_curr",
    "neither, 166.4k": "rl_guide_thesis_nointr",
    "same, 332.8k (its run's best on validation)": "rl_guide_thesis_nointr_332800",
    "neither, one action scale for all states, 166.4k": "rl_guide_thesis_nointr_gstd",
    "same, and a bounded mean (today's defaults), 166.4k": "rl_guide_thesis_nointr_bounded",
    "the same checkpoint shipped (`method.checkpoint=pretrained`)": "rl_guide_pretrained",
}


def pretrained_ablation(result: dict) -> str:
    """The equal-budget reward ablation and the shipped guide, success % (collision %) by problem type."""
    return "\n".join(_by_type(result, PRETRAINED_ROWS, "600 test problems, success % (collision %)", time=False)) + "\n"


# ------------------------------------------------------------------------ the registry


@dataclasses.dataclass(frozen=True)
class Table:
    title: str
    commands: tuple[str, ...]  # run from the repository root with FABRAX_DATA set; the last one writes the JSON
    views: dict[str, Callable[[dict], str]]  # view name -> markdown from the JSON ("main" when the marker names none)

    @property
    def json(self) -> Path:
        return RESULTS / f"{self.name}.json"

    name: str = ""


# the network settings of guides trained before network.std and network.loc_bound existed
LEGACY_NET = "network.std=state network.loc_bound=null"
MBM_BENCH = "fabrax bench problems=mbm split=test progress=false"
SIX = '"classes=[' + ",".join(MBM_CLASSES) + ']"'
T41_BENCH = "fabrax bench problems=mpinets split=test progress=false"
# validation: 256 MPiNets-like problems of another seed, where checkpoints are chosen (never on the test split)
VAL_BENCH = "fabrax bench problems=mpinets split=test seed=20000 limit=256 solvable_s=null progress=false method=rl_guide"
RL_NOINTR = f"python experiments/rl.py rl=thesis {LEGACY_NET} env.intrinsic_weight=0 curriculum.cells=0 hydra.run.dir=bench_out/rl/thesis_nointr"
RL_THESIS = "python experiments/rl.py rl=thesis"
RL_LONG = "env.intrinsic_weight=0 curriculum.cells=0 ppo.num_evals={} ppo.num_timesteps={}"  # neither, evaluations 33,280 steps apart
ABLATION = ("thesis", "thesis_intr", "thesis_curr", "thesis_nointr", "thesis_nointr_gstd", "thesis_nointr_bounded")
TABLES = {
    t.name: t
    for t in (
        Table(
            "MotionBenchMaker test split, gfcs_paper Table I",
            (
                f"{MBM_BENCH} method=gf out=bench_out/mbm/gf",
                f"{MBM_BENCH} method=gf_joint out=bench_out/mbm/gf_joint",
                f"{MBM_BENCH} method=gfcs {SIX} out=bench_out/mbm/gfcs",
                f"{MBM_BENCH} method=gfcs method.name=gfcs_hand method.hand_mass=5.304 {SIX} out=bench_out/mbm/gfcs_hand",
                f"{MBM_BENCH} method=rrtconnect {SIX} out=bench_out/mbm/rrtconnect",
                f"{MBM_BENCH} method=biest {SIX} out=bench_out/mbm/biest",
                f"{MBM_BENCH} method=bitstar {SIX} out=bench_out/mbm/bitstar",
                f"{MBM_BENCH} method=aitstar {SIX} out=bench_out/mbm/aitstar",
            )
            + tuple(
                f"python experiments/gfcs.py class_name={c} reactive.n_obstacles=0 method.hand_mass=5.304 evaluate=[gfcs_learned] "
                f"progress=false hydra.run.dir=bench_out/mbm_learned/{c}"
                for c in MBM_CLASSES
            )
            + ("python experiments/bench_table.py bench_out/mbm/* bench_out/mbm_learned/* --out docs/results/mbm",),
            {"main": mbm_success, "detail": mbm_detail},
            "mbm",
        ),
        Table(
            "Table 4.1 on the MπNets-faithful test set (fabrics_guided_rl_thesis)",
            (
                f"python experiments/rl.py rl=mpinets {LEGACY_NET} ppo.num_timesteps=192000 ppo.num_evals=4 hydra.run.dir=bench_out/rl/mpinets",
                f"python experiments/rl.py rl=mpinets_train {LEGACY_NET} ppo.num_timesteps=192000 ppo.num_evals=4 "
                "hydra.run.dir=bench_out/rl/mpinets_train",
                f"{T41_BENCH} method=gf goal.criterion=keypoints out=bench_out/t41m/gf_kp",
                f"{T41_BENCH} method=rl_guide method.scripted=switch method.name=fabric_switch out=bench_out/t41m/fabric_switch",
                f"{T41_BENCH} method=rl_guide method.name=rl_guide_mpinets method.checkpoint=bench_out/rl/mpinets/checkpoints/000000128000 "
                "out=bench_out/t41m/rl_guide",
                f"{T41_BENCH} method=rl_guide method.name=rl_guide_mpinets_train "
                "method.checkpoint=bench_out/rl/mpinets_train/checkpoints/000000128000 out=bench_out/t41m/rl_guide_train",
                f"{T41_BENCH} method=rl_guide method.name=rl_guide_pretrained method.checkpoint=pretrained out=bench_out/t41m/rl_guide_pretrained",
                f'{T41_BENCH} method=gfcs method.batches=1 "method.report=[]" ik_goals=true out=bench_out/t41m/gfcs',
                f"{T41_BENCH} method=gfcs method.goal=pose method.name=gfcs_pose out=bench_out/t41m/gfcs_pose",
                f"{T41_BENCH} method=rrtconnect method.budget_s=20 method.first_solution=true ik_goals=true out=bench_out/t41m/rrtconnect",
                f"{T41_BENCH} method=aitstar method.budget_s=20 method.first_solution=true ik_goals=true out=bench_out/t41m/aitstar",
                "python experiments/table_4_1.py bench_out/t41m/* --out docs/results/table_4_1",
            ),
            {"main": t41_readme, "full": lambda r: _script("table_4_1").markdown(r)},
            "table_4_1",
        ),
        Table(
            "The pretrained guide: the thesis' scenes, a reward ablation at equal budget (fabrics_guided_rl_thesis §3.4)",
            (
                f"python experiments/rl.py rl=thesis {LEGACY_NET} hydra.run.dir=bench_out/rl/thesis",
                RL_NOINTR,
                f"{RL_NOINTR} resume=true ppo.num_timesteps=399360",
                f"FABRAX_CPU_DEVICES=2 {RL_NOINTR} resume=true ppo.num_timesteps=599040",
                "mkdir -p docs/results/rl_pretrained/thesis_rewards && cd bench_out/rl/thesis && "
                "cp progress.jsonl curves.png settings.json ../../../docs/results/rl_pretrained/thesis_rewards/",
                f"{RL_THESIS} {LEGACY_NET} curriculum.cells=0 hydra.run.dir=bench_out/rl/thesis_intr",
                f"{RL_THESIS} {LEGACY_NET} env.intrinsic_weight=0 hydra.run.dir=bench_out/rl/thesis_curr",
                f"FABRAX_CPU_DEVICES=2 {RL_THESIS} network.std=global network.loc_bound=null {RL_LONG.format(16, 499200)} "
                "hydra.run.dir=bench_out/rl/thesis_nointr_gstd",
                f"FABRAX_CPU_DEVICES=2 {RL_THESIS} {RL_LONG.format(14, 432640)} hydra.run.dir=bench_out/rl/thesis_nointr_bounded",
                f"for s in 133120 166400 332800 366080 532480; do {VAL_BENCH} method.name=nointr_$s "
                "method.checkpoint=bench_out/rl/thesis_nointr/checkpoints/000000$s out=bench_out/val/nointr_$s; done",
                f"for s in 166400 266240 332800 432640; do {VAL_BENCH} method.name=bounded_$s "
                "method.checkpoint=bench_out/rl/thesis_nointr_bounded/checkpoints/000000$s out=bench_out/val/bounded_$s; done",
                f"{VAL_BENCH} method.scripted=switch method.name=fabric_switch out=bench_out/val/fabric_switch",
                "python experiments/table_4_1.py bench_out/val/* --out docs/results/rl_pretrained/validation",
                "python experiments/ship_guide.py bench_out/rl/thesis_nointr_bounded --step 166400 --curves docs/results/rl_pretrained "
                '--note "one run to 432,640 env steps under FABRAX_CPU_DEVICES=2 (two XLA CPU devices); 166,400 is the checkpoint '
                "of highest validation success (256 MPiNets-like problems of seed 20000) with fewer collisions than the env's fabric\"",
                "cp bench_out/rl/thesis_nointr_bounded/{progress.jsonl,curves.png,settings.json} docs/results/rl_pretrained/one_scale_bounded/ && "
                "cp bench_out/rl/thesis_nointr_gstd/{curves.png,settings.json} docs/results/rl_pretrained/one_scale/",
                "for r in thesis_nointr thesis_nointr_gstd; do python experiments/rl_spread.py bench_out/rl/$r "
                "366080 399360 432640 465920 499200 --out docs/results/rl_spread/$r; done",
                "python experiments/rl_spread.py bench_out/rl/thesis_nointr_bounded 332800 366080 399360 432640 "
                "--out docs/results/rl_spread/thesis_nointr_bounded",
                f"{T41_BENCH} method=rl_guide method.scripted=switch method.name=fabric_switch out=bench_out/t41m/fabric_switch",
                f"for r in {' '.join(ABLATION)}; do {T41_BENCH} method=rl_guide method.name=rl_guide_$r "
                "method.checkpoint=bench_out/rl/$r/checkpoints/000000166400 out=bench_out/t41m/rl_guide_$r; done",
                f"{T41_BENCH} method=rl_guide method.name=rl_guide_thesis_nointr_332800 "
                "method.checkpoint=bench_out/rl/thesis_nointr/checkpoints/000000332800 out=bench_out/t41m/rl_guide_thesis_nointr_332800",
                f"{T41_BENCH} method=rl_guide method.name=rl_guide_pretrained method.checkpoint=pretrained out=bench_out/t41m/rl_guide_pretrained",
                "python experiments/table_4_1.py bench_out/t41m/fabric_switch "
                + " ".join(f"bench_out/t41m/rl_guide_{r}" for r in ABLATION)
                + " bench_out/t41m/rl_guide_thesis_nointr_332800 bench_out/t41m/rl_guide_pretrained --out docs/results/rl_pretrained",
            ),
            {"main": pretrained_ablation},
            "rl_pretrained",
        ),
        Table(
            "Where the env's pure fabric is trapped: the shipped guide on the problems it fails (fabrics_guided_rl_thesis §4)",
            (
                f"{T41_BENCH} method=rl_guide method.scripted=switch method.name=fabric_switch out=bench_out/t41m/fabric_switch",
                f"{T41_BENCH} method=rl_guide method.name=rl_guide_pretrained method.checkpoint=pretrained out=bench_out/t41m/rl_guide_pretrained",
                "python experiments/trapped.py bench_out/t41m/fabric_switch bench_out/t41m/rl_guide_pretrained --out docs/results/trapped",
            ),
            {"main": lambda r: _script("trapped").sentence(r), "table": lambda r: _script("trapped").markdown(r)},
            "trapped",
        ),
        Table(
            "GFCS reactive re-execution and warm-started re-planning (gfcs_paper §V)",
            tuple(
                f"python experiments/gfcs.py class_name={c} evaluate=[] reactive.method=gfcs reactive.results=bench_out/mbm/gfcs "
                f"progress=false hydra.run.dir=bench_out/reactive/{c}"
                for c in MBM_CLASSES
            )
            + tuple(  # the same study on the learned-sampler solutions of Table I (mbm's commands), written apart
                f"python experiments/gfcs.py class_name={c} evaluate=[] reactive.method=gfcs_learned reactive.results=bench_out/mbm_learned/{c} "
                f"method.hand_mass=5.304 progress=false hydra.run.dir=bench_out/reactive_learned/{c}"
                for c in MBM_CLASSES
            )
            + (
                "python experiments/reactive_table.py bench_out/reactive_learned/* --out docs/results/reactive_learned",
                "python experiments/reactive_table.py " + " ".join(f"bench_out/reactive/{c}" for c in MBM_CLASSES) + " --out docs/results/reactive",
            ),
            {"main": lambda r: _script("reactive_table").markdown(r)},
            "reactive",
        ),
        Table(
            "gf and GFCS on generated MBM-like problems, every shipped arm",
            ("python experiments/arms.py --limit 20 --out docs/results/arms",),
            {"main": arms_readme, "full": lambda r: _script("arms").markdown(r)},
            "arms",
        ),
    )
}


def render(text: str) -> str:
    """`text` with every marked table re-rendered from its JSON."""

    def one(m: re.Match) -> str:
        name, view = m["name"], m["view"] or "main"
        if name not in TABLES:
            raise SystemExit(f"reproduce: unknown table '{name}' in a marker (known: {', '.join(TABLES)})")
        table = TABLES[name]
        if view not in table.views:
            raise SystemExit(f"reproduce: table '{name}' has no view '{view}' (views: {', '.join(table.views)})")
        return m.group(1) + table.views[view](json.loads(table.json.read_text())) + m.group(5)

    return MARKER.sub(one, text)


def stale() -> list[str]:
    """The files whose marked tables differ from their JSON's rendering."""
    return [str(f.relative_to(ROOT)) for f in FILES if render(f.read_text()) != f.read_text()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("table", nargs="?", help="a table to rerun and render (see --list)")
    ap.add_argument("--list", action="store_true", help="the tables, their JSON and their commands")
    ap.add_argument("--render", action="store_true", help="re-render README.md and docs/results.md from the JSON")
    ap.add_argument("--check", action="store_true", help="exit 1 when a rendered table differs from its JSON")
    args = ap.parse_args(argv)
    if args.list:
        for name, t in TABLES.items():
            print(f"{name}: {t.title}\n  json: {t.json.relative_to(ROOT)}")
            print("\n".join(f"  $ {c}" for c in t.commands))
        return 0
    if args.check:
        bad = stale()
        print(
            "\n".join(f"{f}: a table differs from its JSON; run python experiments/reproduce.py --render" for f in bad)
            or "every table matches its JSON"
        )
        return 1 if bad else 0
    if args.table:
        if args.table not in TABLES:
            raise SystemExit(f"reproduce: unknown table '{args.table}' (known: {', '.join(TABLES)})")
        for command in TABLES[args.table].commands:
            print(f"$ {command}", flush=True)
            subprocess.run(command, shell=True, check=True, cwd=ROOT)
    if args.table or args.render:
        for f in FILES:
            f.write_text(render(f.read_text()))
        print(f"rendered: {', '.join(str(f.relative_to(ROOT)) for f in FILES)}")
        return 0
    ap.print_help()
    return 2


if __name__ == "__main__":
    sys.exit(main())
