"""The guide that ships with fabrax: `pretrained` loads from the package, was trained on no MπNets
family (thesis §4.1: the evaluation scenes are outside the training distribution), records how it
was trained, and runs in the bench with the shipped Panda settings."""

import json

import numpy as np
import pytest

from fabrax.problems.procedural import MPINETS_LIKE
from fabrax.rl.networks import DEFAULTS
from fabrax.rl.policy import PRETRAINED, load_guide, pretrained_dir


@pytest.fixture(scope="module")
def guide():
    return load_guide(PRETRAINED)


def test_the_shipped_guide_loads_and_says_how_it_was_trained(guide):
    assert guide.checkpoint.parent.parent == pretrained_dir()
    assert guide.steps > 0
    trained = json.loads((pretrained_dir() / "trained.json").read_text())
    assert trained["command"].startswith("python experiments/rl.py") and trained["steps"] == guide.steps
    assert trained["wall_s"] > 0 and trained["hardware"]
    scenes = guide.settings["env"]["scenes"]
    assert scenes["mpinets"] == 0 and not {c for c, n in scenes["procedural"] if n} & set(MPINETS_LIKE)
    assert scenes["mbm_classes"] and sum(n for _, n in scenes["generated"]) > 0  # dataset and procedural scenes
    # trained with today's action distribution: one learned scale per action dimension, a bounded mean
    saved = json.loads((pretrained_dir() / "settings.json").read_text())["network"]
    assert {k: saved[k] for k in ("std", "loc_bound")} == {k: DEFAULTS[k] for k in ("std", "loc_bound")}


def test_the_shipped_guide_acts_in_the_bench(guide, panda):
    from fabrax.bench.methods.rl_guide import build
    from fabrax.config import load
    from fabrax.problems.generators import demo_problem

    cfg = {"fabric": load("fabric", "panda"), "frame": "panda_hand"}  # the shipped robot settings: no refusal
    method = build({"name": "rl_guide", "checkpoint": PRETRAINED, "scripted": None, "batch_size": 1}, cfg, panda)
    problem = demo_problem(panda)
    (sol,) = method.solve(panda, [problem])
    assert np.isfinite(sol.q).all() and sol.q.shape[1] == panda.dof and sol.q.shape[0] > 1
    np.testing.assert_allclose(sol.q[0], problem.start_q, atol=1e-6)
    assert sol.info["policy_steps"] >= 1


def test_a_missing_checkpoint_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match="no guide checkpoint at .*nowhere"):
        load_guide(tmp_path / "nowhere")


def test_the_viewer_builds_a_few_of_the_guides_held_out_scenes(guide):
    from fabrax.rl.config import env_config
    from fabrax.rl.train import eval_settings
    from fabrax.viz.rl_view import few_scenes

    full = eval_settings(guide.settings["env"], guide.settings["eval_scenes"])
    few = env_config(few_scenes(full, 4)).scenes
    assert few.mpinets == min(4, full["scenes"]["mpinets"]) and (not few.mbm_classes or few.mbm_limit <= 4)
    assert all(n <= 4 for _, n in few.generated + few.procedural)


def test_reaction_benchmark_times_every_piece(tmp_path):
    """experiments/bench_reaction.py: each piece of the guide's reaction timed on new scenes, written as JSON."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "experiments" / "bench_reaction.py"
    spec = importlib.util.spec_from_file_location("bench_reaction", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.main(["--out", str(tmp_path / "r"), "--calls", "3", "--scenes", "1"]) == 0
    rows = json.loads((tmp_path / "r.json").read_text())["rows"]
    assert set(rows) == {"static BPS", "observation", "policy", "targets + fabric step", "reaction", "pure fabric"}
    assert all(r["mean_ms"] > 0 and r["std_ms"] >= 0 for r in rows.values())
    with pytest.raises(SystemExit, match="--calls"):
        script.main(["--out", str(tmp_path / "r"), "--calls", "0"])
