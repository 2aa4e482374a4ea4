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
