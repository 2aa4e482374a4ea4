"""The installed package carries everything its entry points read: every subpackage, configs/ and the pretrained guide."""

import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_every_subpackage_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "fabrax").rglob("__init__.py")}
    assert found <= listed, f"add to [tool.setuptools] packages: {sorted(found - listed)}"


@pytest.mark.slow
def test_the_wheel_carries_the_configs_and_finds_them(tmp_path):
    """A non-editable install has no checkout beside it: `config.load_robot("panda")` (README's
    snippet) must read the configs the wheel ships."""
    out = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path / "w"), str(ROOT)], capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr[-2000:]
    (wheel,) = (tmp_path / "w").glob("fabrax-*.whl")
    shipped = {n for n in zipfile.ZipFile(wheel).namelist() if n.startswith("fabrax/configs/")}
    ours = {"fabrax/configs/" + str(p.relative_to(ROOT / "configs")) for p in (ROOT / "configs").rglob("*.yaml")}
    assert ours <= shipped, sorted(ours - shipped)
    guide = {"fabrax/rl/" + str(p.relative_to(ROOT / "fabrax/rl")) for p in (ROOT / "fabrax/rl/pretrained").rglob("*") if p.is_file()}
    assert guide and guide <= set(zipfile.ZipFile(wheel).namelist()), sorted(guide - set(zipfile.ZipFile(wheel).namelist()))  # the pretrained guide
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = "from fabrax import config; print(config.config_dir()); print(config.load('robot', 'panda')['name'])"
    env = {"PYTHONPATH": str(site), "PATH": ""}  # the wheel's fabrax, not the checkout's
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    where, name = run.stdout.split()
    assert Path(where) == site / "fabrax" / "configs" and name == "panda"
