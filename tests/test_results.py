"""docs/results.md and README.md show what their JSON holds: every marked table is its JSON's
rendering (`experiments/reproduce.py`), docs/results.md stays a page of current results, and every
results file it names exists."""

import importlib.util
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]


@pytest.fixture(scope="module")
def reproduce():
    spec = importlib.util.spec_from_file_location("reproduce", ROOT / "experiments" / "reproduce.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve the module's annotations through sys.modules
    spec.loader.exec_module(module)
    return module


def test_every_marked_table_is_its_json_rendered(reproduce):
    marked = {m["name"] for f in reproduce.FILES for m in reproduce.MARKER.finditer(f.read_text())}
    assert marked == set(reproduce.TABLES), "every table appears in README.md or docs/results.md, and only known ones"
    readme = {m["name"] for m in reproduce.MARKER.finditer((ROOT / "README.md").read_text())}
    results = {m["name"] for m in reproduce.MARKER.finditer((ROOT / "docs" / "results.md").read_text())}
    assert readme <= results, "each README table has its section in docs/results.md"
    for table in reproduce.TABLES.values():
        assert table.json.exists(), table.json
        assert table.commands and all(c.strip() for c in table.commands)
    assert reproduce.stale() == [], "run python experiments/reproduce.py --render"


def test_rendering_replaces_a_stale_table(reproduce):
    text = "before\n<!-- reproduce:arms -->\n| stale |\n<!-- /reproduce -->\nafter\n"
    out = reproduce.render(text)
    assert "| stale |" not in out and "| Panda |" in out and out.startswith("before\n") and out.endswith("after\n")
    with pytest.raises(SystemExit, match="unknown table 'nope'"):
        reproduce.render("<!-- reproduce:nope -->\n<!-- /reproduce -->")


def test_results_page_is_current_and_names_existing_files():
    text = (ROOT / "docs" / "results.md").read_text()
    assert len(text.splitlines()) <= 400
    assert not re.search(r"\b(stop|session) \d+", text, re.I)
    missing = []
    for ref in sorted(set(re.findall(r"docs/results/[\w./*{},-]+", text))):
        ref = ref.rstrip(".,)")
        options = re.sub(r"\{([^}]*)\}", lambda m: "(" + "|".join(m[1].split(",")) + ")", ref)
        pattern = re.compile(options.replace(".", r"\.").replace("*", ".*").replace("(", "(?:") + r"(?:[./].*)?")  # `--out` prefixes too
        if not any(pattern.fullmatch(str(p.relative_to(ROOT))) for p in (ROOT / "docs" / "results").rglob("*")) and not (ROOT / ref).exists():
            missing.append(ref)
    assert not missing, f"named in docs/results.md but not in the tree: {missing}"


def test_table_4_1_merge_adds_a_run_and_keeps_the_others(tmp_path):
    """`table_4_1.py RUN --merge` adds RUN's methods to an existing table (one new run need not
    rerun the others) and replaces a method of the same name."""
    import json

    spec = importlib.util.spec_from_file_location("table_4_1", ROOT / "experiments" / "table_4_1.py")
    t41 = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(t41)

    def run(name: str, method: str, successes: list[bool]) -> Path:
        rows = [
            {"method": method, "valid_problem": True, "success": ok, "success_pose": ok, "collision": False, "class": "cubby",
             "problem_type": "task_oriented", "plan_time_s": 0.5, "info": {}}
            for ok in successes
        ]  # fmt: skip
        d = tmp_path / name
        d.mkdir()
        (d / "results.json").write_text(json.dumps({"meta": {"config": {"method": {"type": "gfcs", "name": method}}}, "rows": rows}))
        return d

    out = tmp_path / "table"
    t41.main([str(run("a", "gfcs", [True, False])), "--out", str(out)])
    t41.main([str(run("b", "gfcs_pose", [True, True, True, False])), "--out", str(out), "--merge"])
    result = json.loads(out.with_suffix(".json").read_text())
    assert set(result["methods"]) == {"gfcs", "gfcs_pose"} and len(result["runs"]) == 2
    assert result["methods"]["gfcs"]["all"]["success_pct"] == 50.0 and result["methods"]["gfcs_pose"]["all"]["success_pct"] == 75.0
    t41.main([str(run("c", "gfcs", [True])), "--out", str(out), "--merge"])
    assert json.loads(out.with_suffix(".json").read_text())["methods"]["gfcs"]["all"]["success_pct"] == 100.0


def test_trapped_counts_what_the_guide_gains_and_loses(tmp_path):
    """experiments/trapped.py: problems the fabric ends without goal and collision (trapped), and
    what the guide does on them and on the ones the fabric reaches."""
    spec = importlib.util.spec_from_file_location("trapped", ROOT / "experiments" / "trapped.py")
    trapped = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(trapped)

    def row(name, kind, success, collision):
        return {"problem": name, "problem_type": kind, "success": success, "collision": collision, "valid_problem": True}

    fabric = {r["problem"]: r for r in [row("a", "task_oriented", False, False), row("b", "task_oriented", False, False),
                                         row("c", "task_oriented", True, False), row("d", "neutral_goal", False, True)]}  # fmt: skip
    guide = {r["problem"]: r for r in [row("a", "task_oriented", True, False), row("b", "task_oriented", False, True),
                                        row("c", "task_oriented", False, False), row("d", "neutral_goal", True, False)]}  # fmt: skip
    got = trapped.compare(fabric, guide)
    assert got["task_oriented"] == {
        "n": 3, "fabric_trapped": 2, "fabric_reached": 1, "guide_reached_trapped": 1, "guide_collided_trapped": 1, "guide_lost_reached": 1,
    }  # fmt: skip
    assert got["neutral_goal"]["fabric_trapped"] == 0 and got["all"]["n"] == 4  # a collision is not a trap
    with pytest.raises(SystemExit, match="lacks 1"):
        trapped.compare(fabric, {k: v for k, v in guide.items() if k != "d"})
