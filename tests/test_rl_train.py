"""Training the RL guide: the training wrappers, a few hundred PPO steps that change the
networks, checkpoint -> resume, settings checks, and the benchmark method on a checkpoint."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from fabrax import config
from fabrax.rl.train import normalise, train

PANDA = {"robot": config.load("robot", "panda"), "fabric": config.load("fabric", "panda")}

TINY = {  # configs/rl/tiny.yaml's values: seconds of training
    **PANDA,
    "env": {
        "substeps": 4,
        "episode_s": 2.0,
        "scenes": {"generated": {"cuboid_forest": 2, "shelves": 0, "flying_cuboids": 0}, "configs_per_scene": 4},
    },
    "eval_scenes": {"seed": 1, "procedural_seed": 20000},
    "network": {"variant": "mlp", "hidden": [32, 32]},
    "curriculum": {"cells": 3},
    "ppo": {
        "num_timesteps": 256,
        "num_envs": 8,
        "unroll_length": 4,
        "batch_size": 8,
        "num_minibatches": 4,
        "num_updates_per_batch": 1,
        "num_evals": 2,
        "num_eval_envs": 8,
    },
}


def test_the_tiny_preset_is_the_tests_settings():
    """experiments/rl.py rl=tiny composes to these settings (the resume test below relies on it)."""
    from hydra import compose, initialize_config_dir

    from fabrax import config

    with initialize_config_dir(config_dir=str(config.config_dir()), version_base=None):
        cfg = config.resolve(compose("rl", overrides=["rl=tiny"]))
    app = normalise({k: cfg[k] for k in ("robot", "fabric", "env", "eval_scenes", "network", "curriculum", "ppo")})
    assert app == normalise(TINY)


@pytest.mark.parametrize("preset", sorted(p.stem for p in (Path(__file__).parents[1] / "configs" / "rl").glob("*.yaml")))
def test_every_preset_composes_to_valid_settings(preset):
    """Each configs/rl preset passes the settings checks that run before any environment is built."""
    from hydra import compose, initialize_config_dir

    from fabrax import config

    with initialize_config_dir(config_dir=str(config.config_dir()), version_base=None):
        cfg = config.resolve(compose("rl", overrides=[f"rl={preset}"]))
    normalise({k: cfg[k] for k in ("robot", "fabric", "env", "eval_scenes", "network", "curriculum", "ppo")})


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A tiny training run: (run directory, initial parameters, trained parameters)."""
    from fabrax.compat import brax_ppo
    from fabrax.rl.env import make_env
    from fabrax.rl.networks import make_guide_networks
    from fabrax.rl.wrappers import wrap_for_training

    ppo = brax_ppo()
    run_dir = tmp_path_factory.mktemp("rl") / "run"
    env = make_env(TINY["env"], **PANDA)
    factory = lambda *a, **k: make_guide_networks(*a, **k, variant="mlp", hidden=(32, 32))  # noqa: E731
    # brax's own initialisation with the same seed and networks: the parameters before any update
    _, init, _ = ppo.train(
        env, num_timesteps=0, episode_length=env.cfg.episode_steps, wrap_env_fn=wrap_for_training, network_factory=factory, num_envs=8
    )
    _, params, _ = train(TINY, run_dir)
    return run_dir, init, params


def _leaves(p):
    return [np.asarray(x) for x in jax.tree.leaves(p)]


def test_ppo_steps_change_the_networks_and_write_the_run(run):
    run_dir, init, params = run
    changed = [not np.allclose(a, b) for a, b in zip(_leaves(init[1]), _leaves(params[1]))]
    assert sum(changed) >= len(changed) // 2  # most policy tensors moved
    rows = [json.loads(line) for line in (run_dir / "progress.jsonl").read_text().splitlines()]
    evals = [r for r in rows if "eval" in r]
    assert len(evals) >= 2 and all(0.0 <= r["eval"]["success"] <= 1.0 for r in evals)
    assert all(r["eval"]["stage_per_step"] == 2.0 for r in evals)  # evaluation runs the task
    # PPO's approximate KL between the policy that collected a batch and the updated one stays small:
    # with brax's unclipped normaliser the stage-1-constant switch observation blew it up by orders of
    # magnitude, and with the normaliser moved before the update (brax's NONE schedule) the first
    # updates read ~15 (docs/results.md, "PPO's KL")
    kl = [r["train"]["kl_mean"] for r in rows if "train" in r and "kl_mean" in r["train"]]
    assert kl and max(kl) < 2.0, kl
    trained = [r for r in rows if "train" in r and "unique_cells" in r["train"]]
    assert trained and all(0 < r["train"]["unique_cells"] <= 8000 for r in trained)  # final counts, not sums over steps
    assert (run_dir / "curves.png").stat().st_size > 0
    assert json.loads((run_dir / "settings.json").read_text()) == normalise(TINY)


def test_checkpoint_holds_the_trained_parameters_and_resume_continues(run, tmp_path):
    from fabrax.rl.policy import load_guide
    from fabrax.rl.train import latest_checkpoint

    run_dir, _, params = run
    guide = load_guide(run_dir)
    assert guide.steps == int(latest_checkpoint(run_dir).name) >= 256
    for a, b in zip(_leaves(guide.params), _leaves(params)):
        np.testing.assert_array_equal(a, b)

    resumed = tmp_path / "resumed"
    shutil.copytree(run_dir, resumed)
    more = {**TINY, "ppo": {**TINY["ppo"], "num_timesteps": 512}}
    with pytest.raises(ValueError, match="already holds a run"):
        train(more, resumed)
    with pytest.raises(ValueError, match="other settings .*network.hidden"):
        train({**more, "network": {"variant": "mlp", "hidden": [64]}}, resumed, resume=True)
    # resume through the hydra app, on two host devices: brax's pmap splits the envs between them
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    cmd = [sys.executable, "experiments/rl.py", "rl=tiny", "resume=true", "ppo.num_timesteps=512", f"hydra.run.dir={resumed}"]
    done = subprocess.run(cmd, cwd=Path(__file__).parents[1], env=env, capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0, done.stderr[-2000:]
    console = done.stdout + done.stderr
    assert " eval: success" in console and "kl_mean" in console and " train: " not in console  # one line per evaluation
    steps = sorted(int(p.name) for p in (resumed / "checkpoints").iterdir())
    assert steps[-1] >= 512 and steps[-1] > guide.steps
    rows = [json.loads(line) for line in (resumed / "progress.jsonl").read_text().splitlines()]
    assert max(r["step"] for r in rows) == steps[-1]
    evals = [r["step"] for r in rows if "eval" in r]
    assert len(evals) == len(set(evals)) and guide.steps in evals  # the resume step is evaluated once
    walls = [r["wall_s"] for r in rows]
    assert walls == sorted(walls)  # wall time goes on from the stopped run's
    new = load_guide(resumed).params
    assert any(not np.allclose(a, b) for a, b in zip(_leaves(new[1]), _leaves(params[1])))
    assert {r["devices"] for r in rows if r["step"] > guide.steps} == {2}


def test_ship_guide_packs_a_checkpoint_that_loads(run, tmp_path):
    """experiments/ship_guide.py (how the pretrained guide is made) copies one checkpoint, the
    settings and trained.json; the copy loads with the trained parameters."""
    from fabrax.rl.policy import load_guide

    run_dir, _, params = run
    into = tmp_path / "shipped"
    cmd = [sys.executable, "experiments/ship_guide.py", str(run_dir), "--into", str(into), "--note", "tiny"]
    done = subprocess.run(cmd, cwd=Path(__file__).parents[1], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    guide = load_guide(into)
    for a, b in zip(_leaves(guide.params), _leaves(params)):
        np.testing.assert_array_equal(a, b)
    trained = json.loads((into / "trained.json").read_text())
    assert trained["steps"] == guide.steps and trained["note"] == "tiny" and trained["wall_s"] > 0
    assert len(list((into / "checkpoints").iterdir())) == 1
    bad = subprocess.run(
        [*cmd[:3], "--step", "7", "--into", str(tmp_path / "x")], cwd=Path(__file__).parents[1], capture_output=True, text=True, timeout=300
    )
    assert bad.returncode == 2 and "no checkpoint 7" in bad.stderr


def test_bench_method_runs_a_checkpoint_and_refuses_bad_ones(run, panda, tmp_path):
    from fabrax.bench.methods.rl_guide import build as rl_guide_method
    from fabrax.bench.runner import run as bench_run
    from fabrax.config import load
    from fabrax.problems.generators import demo_problem

    run_dir, _, _ = run
    cfg = {"fabric": load("fabric", "panda"), "frame": "panda_hand"}
    method = rl_guide_method({"name": "rl_guide", "checkpoint": str(run_dir), "scripted": None}, cfg, panda)
    problem = demo_problem(panda)
    rows = bench_run(method, panda, [problem, problem])
    assert len(rows) == 2 and rows[0]["criterion"] == "keypoints"
    assert rows[0]["path"].shape[1] == panda.dof and rows[0]["path"].shape[0] > 1
    np.testing.assert_allclose(rows[0]["path"][0], problem.start_q, atol=1e-6)
    sol = method.solve(panda, [problem, problem])[0]  # the compiled batch of two again
    assert sol.dt == pytest.approx(1 / 60) and sol.info["reaction_ms"] > 0
    assert len(sol.q) == 1 + sol.info["policy_steps"] * method.env.cfg.substeps

    assert method.env.cfg.episode_s == 20.0 != TINY["env"]["episode_s"]  # the thesis' evaluation, not the training episodes
    robot = load("robot", "panda")
    other = {**cfg, "robot": {**robot, "spheres": {**robot["spheres"], "budget": 40}}}
    with pytest.raises(ValueError, match=r"trained with other robot settings \(spheres.budget\)"):
        rl_guide_method({"name": "rl_guide", "checkpoint": str(run_dir), "scripted": None}, other, panda)
    with pytest.raises(ValueError, match="method.episode_s must be a positive number"):
        rl_guide_method({"name": "rl_guide", "checkpoint": str(run_dir), "scripted": None, "episode_s": 0}, cfg, panda)
    with pytest.raises(ValueError, match="does not exist"):
        rl_guide_method({"name": "rl_guide", "checkpoint": str(tmp_path / "nothing"), "scripted": None}, cfg, panda)
    broken = tmp_path / "broken"
    shutil.copytree(run_dir, broken)
    for f in (broken / "checkpoints").rglob("manifest.ocdbt"):
        f.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="unreadable guide checkpoint"):
        rl_guide_method({"name": "rl_guide", "checkpoint": str(broken), "scripted": None}, cfg, panda)


def test_resampling_reset_and_episode_sums():
    """Finished envs start new episodes (brax's AutoResetWrapper would replay the first) in the
    curriculum stage reached; the episode sums of the increments are the cumulative values."""
    from fabrax.rl.env import make_env
    from fabrax.rl.wrappers import wrap_for_training

    env = make_env({**TINY["env"], "episode_s": 0.4}, **PANDA)  # 6 policy steps per episode
    wrapped = wrap_for_training(env, env.cfg.episode_steps, cells=1.0)
    state = jax.jit(wrapped.reset)(jax.random.split(jax.random.PRNGKey(0), 4))
    assert np.all(np.asarray(state.info["stage"]) == 1)

    @jax.jit
    def unroll(state):
        def body(s, k):
            a = jax.random.uniform(k, (4, env.action_size), minval=-1, maxval=1)
            n = wrapped.step(s, a)
            return n, (n.done, n.info["episode_metrics"]["unique_cells"], n.info["last_cells"], n.pipeline_state.goal_pos, n.info["stage"])

        return jax.lax.scan(body, state, jax.random.split(jax.random.PRNGKey(1), 14))[1]

    done, sums, last, goal, stage = (np.asarray(x) for x in unroll(state))
    first_goal = np.asarray(state.pipeline_state.goal_pos)
    assert done[5].all()  # the time limit ends every env's first episode at its 6th step
    first_end = np.argmax(done, axis=0)
    for e in range(4):  # within the first episode the summed increments are the cumulative count
        np.testing.assert_allclose(sums[: first_end[e], e], last[: first_end[e], e])
    assert not np.allclose(goal[6], first_goal)  # new episodes, not the first one again
    assert np.all(stage[6:] == 2)  # finished episodes visited >= 1 cell: the curriculum moved on


def test_viewer_plays_the_trained_guide_on_a_held_out_scene(run, free_port):
    from fabrax.viz.app import Viewer
    from fabrax.viz.rl_view import rl_view

    viewer = Viewer("panda", port=free_port)
    try:
        info = rl_view(viewer, checkpoint=run[0])
    finally:
        viewer.close()
    assert info["policy"] == "guide" and info["scene"].startswith("cuboid_forest/")
    assert info["fabric_steps"] == 1 + 4 * info["steps"]  # the run's 4 substeps per policy step


def test_training_keeps_brax_metric_dumps_off_the_console(run):
    """brax dumps ~20 lines of metrics per iteration through the root logger; fabrax's own lines and
    progress.jsonl carry them, so the dumps are filtered while training, and only then."""
    import logging

    from fabrax.rl.train import _not_brax_metrics

    assert _not_brax_metrics not in logging.getLogger().filters
    dump = logging.LogRecord("root", logging.INFO, "/env/site-packages/brax/training/logger.py", 85, "Steps Env: 128", None, None)
    ours = logging.LogRecord("fabrax.rl", logging.INFO, "/src/fabrax/rl/train.py", 240, "step 128 train", None, None)
    assert not _not_brax_metrics(dump) and _not_brax_metrics(ours)


def test_spread_script_reads_the_action_distribution_of_checkpoints(run, tmp_path):
    """experiments/rl_spread.py on the tiny run: scales per dimension, and zero KL from a checkpoint to itself."""
    import importlib.util

    from fabrax.rl.train import latest_checkpoint

    run_dir, _, _ = run
    step = int(latest_checkpoint(run_dir).name)
    spec = importlib.util.spec_from_file_location("rl_spread", Path(__file__).resolve().parents[1] / "experiments" / "rl_spread.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    out = tmp_path / "spread"
    assert script.main([str(run_dir), str(step), str(step), "--out", str(out), "--envs", "4", "--steps-per-env", "2"]) == 0
    result = json.loads(out.with_suffix(".json").read_text())
    assert result["states"] == 8 and result["std"] == "global"
    (row, _), (pair,) = result["checkpoints"], result["kl"]
    assert len(row["scale_min"]) == 6 + 7 + 1 and all(0.001 <= s <= m for s, m in zip(row["scale_min"], row["scale_median"]))
    assert abs(pair["max"]) < 1e-3  # KL of a distribution with itself (brax adds 1e-5 inside its log)


def test_a_guide_from_before_the_network_options_loads_as_it_was_trained(run, tmp_path):
    """A run recorded before `network.std` and `network.loc_bound` (neither in its settings nor in its
    checkpoint's network config) had a scale output per state and an unbounded mean
    (`fabrax.rl.networks.LEGACY`): it loads and acts as that network."""
    import functools

    from brax.training.agents.ppo import checkpoint as ppo_checkpoint

    from fabrax.rl.networks import make_guide_networks
    from fabrax.rl.policy import load_guide

    run_dir, _, params = run
    new = load_guide(run_dir)
    cfg = ppo_checkpoint.load_config(new.checkpoint)
    kwargs = {k: v for k, v in cfg.network_factory_kwargs.items() if k not in ("std", "loc_bound")}
    factory = functools.partial(make_guide_networks, **kwargs)
    sizes = {k: tuple(v) for k, v in cfg.observation_size.items()}
    legacy = make_guide_networks(sizes, cfg.action_size, **kwargs, std="state", loc_bound=None)
    policy = legacy.policy_network.init(jax.random.PRNGKey(1))
    old = tmp_path / "old"
    settings = json.loads((run_dir / "settings.json").read_text())
    settings["network"] = {k: v for k, v in settings["network"].items() if k not in ("std", "loc_bound")}
    old.mkdir()
    (old / "settings.json").write_text(json.dumps(settings))
    saved = ppo_checkpoint.network_config(sizes, cfg.action_size, cfg.normalize_observations, factory)
    ppo_checkpoint.save(old / "checkpoints", new.steps, (params[0], policy, params[2]), saved)
    (written,) = (old / "checkpoints").glob("*/ppo_network_config.json")
    network_config = json.loads(written.read_text())  # as older brax checkpoints of the guide recorded it
    network_config["network_factory_kwargs"] = kwargs
    written.write_text(json.dumps(network_config))

    guide = load_guide(old)
    assert guide.settings["network"]["std"] == "state" and guide.settings["network"]["loc_bound"] is None
    last = jax.tree.leaves(guide.params[1])
    assert 2 * cfg.action_size in {x.shape[-1] for x in last}  # a loc and a scale per action dimension and state
    obs = {k.removeprefix("pixels/"): np.zeros(s, np.float32) for k, s in sizes.items()}  # the env's names
    action = np.asarray(guide.act(obs))
    assert action.shape == (cfg.action_size,) and np.isfinite(action).all()
