"""Sweeps: a hydra multirun of experiments/bench.py over a fabric gain, collected into one table;
the launcher presets compose."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_multirun_sweep_is_collected(tmp_path, shared_data):
    sweep = tmp_path / "sweep"
    cmd = [sys.executable, str(ROOT / "experiments" / "bench.py"), "-m", "method=gf", "problems=mbm", "classes=[cage]", "limit=1"]
    cmd += ["fabric.terms.goal.k_force=3.0,4.2", "progress=false", f"hydra.sweep.dir={sweep}"]
    subprocess.run(cmd, check=True, cwd=tmp_path, capture_output=True, text=True)
    for job in ("0", "1"):
        assert (sweep / job / "results.json").exists() and (sweep / job / ".hydra" / "config.yaml").exists()
        meta = json.loads((sweep / job / "results.json").read_text())["meta"]
        assert meta["seed"] == 0 and meta["versions"]["jax"]
    k = [json.loads((sweep / j / "results.json").read_text())["meta"]["config"]["fabric"]["terms"]["goal"]["k_force"] for j in "01"]
    assert k == [3.0, 4.2]  # the override reached the fabric
    from fabrax.bench.collect import collect, main

    rows = collect([sweep])
    assert [r["overrides"] for r in rows] == ["fabric.terms.goal.k_force=3.0", "fabric.terms.goal.k_force=4.2"]
    assert all(r["n"] == 1 and r["class"] == "cage" for r in rows)
    assert main([str(sweep), "--out", str(tmp_path / "table")]) == 0
    assert "k_force=4.2" in (tmp_path / "table.md").read_text()
    with pytest.raises(SystemExit, match="no such directory"):
        main([str(tmp_path / "missing")])


@pytest.mark.parametrize("launcher, target", [("fabrax_joblib", "JoblibLauncher"), ("fabrax_slurm", "SlurmLauncher")])
def test_launcher_presets_compose(launcher, target):
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher", reason="needs the sweep extra (hydra launchers)")
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher", reason="needs the sweep extra (hydra launchers)")
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base=None):
        cfg = compose("bench", overrides=[f"hydra/launcher={launcher}"], return_hydra_config=True)
    assert cfg.hydra.launcher._target_.endswith(target)


def test_unknown_key_fails_with_hydras_error():
    from fabrax.bench.cli import compose

    with pytest.raises(SystemExit, match="nonexistent_key"):
        compose(["nonexistent_key=1"])


def test_skills_config_composes_and_rejects_unknown_keys():
    from hydra import compose, initialize_config_dir
    from hydra.errors import ConfigCompositionException

    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base=None):
        cfg = compose("skills", overrides=["demo=joint", "vae.latent=4", "obstacle.point=5"])
        assert cfg.vae.latent == 4 and cfg.obstacle.point == 5
        with pytest.raises(ConfigCompositionException, match="nonexistent_key"):
            compose("skills", overrides=["vae.nonexistent_key=1"])


@pytest.mark.parametrize("app", ["bench", "gfcs", "skills"])
def test_robot_and_fabric_are_groups_with_field_overrides(app, tmp_path, monkeypatch):
    """robot=NAME and fabric=NAME select configs/robot and configs/fabric in every app; their fields
    override like any other key; data_dir reaches the robot's $FABRAX_DATA sphere file."""
    from hydra import compose, initialize_config_dir

    from fabrax import config

    monkeypatch.setenv("FABRAX_DATA", "unset")
    monkeypatch.delenv("FABRAX_DATA")
    overrides = ["robot=panda_mbm", "robot.spheres.set=other", "fabric=panda", "fabric.terms.goal.k_force=2.5"]
    overrides += [] if app == "skills" else [f"data_dir={tmp_path}"]
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base=None):
        cfg = config.resolve(compose(app, overrides=overrides))
    assert cfg["robot"]["held"] == {"panda_finger_joint1": 0.065} and cfg["robot"]["spheres"]["set"] == "other"
    assert cfg["fabric"]["terms"]["goal"]["k_force"] == 2.5
    if app != "skills":
        assert cfg["robot"]["spheres"]["file"] == f"{tmp_path}/panda_spheres.json"
        with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base=None):
            default = config.resolve(compose(app, overrides=["problems=mbm"]))
        assert config.robot_choice(default) == "panda_mbm"
