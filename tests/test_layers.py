"""Arrows point down: no pillar imports another pillar, the benchmark harness or the viewer."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).parents[1] / "fabrax"
PILLARS = ("fabrax.planners", "fabrax.rl", "fabrax.skills")  # GFCS, the RL guide, motion skills
ABOVE = ("fabrax.bench", "fabrax.viz", "fabrax.cli")  # what uses the pillars


def imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


@pytest.mark.parametrize("pillar", PILLARS)
def test_pillars_import_only_the_floors_below(pillar):
    root = PACKAGE.joinpath(*pillar.split(".")[1:])
    if not root.exists():
        pytest.skip(f"{pillar} does not exist yet")
    forbidden = [p for p in PILLARS + ABOVE if p != pillar]
    files = sorted(root.rglob("*.py"))
    bad = [f"{f.relative_to(PACKAGE)} imports {n}" for f in files for n in sorted(imports(f)) if any(under(n, p) for p in forbidden)]
    assert not bad, "; ".join(bad)
