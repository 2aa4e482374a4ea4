"""GFCS: the command-sequence cost and the CMA-ES solver (gfcs_paper eqs. 4-8, Algorithm 1)."""

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fabrax import config
from fabrax.planners.gfcs import GFCSConfig, sequence_cost, solve, to_commands, to_unconstrained, uniform_sampler
from fabrax.problems import Problem, ProblemBatch
from fabrax.robot import frame_pose
from fabrax.scene import from_dict

READY = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785], np.float32)


@pytest.fixture(scope="module")
def fabric_params(panda):
    return config.load_fabric(panda, "panda")


def _problem(goal, obstacles=()):
    scene = from_dict({"obstacles": list(obstacles)}, {"cuboids": 2})
    return ProblemBatch.of(Problem(np.asarray(READY), scene, goal_q=np.asarray(goal, np.float32)), scene.capacity)


def test_commands_stay_inside_limits_and_round_trip(panda):
    z = jnp.asarray(np.random.default_rng(0).normal(0, 20, (100, 2, 7)), jnp.float32)
    q = to_commands(z, panda.lower, panda.upper)
    assert bool(jnp.all((q >= panda.lower) & (q <= panda.upper)))
    q0 = jnp.asarray(READY)
    assert np.allclose(to_commands(to_unconstrained(q0, panda.lower, panda.upper), panda.lower, panda.upper), q0, atol=1e-5)
    samples = uniform_sampler(jax.random.PRNGKey(0), panda, 512, 1)
    u = (to_commands(samples, panda.lower, panda.upper) - panda.lower) / (panda.upper - panda.lower)
    assert abs(float(u.mean()) - 0.5) < 0.02 and float(u.std()) == pytest.approx(np.sqrt(1 / 12), abs=0.02)


def test_cost_of_a_reaching_sequence_is_lower(fabric_params, panda):
    fabric, params = fabric_params
    goal = READY + np.array([0.5, 0.2, 0, 0.2, 0, 0, 0], np.float32)
    problem = _problem(goal)
    z_good = to_unconstrained(jnp.asarray((READY + goal) / 2)[None], panda.lower, panda.upper)  # a command on the way
    z_far = to_unconstrained(jnp.asarray(panda.lower + 0.02 * (panda.upper - panda.lower))[None], panda.lower, panda.upper)
    kw = dict(steps=150)  # 1.5 s per command: the far command cannot be reached and eats the budget
    cost_good, tr_good = jax.jit(lambda z: sequence_cost(fabric, params, problem, z, **kw))(z_good)
    cost_far, tr_far = jax.jit(lambda z: sequence_cost(fabric, params, problem, z, **kw))(z_far)
    assert bool(tr_good.reached) and float(cost_good) == pytest.approx(float(jnp.sum(tr_good.segment_times)))
    assert float(cost_far) > float(cost_good)
    assert float(cost_good) < 2 * 1.5  # within the two segments' budgets, no penalty
    # the length term adds the hand's path length, as the benchmark's EE-length metric measures it
    cost_len, _ = jax.jit(lambda z: sequence_cost(fabric, params, problem, z, length_weight=2.0, **kw))(z_good)
    q = np.asarray(tr_good.q)[: int(tr_good.length)]
    hand = np.stack([np.asarray(frame_pose(panda, jnp.asarray(qi), fabric.goal_frame).translation()) for qi in [*q[::5], q[-1]]])
    chord = np.linalg.norm(np.diff(hand, axis=0), axis=1).sum()  # a lower bound of the path length
    assert float(cost_len) - float(cost_good) == pytest.approx(2.0 * chord, rel=0.02)
    # a command at the start is passed at once: the sequence is the fabric aimed at the goal alone
    z_direct = to_unconstrained(jnp.asarray(READY)[None], panda.lower, panda.upper)
    _, tr_direct = jax.jit(lambda z: sequence_cost(fabric, params, problem, z, **kw))(z_direct)
    assert bool(tr_direct.reached) and float(tr_direct.segment_times[0]) <= 0.02


def test_cma_es_best_so_far_improves(fabric_params):
    """A wall between start and goal: the best-so-far cost never rises and improves on batch 1."""
    fabric, params = fabric_params
    goal = np.array([1.2, 0.3, 0.2, -1.6, 0.1, 1.9, 0.8], np.float32)
    wall = {"type": "cuboid", "center": [0.45, 0.3, 0.45], "size": [0.12, 0.12, 0.3]}
    cfg = GFCSConfig(population=12, batches=4, t_max=2.0)
    r = solve(fabric, params, _problem(goal, [wall]), jax.random.PRNGKey(1), cfg)
    best = [b["best_cost"] for b in r.per_batch]
    assert all(b <= a for a, b in zip(best, best[1:]))
    assert r.best_cost == best[-1] == float(r.top_cost[0]) and len(r.top_cost) == cfg.top_m
    assert np.all(np.diff(r.top_cost) >= 0)
    kw = dict(steps=cfg.steps, patience=cfg.patience, via_tolerance=cfg.via_tolerance, final_pose=cfg.final_pose, length_weight=cfg.length_weight)
    cost, _ = sequence_cost(fabric, params, _problem(goal, [wall]), jnp.asarray(r.best_z), **kw)
    assert float(cost) == pytest.approx(r.best_cost, rel=1e-5)  # the reported cost is the candidate's cost
    with pytest.raises(ValueError, match="samples"):
        solve(fabric, params, _problem(goal), jax.random.PRNGKey(0), cfg, samples=jnp.zeros((3, 1, 7)))


def test_pose_goal_gfcs_ends_at_the_pose_without_ik(fabric_params, panda):
    """goal="pose": a problem given only a hand pose (behind a wall) is solved without a joint goal;
    the final state meets the pose test, the reported cost is the candidate's, and goal="joint"
    refuses the same problem before any work."""
    fabric, params = fabric_params
    q_goal = jnp.asarray([1.2, 0.3, 0.2, -1.6, 0.1, 1.9, 0.8])
    pose = frame_pose(panda, q_goal, fabric.goal_frame)
    wall = {"type": "cuboid", "center": [0.45, 0.3, 0.45], "size": [0.12, 0.12, 0.3]}
    scene = from_dict({"obstacles": [wall]}, {"cuboids": 2})
    goal_pose = (np.asarray(pose.translation()), np.asarray(pose.rotation().wxyz))
    problem = ProblemBatch.of(Problem(np.asarray(READY), scene, goal_pose=goal_pose), scene.capacity)
    cfg = GFCSConfig(population=12, batches=2, t_max=3.0, goal="pose")
    r = solve(fabric, params, problem, jax.random.PRNGKey(1), cfg)
    assert r.best_cost < cfg.penalty and bool(r.trajectory.reached)
    q_end = jnp.asarray(r.trajectory.q[int(r.trajectory.length) - 1])
    end = frame_pose(panda, q_end, fabric.goal_frame)
    assert float(jnp.linalg.norm(end.translation() - pose.translation())) <= fabric.position_tolerance + 1e-6
    kw = dict(steps=cfg.steps, patience=cfg.patience, via_tolerance=cfg.via_tolerance, length_weight=cfg.length_weight, goal="pose")
    cost, _ = sequence_cost(fabric, params, problem, jnp.asarray(r.best_z), **kw)
    assert float(cost) == pytest.approx(r.best_cost, rel=1e-5)
    with pytest.raises(ValueError, match="goal=joint needs joint goals"):
        solve(fabric, params, problem, jax.random.PRNGKey(1), dataclasses.replace(cfg, goal="joint"))
    with pytest.raises(ValueError, match="goal must be one of"):
        GFCSConfig(goal="hand")


def test_solve_batch_equals_solve_per_problem(fabric_params):
    """Problems solved together (one rollout call and one vmapped CMA-ES update per batch for all of
    them) give each problem what `solve` gives it alone with its key: the first batch's costs and the
    best candidates of every batch, up to the float rounding CMA-ES amplifies."""
    from fabrax.planners.gfcs import solve_batch

    fabric, params = fabric_params
    goals = [np.array([1.2, 0.3, 0.2, -1.6, 0.1, 1.9, 0.8], np.float32), READY + np.array([0.5, 0.2, 0, 0.2, 0, 0, 0], np.float32)]
    wall = {"type": "cuboid", "center": [0.45, 0.3, 0.45], "size": [0.12, 0.12, 0.3]}
    problems = [_problem(goals[0], [wall]), _problem(goals[1])]
    keys = jax.random.split(jax.random.PRNGKey(3), 2)
    cfg = GFCSConfig(population=12, batches=3, t_max=2.0, direct=True)
    alone = [solve(fabric, params, p, k, cfg) for p, k in zip(problems, keys)]
    together = ProblemBatch.stack(problems)
    batch = solve_batch(fabric, params, together, keys, cfg)
    assert len(batch) == 2
    for a, b in zip(alone, batch):
        assert b.per_batch[0]["best_cost"] == pytest.approx(a.per_batch[0]["best_cost"], rel=1e-5)
        assert [x["best_cost"] for x in b.per_batch] == pytest.approx([x["best_cost"] for x in a.per_batch], rel=1e-3)
        np.testing.assert_allclose(b.best_commands, a.best_commands, atol=1e-3)
        assert int(b.trajectory.length) == int(a.trajectory.length)
    assert batch[0].per_batch[0]["wall_s"] == batch[1].per_batch[0]["wall_s"]  # one call for both
    with pytest.raises(ValueError, match="keys"):
        solve_batch(fabric, params, together, keys[:1], cfg)


def _toy_data(n, key):
    """Context x in R^4; the good target y in [0, 1]^2 is a fixed smooth function of x."""
    x = jax.random.normal(key, (n, 4))
    y = jax.nn.sigmoid(jnp.stack([x[:, 0] + x[:, 1], x[:, 2] - x[:, 3]], -1))
    return x, y


def test_energy_model_is_the_mlp_on_concatenated_context_and_target():
    """The split first layer (context share computed once) is the paper's MLP on concat(x, y)."""
    from flax import nnx

    from fabrax.planners.gfcs.ebm import EnergyModel

    model = EnergyModel(5, 3, hidden=16, layers=3, rngs=nnx.Rngs(1))
    x, y = jax.random.normal(jax.random.PRNGKey(0), (6, 5)), jax.random.uniform(jax.random.PRNGKey(1), (6, 3))
    h = jnp.concatenate([x, y], -1)
    for layer in model.hidden:
        h = jax.nn.relu(h @ layer.kernel[...] + layer.bias[...])
    ref = (h @ model.out.kernel[...] + model.out.bias[...])[:, 0]
    np.testing.assert_allclose(np.asarray(model(x, y)), np.asarray(ref), rtol=1e-5, atol=1e-5)
    y4 = jax.random.uniform(jax.random.PRNGKey(2), (6, 4, 3))  # one context against many targets
    np.testing.assert_allclose(
        np.asarray(model.given(model.context(x)[:, None], y4)), np.asarray(model(jnp.broadcast_to(x[:, None], (6, 4, 5)), y4)), rtol=1e-5, atol=1e-5
    )


def test_energy_model_learns_and_ranks_positives_above_sgld_negatives():
    """Trained with InfoNCE against SGLD negatives: on held-out contexts the loss against fixed SGLD
    negatives (drawn from the untrained model) falls, positives rank below them in energy, and SGLD on
    the trained model samples near the true targets (it has become a useful warm-start sampler)."""
    import optax
    from flax import nnx

    from fabrax.planners.gfcs.ebm import EnergyModel, SGLDConfig, info_nce, sgld, train_step

    model = EnergyModel(4, 2, hidden=64, layers=2, rngs=nnx.Rngs(0))
    opt = nnx.Optimizer(model, optax.adam(3e-3), wrt=nnx.Param)
    x, y = _toy_data(512, jax.random.PRNGKey(0))
    xt, yt = _toy_data(64, jax.random.PRNGKey(7))  # held out
    cfg = SGLDConfig(steps=10, step=0.01, noise=0.1)
    draw = lambda m, k: jax.vmap(lambda xi, kk: sgld(m, xi, kk, 8, cfg))(xt, jax.random.split(k, 64))  # noqa: E731
    fixed_neg = draw(model, jax.random.PRNGKey(8))
    assert bool(jnp.all((fixed_neg >= 0) & (fixed_neg <= 1)))  # SGLD stays within the (normalised) limits
    before = float(info_nce(model, xt, yt, fixed_neg))
    for s in range(300):
        idx = jax.random.choice(jax.random.PRNGKey(100 + s), 512, (64,), replace=False)
        train_step(model, opt, x[idx], y[idx], jax.random.PRNGKey(s), 8, cfg)
    after = float(info_nce(model, xt, yt, fixed_neg))
    assert after < 0.5 * before
    e_pos, e_neg = model(xt, yt), model(jnp.broadcast_to(xt[:, None], (64, 8, 4)), fixed_neg)
    assert float(jnp.mean(e_pos[:, None] < e_neg)) > 0.9
    samples = draw(model, jax.random.PRNGKey(9))
    assert bool(jnp.all((samples >= 0) & (samples <= 1)))
    err_learned = float(jnp.mean(jnp.linalg.norm(samples - yt[:, None], axis=-1)))
    err_uniform = float(jnp.mean(jnp.linalg.norm(fixed_neg - yt[:, None], axis=-1)))
    assert err_learned < 0.5 * err_uniform


def test_learned_samples_lie_within_joint_limits(panda):
    from fabrax.planners.gfcs.selfsup import SelfSupConfig, learned_samples, new_learner

    cfg = SelfSupConfig(hidden=32, layers=2)
    learner = new_learner(10, 14, cfg)
    z = learned_samples(learner, panda, jnp.zeros(10), jax.random.PRNGKey(0), 16, 2, cfg)
    q = to_commands(z, panda.lower, panda.upper)
    assert z.shape == (16, 2, 7) and bool(jnp.all((q >= panda.lower) & (q <= panda.upper)))


def test_oversampled_warm_start_keeps_the_lowest_energy_samples(panda):
    """warm.oversample k draws k x population SGLD particles (the same draw as a population of k x
    population) and keeps the population lowest in the model's energy."""
    from fabrax.planners.gfcs.selfsup import SelfSupConfig, WarmStart, learned_samples, new_learner

    cfg = SelfSupConfig(hidden=32, layers=2)
    learner = new_learner(10, 14, cfg)
    x, key = jnp.linspace(0.0, 1.0, 10), jax.random.PRNGKey(3)
    every = learned_samples(learner, panda, x, key, 64, 2, cfg)  # one draw of 64 = 8 x 8
    kept = learned_samples(learner, panda, x, key, 8, 2, dataclasses.replace(cfg, warm=WarmStart(oversample=8)))
    energy = lambda z: learner.model(jnp.broadcast_to(x, (len(z), 10)), jax.nn.sigmoid(z).reshape(len(z), 14))  # noqa: E731
    e_all = np.sort(np.asarray(energy(every)))
    assert kept.shape == (8, 2, 7)
    np.testing.assert_allclose(np.sort(np.asarray(energy(kept))), e_all[:8], rtol=1e-3, atol=1e-2)
    with pytest.raises(ValueError, match="warm.oversample must be a positive integer"):
        WarmStart(oversample=0)


def test_replayed_warm_start_draws_the_buffer(panda):
    """warm.replay p: the last round(p x population) candidates are buffered solutions (exactly,
    without noise; within the noise's reach with it), the rest the model's SGLD particles, which
    are then the same draw as a model-only population of that size."""
    from fabrax.planners.gfcs.selfsup import SelfSupConfig, WarmStart, learned_samples, new_learner

    cfg = SelfSupConfig(hidden=32, layers=2)
    learner = new_learner(10, 14, cfg)
    learner.targets = np.random.default_rng(0).uniform(0.1, 0.9, (5, 14)).astype(np.float32)
    x, key = jnp.linspace(0.0, 1.0, 10), jax.random.PRNGKey(3)
    unit = lambda z: np.asarray(jax.nn.sigmoid(z)).reshape(len(z), 14)  # noqa: E731  (to_commands, normalised)
    nearest = lambda u: np.min(np.abs(u[:, None] - learner.targets[None]).max(-1), axis=1)  # noqa: E731

    half = learned_samples(learner, panda, x, key, 8, 2, dataclasses.replace(cfg, warm=WarmStart(replay=0.5, replay_noise=0.0)))
    assert half.shape == (8, 2, 7)
    np.testing.assert_allclose(nearest(unit(half[4:])), 0.0, atol=1e-5)
    model_only = learned_samples(learner, panda, x, key, 4, 2, cfg)
    np.testing.assert_allclose(np.asarray(half[:4]), np.asarray(model_only), rtol=1e-5, atol=1e-5)
    assert nearest(unit(half[:4])).min() > 1e-3  # SGLD particles are not buffer rows

    noisy = unit(learned_samples(learner, panda, x, key, 64, 2, dataclasses.replace(cfg, warm=WarmStart(replay=1.0, replay_noise=0.05))))
    d = nearest(noisy)
    assert d.max() < 0.05 * 6 and d.mean() > 0.01  # moved by the noise, never far from a buffered solution
    for bad, match in (({"replay": 1.5}, "warm.replay must be a share"), ({"replay_noise": -0.1}, "warm.replay_noise must be")):
        with pytest.raises(ValueError, match=match):
            WarmStart(**bad)


def test_problem_encoding(panda):
    from fabrax.planners.gfcs.encoding import Encoding

    enc = Encoding()
    lattice = enc.lattice()
    assert np.allclose(np.diff(np.unique(lattice[:, 0])), 0.15)
    box = {"type": "cuboid", "center": [0.45, 0.0, 0.45], "size": [0.3, 0.3, 0.3]}
    d = np.asarray(enc.scene_distances(from_dict({"obstacles": [box]})))
    k = int(np.argmin(np.linalg.norm(lattice - [0.45, 0.0, 0.45], axis=1)))
    assert d.shape == (len(lattice),) and d[k] < 0 and d.max() <= 1.0
    far = int(np.argmax(np.linalg.norm(lattice - [0.45, 0.0, 0.45], axis=1)))
    assert d[far] == pytest.approx(1.0)
    x = enc.context(panda, jnp.asarray(READY), jnp.zeros(7), jnp.asarray(READY), from_dict({"obstacles": [box]}))
    assert x.shape == (21 + len(lattice),) and bool(jnp.all(jnp.isfinite(x)))
    # scene_scale weighs d_E alone: the joint part is unchanged, 0 leaves start, velocity and goal
    for scale in (0.1, 0.0):
        xs = Encoding(scene_scale=scale).context(panda, jnp.asarray(READY), jnp.zeros(7), jnp.asarray(READY), from_dict({"obstacles": [box]}))
        np.testing.assert_array_equal(np.asarray(xs[:21]), np.asarray(x[:21]))
        np.testing.assert_allclose(np.asarray(xs[21:]), scale * d, rtol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("latent", [None, 8], ids=["raw_dE", "autoencoder"])
def test_self_supervised_run_checkpoints_and_resumes(tmp_path, panda, fabric_params, latent):
    import dataclasses

    from flax import nnx

    from fabrax.planners.gfcs.selfsup import SelfSupConfig, load, run
    from fabrax.problems import make_problem

    fabric, params = fabric_params
    goals = [READY + d for d in (np.array([0.4, 0, 0, 0, 0, 0, 0]), np.array([-0.3, 0.2, 0, 0.2, 0, 0, 0]))]
    problems = [make_problem(panda, READY, {"obstacles": []}, goal_q=g, name=f"free{k}") for k, g in enumerate(goals)]
    gcfg = GFCSConfig(population=4, batches=1, t_max=1.5)
    cfg = SelfSupConfig(hidden=16, layers=2, retrain_every=2, passes=2, train_steps=3, batch=4, n_neg=2, buffer_size=6, latent=latent, ae_steps=20)
    quiet = lambda *_: None  # noqa: E731
    full = run(fabric, params, problems, gcfg, cfg, tmp_path / "full.msgpack", log=quiet)
    part = tmp_path / "part.msgpack"
    first = run(fabric, params, problems, gcfg, cfg, part, log=quiet, stop_after=3)  # "interrupted" after 3 solves
    assert first.solved == 3 and load(part, first.contexts.shape[1], 7, cfg).solved == 3
    resumed = run(fabric, params, problems, gcfg, cfg, part, log=quiet)
    assert full.solved == resumed.solved == 4 and full.trained and len(full.targets) > 0
    assert len(full.targets) <= cfg.buffer_size
    assert np.array_equal(full.targets, resumed.targets) and np.array_equal(full.costs, resumed.costs)
    leaves = lambda m: jax.tree.leaves(nnx.state(m, nnx.Param))  # noqa: E731
    assert all(np.allclose(a, b) for a, b in zip(leaves(full.model), leaves(resumed.model), strict=True))
    assert full.contexts.shape[1] == 21 + (latent or 1859)  # [q0, qd0, q_goal] + d_E or its code
    if latent:
        assert all(np.allclose(a, b) for a, b in zip(leaves(full.ae), leaves(resumed.ae), strict=True))
    # resuming with another setting is refused before anything runs, naming the setting
    with pytest.raises(ValueError, match=r"other settings: selfsup.hidden \(16 -> 32\)"):
        run(fabric, params, problems, gcfg, dataclasses.replace(cfg, hidden=32), part, log=quiet)
    with pytest.raises(ValueError, match="problems"):
        run(fabric, params, problems[:1], gcfg, cfg, part, log=quiet)
    with pytest.raises(ValueError, match="cannot read GFCS checkpoint"):
        (tmp_path / "bad.msgpack").write_bytes(b"not a checkpoint")
        load(tmp_path / "bad.msgpack", 10, 7, cfg)


def test_autoencoder_compresses_distance_fields():
    """d_E of many scenes (here: distances to a sphere moving on a line) compress to a few numbers."""
    from fabrax.planners.gfcs.autoencoder import fit

    pts = np.linspace(-1, 1, 200)
    centres = np.random.default_rng(0).uniform(-1, 1, 64)
    d = np.clip(np.abs(pts[None] - centres[:, None]) - 0.1, -0.15, 1.0).astype(np.float32)
    model, losses = fit(d, latent=4, hidden=64, steps=300, lr=3e-3)
    assert losses[-1] < 0.05 * losses[0]
    assert model.encode(jnp.asarray(d)).shape == (64, 4)


def test_blocking_cuboids_block_the_path_not_the_ends(panda):
    from fabrax.bench import check_path
    from fabrax.planners.gfcs.reactive import blocking_cuboids, with_obstacles

    goal = READY + np.array([1.2, 0.3, 0, 0.3, 0, 0, 0], np.float32)
    path = READY + np.linspace(0, 1, 120)[:, None] * (goal - READY)
    base = from_dict({"obstacles": [{"type": "cuboid", "center": [-0.5, 0.0, 0.2], "size": [0.1, 0.1, 0.1]}]})
    cubes = blocking_cuboids(panda, path, READY, goal, np.random.default_rng(0), n=2)
    scene = with_obstacles(base, cubes)
    assert int(scene.cuboids.mask.sum()) == 3
    assert check_path(panda, scene, path).collision and not check_path(panda, base, path).collision
    for q in (READY, goal):
        assert check_path(panda, scene, q[None]).min_clearance >= 0.03


def test_gfcs_learned_bench_method_loads_a_run(tmp_path, shared_data):
    """`fabrax bench method=gfcs_learned method.run=DIR` warm-starts from an experiments/gfcs.py run's sampler."""
    import json

    import yaml

    from fabrax import config as fconfig
    from fabrax.bench import cli
    from fabrax.planners.gfcs.selfsup import new_learner, save, settings

    robot = fconfig.load_robot("panda_mbm")
    run = tmp_path / "run"
    (run / ".hydra").mkdir(parents=True)
    cfg = {"seed": 0, "selfsup": {"hidden": 32, "layers": 2, "sgld": {"steps": 5, "step": 0.01, "noise": 0.1}}, "encoding": {"spacing": 0.3}}
    (run / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    ss, enc = settings(cfg)
    learner = new_learner(3 * robot.dof + enc.n_reference, robot.dof, ss)
    save(learner, run / "sampler.msgpack")
    args = ["method=gfcs_learned", f"method.run={run}", "problems=mbm", "classes=[box]", "limit=1", "progress=false"]
    args += ["method.population=8", "method.batches=2", "method.report=[1,2]", f"out={tmp_path / 'out'}"]
    with pytest.raises(SystemExit, match="never trained"):
        cli.main(args)
    learner.trained = True
    save(learner, run / "sampler.msgpack")
    assert cli.main(args) == 0
    rows = json.loads((tmp_path / "out" / "results.json").read_text())["rows"]
    assert {r["method"] for r in rows} == {"gfcs_learned", "gfcs_learned (1 b)"}
    with pytest.raises(SystemExit, match="Missing mandatory value"):
        cli.main(["method=gfcs_learned", "classes=[box]", "limit=1"])


def test_reactive_study_refuses_a_saved_run_with_other_settings(tmp_path):
    """experiments/gfcs.py re-executes a saved run's commands only if they were solved with the same
    dt, budget, fabric, frame and goal segment; otherwise one line names what differs."""
    import importlib.util
    import json
    from pathlib import Path

    from fabrax import config as fconfig

    spec = importlib.util.spec_from_file_location("gfcs_experiment", Path(__file__).parents[1] / "experiments" / "gfcs.py")
    experiment = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(experiment)
    cfg = {"dt": 0.01, "t_max": 7.0, "fabric": "panda", "frame": "panda_hand", "method": {"final_pose": True, "via_tolerance": 0.5}}
    saved = {**cfg, "fabric": fconfig.load("fabric", "panda")}  # bench runs store the composed fabric
    rows = [{"method": "gfcs", "problem": "box/0051", "success": True, "info": {"commands": [[0.0] * 7]}}]
    (tmp_path / "results.json").write_text(json.dumps({"meta": {"config": saved}, "rows": rows}))
    assert experiment.saved_rows(cfg, tmp_path) == rows
    with pytest.raises(SystemExit, match="dt, method.final_pose, method.via_tolerance"):
        experiment.saved_rows({**cfg, "dt": 0.02, "method": {"final_pose": False, "via_tolerance": None}}, tmp_path)
    with pytest.raises(SystemExit, match="fabric"):
        experiment.saved_rows({**cfg, "fabric": {**saved["fabric"], "energization": "none"}}, tmp_path)
    with pytest.raises(SystemExit, match="no results.json"):
        experiment.saved_rows(cfg, tmp_path / "missing")


def test_config_defaults_are_the_method_preset():
    """One set of defaults: `GFCSConfig()` is what `fabrax bench method=gfcs` runs."""
    from fabrax.bench.cli import compose
    from fabrax.bench.methods.gfcs import gfcs_config

    cfg = compose(["method=gfcs"])
    assert gfcs_config(cfg["method"], cfg) == GFCSConfig(dt=cfg["dt"], t_max=cfg["t_max"]) == GFCSConfig()


def test_replan_is_warm_started_at_the_old_solution(fabric_params, panda):
    """Re-planning puts the old solution in its first batch, so its best cost is at most the old
    solution's cost in the new scene; the other candidates spread around it by std_init."""
    from fabrax.planners.gfcs.reactive import replan, replan_config, warm_samples

    z = to_unconstrained(jnp.asarray(READY + 0.3)[None], panda.lower, panda.upper)
    s = warm_samples(jax.random.PRNGKey(0), z, 256, 0.3)
    assert s.shape == (256, 1, 7) and np.array_equal(np.asarray(s[-1]), np.asarray(z))
    assert float(jnp.std(s[:-1] - z)) == pytest.approx(0.3, rel=0.1)
    with pytest.raises(ValueError, match="population"):
        warm_samples(jax.random.PRNGKey(0), z, 1, 0.3)

    fabric, params = fabric_params
    goal = np.array([1.2, 0.3, 0.2, -1.6, 0.1, 1.9, 0.8], np.float32)
    wall = {"type": "cuboid", "center": [0.45, 0.3, 0.45], "size": [0.12, 0.12, 0.3]}
    cfg = replan_config(GFCSConfig(population=8, t_max=2.0), batches=1, std=0.2)
    assert cfg.patience is None and cfg.std_init == 0.2
    with pytest.raises(ValueError, match="batches"):
        replan_config(cfg, batches=0)
    problem = _problem(goal, [wall])
    r = replan(fabric, params, problem, z, jax.random.PRNGKey(3), cfg)
    kw = dict(steps=cfg.steps, patience=cfg.patience, via_tolerance=cfg.via_tolerance, final_pose=cfg.final_pose, length_weight=cfg.length_weight)
    old, _ = sequence_cost(fabric, params, problem, z, **kw)
    assert r.per_batch[0]["best_cost"] <= float(old) * (1 + 1e-5)
    assert len(r.per_batch) == 1 and r.best_cost <= float(old) * (1 + 1e-5)


def test_learned_sampler_refuses_pose_goals_before_any_work(fabric_params, panda):
    """The sampler's context encodes the joint goal: a pose-only problem is refused by name, both by
    the learned bench method and by Algorithm 2, before anything compiles."""
    from fabrax.bench.methods.gfcs import GFCSMethod
    from fabrax.planners.gfcs.selfsup import SelfSupConfig
    from fabrax.planners.gfcs.selfsup import run as learn

    fabric, params = fabric_params
    pose = frame_pose(panda, jnp.asarray(READY), fabric.goal_frame)
    scene = from_dict({"obstacles": []}, {"cuboids": 2})
    p = Problem(np.asarray(READY), scene, goal_pose=(np.asarray(pose.translation()), np.asarray(pose.rotation().wxyz)), name="posed")
    with pytest.raises(ValueError, match="posed has a pose goal"):
        GFCSMethod(fabric, params, GFCSConfig(goal="pose"), learner=object()).solve(panda, [p])
    with pytest.raises(ValueError, match="posed has a pose goal"):
        learn(fabric, params, [p], GFCSConfig(), SelfSupConfig(), Path("/nonexistent/ckpt.msgpack"))


def test_straight_line_floor_bounds_a_hand_path_from_below(shared_data, tmp_path):
    """experiments/mbm_straight_line.py: the start-to-goal distance of a frame bounds the length of
    any path of that frame from below; checked on the hand path of a joint-space line on MBM problems."""
    import importlib.util
    import json

    from fabrax.config import load_robot
    from fabrax.problems.mbm import load_mbm
    from fabrax.robot.kinematics import frame_path

    spec = importlib.util.spec_from_file_location("mbm_straight_line", Path(__file__).parents[1] / "experiments" / "mbm_straight_line.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.main(["--out", str(tmp_path / "s"), "--split", "train", "--classes", "box", "cage", "--limit", "3"]) == 0
    rows = json.loads((tmp_path / "s.json").read_text())["classes"]
    assert set(rows) == {"box", "cage"} and rows["box"]["n"] == 3 and rows["box"]["paper_gf"] == 0.92
    robot = load_robot("panda_mbm")
    problems = load_mbm(robot, classes=["box"], split="train", limit=3)
    floor = script.straight_lines(robot, problems, [robot.ee_frame])[robot.ee_frame]
    np.testing.assert_allclose(floor.mean(), rows["box"][robot.ee_frame]["mean"], rtol=1e-6)
    for p, d in zip(problems, floor):  # a straight joint-space interpolation's hand path is no shorter
        q = np.linspace(p.start_q, p.goal_q, 200)
        hand = np.asarray(frame_path(robot, jnp.asarray(q, jnp.float32), robot.ee_frame)[0])
        assert np.linalg.norm(np.diff(hand, axis=0), axis=-1).sum() >= d - 1e-5
    with pytest.raises(SystemExit, match="--frames: nowhere"):
        script.main(["--out", str(tmp_path / "x"), "--frames", "nowhere"])


def test_hand_mass_makes_the_hand_metric_constant_in_the_rollouts(fabric_params, panda):
    """`hand_mass` sets the end-effector attractor's far mass (m_lo) and nothing else; at m_hi the
    hand's kinetic energy no longer depends on its distance to the target, and the rollouts use it."""
    from fabrax.fabrics import energies as E
    from fabrax.planners.gfcs.cost import with_hand_mass

    fabric, params = fabric_params
    assert with_hand_mass(params, None) is params
    heavy = with_hand_mass(params, float(params["ee"]["m_hi"]))
    assert {k for k in params["ee"] if not np.array_equal(params["ee"][k], heavy["ee"][k])} == {"m_lo"}
    assert all(heavy[k] is params[k] for k in params if k != "ee")
    rd = jnp.array([0.3, -0.1, 0.2])

    def kinetic(p, r):
        return float(E.attractor_energy(jnp.asarray(r), rd, p["m_hi"], p["m_lo"], p["alpha_mass"]))

    assert kinetic(heavy["ee"], [0.5, 0.0, 0.0]) == pytest.approx(kinetic(heavy["ee"], [0.01, 0.0, 0.0]), rel=1e-6)
    assert kinetic(params["ee"], [0.5, 0.0, 0.0]) < kinetic(params["ee"], [0.01, 0.0, 0.0])  # the fabric's: lighter far away
    problem = _problem(READY + np.array([0.5, 0.2, 0, 0.2, 0, 0, 0], np.float32))
    z = to_unconstrained(jnp.asarray(READY)[None], panda.lower, panda.upper)
    _, light = jax.jit(lambda z: sequence_cost(fabric, params, problem, z, steps=300))(z)
    _, held = jax.jit(lambda z: sequence_cost(fabric, params, problem, z, steps=300, hand_mass=float(params["ee"]["m_hi"])))(z)
    assert bool(light.reached) and bool(held.reached)
    assert not np.allclose(np.asarray(light.q), np.asarray(held.q), atol=1e-4)
    with pytest.raises(ValueError, match="hand_mass must be a positive mass"):
        GFCSConfig(hand_mass=0.0)


@pytest.mark.parametrize("shrink", [0, -2, 1.5, True])
def test_gfcs_shrink_must_be_a_positive_integer(shrink):
    with pytest.raises(ValueError, match="shrink must be a positive integer"):
        GFCSConfig(shrink=shrink)
