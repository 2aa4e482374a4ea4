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


def _modules(package: str) -> list[Path]:
    return sorted(PACKAGE.joinpath(*package.split(".")[1:]).rglob("*.py"))


def _bad(package: str, forbidden: tuple[str, ...], allowed: tuple[str, ...] = ()) -> list[str]:
    return [
        f"{f.relative_to(PACKAGE)} imports {n}"
        for f in _modules(package)
        if str(f.relative_to(PACKAGE)) not in allowed
        for n in sorted(imports(f))
        if any(under(n, p) for p in forbidden)
    ]


def test_viewer_never_imports_the_bench_cli():
    """The viewer rebuilds a run's problems through `fabrax.problems.load`, not the bench's CLI."""
    assert not (bad := _bad("fabrax.viz", ("fabrax.bench.cli",))), "; ".join(bad)


def test_floors_below_the_pillars_never_import_upward():
    """problems/ and check/ sit below the pillars and never import the fabric (a robot-limit formula
    lives in fabrax.robot.limits); robot/ and scene/ sit below fabrics/; nothing below the pillars
    imports a pillar, the bench, the viewer or the CLI."""
    above = PILLARS + ABOVE
    rules = {
        "fabrax.problems": ("fabrax.fabrics", "fabrax.rollout", *above),
        "fabrax.check": ("fabrax.fabrics", "fabrax.rollout", "fabrax.problems", *above),
        "fabrax.robot": ("fabrax.fabrics", "fabrax.rollout", "fabrax.problems", "fabrax.check", *above),
        "fabrax.scene": ("fabrax.fabrics", "fabrax.rollout", "fabrax.problems", "fabrax.check", "fabrax.robot", *above),
        "fabrax.fabrics": ("fabrax.rollout", "fabrax.problems", "fabrax.check", *above),
        "fabrax.rollout": ("fabrax.problems", "fabrax.check", *above),
    }
    bad = [b for package, forbidden in rules.items() for b in _bad(package, forbidden)]
    assert not bad, "; ".join(bad)


def test_the_library_never_reads_yaml():
    """Only the CLI, the bench's command line and run collection, experiments, the viewer and
    notebooks read YAML configs; problems/mbm.py parses MotionBenchMaker's MoveIt files, which are
    data in YAML, and fabrax/config.py is the one place that turns presets into mappings."""
    parsers = ("yaml", "omegaconf", "hydra")
    library = ("fabrax.fabrics", "fabrax.robot", "fabrax.scene", "fabrax.rollout", "fabrax.check", "fabrax.problems", *PILLARS)
    bad = [b for package in library for b in _bad(package, parsers, allowed=("problems/mbm.py",))]
    assert not bad, "; ".join(bad)


def test_the_library_takes_objects_not_preset_names():
    """Presets are resolved above the library: the floors and the pillars never import
    `fabrax.config` (the preset reader); they take robots, fabrics and settings objects or mappings."""
    library = ("fabrax.fabrics", "fabrax.robot", "fabrax.scene", "fabrax.rollout", "fabrax.check", "fabrax.problems", *PILLARS)
    bad = [b for package in library for b in _bad(package, ("fabrax.config",))]
    assert not bad, "; ".join(bad)
