"""The RL guide's environment (thesis §3.4): brax Env purity, observations, rewards, switch, collisions."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from fabrax import config
from fabrax.check.clearance import state_clearances
from fabrax.config import load_robot
from fabrax.rl import build_pool, env_config, make_env, sample_episode
from fabrax.rl.observations import cell_centres, cell_index, grid_points, intrinsic_reward, keypoint_distance
from fabrax.robot.kinematics import frame_pose, keypoints, keypoints_at_pose
from fabrax.scene import signed_distances

CFG = {"substeps": 5, "scenes": {"generated": {"cuboid_forest": 1, "shelves": 1, "flying_cuboids": 1}, "configs_per_scene": 4}}


@pytest.fixture(scope="module")
def env():
    return make_env(CFG, load_robot("panda"), config.load("fabric", "panda"))


@pytest.fixture(scope="module")
def fns(env):
    return jax.jit(env.reset), jax.jit(env.step)


def _stage(state, stage):
    return state.replace(info={**state.info, "stage": jnp.asarray(stage, jnp.int32)})


def test_reset_and_step_are_pure_and_batch(env, fns):
    reset, step = fns
    a = jax.random.uniform(jax.random.PRNGKey(3), (env.action_size,), minval=-1, maxval=1)
    s1, s2 = reset(jax.random.PRNGKey(0)), reset(jax.random.PRNGKey(0))
    assert jax.tree.all(jax.tree.map(lambda x, y: bool(jnp.array_equal(x, y)), s1, s2))
    n1, n2 = step(s1, a), step(s1, a)
    assert jax.tree.all(jax.tree.map(lambda x, y: bool(jnp.array_equal(x, y)), n1, n2))
    assert not np.allclose(n1.obs["q"], s1.obs["q"])  # the arm moved
    batch = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), 3))
    moved = jax.jit(jax.vmap(env.step))(batch, jnp.tile(a, (3, 1)))
    assert moved.reward.shape == (3,) and moved.obs["bps"].shape == (3, 16, 16, 16, 3)
    one = step(jax.tree.map(lambda x: x[1], batch), a)
    np.testing.assert_allclose(moved.obs["q"][1], one.obs["q"], atol=1e-5)
    full, qs, _ = jax.jit(env.step_with_path)(s1, a)
    assert qs.shape == (env.cfg.substeps, env.robot.dof)
    np.testing.assert_array_equal(qs[-1], n1.pipeline_state.q)
    np.testing.assert_array_equal(full.reward, n1.reward)


def test_observation_shapes_and_contents(env, fns):
    reset, step = fns
    s = step(reset(jax.random.PRNGKey(2)), jnp.zeros(env.action_size))
    assert {k: tuple(v.shape) for k, v in s.obs.items()} == env.observation_size
    assert env.action_size == 6 + env.robot.dof + 1
    ep = s.pipeline_state
    np.testing.assert_allclose(s.obs["hand_keypoints"], keypoints(env.robot, ep.q).reshape(-1), atol=1e-6)
    np.testing.assert_allclose(s.obs["goal_keypoints"], keypoints(env.robot, ep.goal_q).reshape(-1), atol=1e-6)
    # the exploration map marks the cells the hand passed through in this step, and only those
    assert 1 <= int(s.obs["exploration"].sum()) <= env.cfg.substeps
    hand = frame_pose(env.robot, ep.q, env.fabric.goal_frame).translation()
    cell, inside = cell_index(hand, env.cfg.map_cells, *env.cfg.bounds)
    assert bool(inside) and s.obs["exploration"].reshape(-1)[cell] == 1.0


def _surface_samples(scene, n=10000, seed=0):
    """Points on every cuboid's surface (brute-force reference for the BPS)."""
    rng = np.random.default_rng(seed)
    c = scene.cuboids
    out = []
    for k in np.flatnonzero(np.asarray(c.mask)):
        h = np.asarray(c.half_extents[k], np.float64)
        u = rng.uniform(-1, 1, (n, 3)) * h
        axis = rng.integers(0, 3, n)
        u[np.arange(n), axis] = np.sign(rng.uniform(-1, 1, n)) * h[axis]
        r = np.asarray(jaxlie.SO3(c.quat[k]).as_matrix(), np.float64)
        out.append(u @ r.T + np.asarray(c.center[k]))
    return np.concatenate(out)


def test_bps_vectors_point_to_the_nearest_surface(env):
    pool = env.pool
    i = 2  # the flying cuboids
    scene = jax.tree.map(lambda a: a[i], pool.scene)
    grid = np.asarray(grid_points(env.cfg.bps_cells, *env.cfg.bounds)).reshape(-1, 3)
    vec = np.asarray(pool.bps[i]).reshape(-1, 3)
    pick = np.random.default_rng(0).choice(len(grid), 300, replace=False)
    d = np.asarray(signed_distances(scene, jnp.asarray(grid[pick]))).min(1)
    # |v| is the distance, and b + v lies on an obstacle surface
    np.testing.assert_allclose(np.linalg.norm(vec[pick], axis=1), np.minimum(np.abs(d), env.cfg.bps_clip), atol=1e-4)
    tip = np.asarray(signed_distances(scene, jnp.asarray(grid[pick] + vec[pick]))).min(1)
    np.testing.assert_allclose(tip, 0.0, atol=1e-4)
    # brute force: the nearest of dense surface samples is no nearer than |v| (outside points)
    samples = _surface_samples(scene)
    out = pick[d > 0]
    brute = np.min(np.linalg.norm(grid[out][:, None, :] - samples[None], axis=-1), axis=1)
    assert np.all(brute >= np.linalg.norm(vec[out], axis=1) - 1e-4)
    assert np.all(brute <= np.linalg.norm(vec[out], axis=1) + 0.01)


def test_dynamic_basis_points_agree_with_the_checker(env, fns):
    reset, _ = fns
    s = reset(jax.random.PRNGKey(5))
    ep = s.pipeline_state
    env_clear, _, _ = state_clearances(env.robot, ep.scene, ep.q[None])
    np.testing.assert_allclose(np.min(s.obs["dynamic_bps"] - env.robot.collision.radius), env_clear[0], atol=1e-5)


def test_keypoints_of_a_pose_and_the_distance():
    robot = load_robot("panda")
    q = jnp.asarray([0.3, -0.4, 0.2, -2.0, 0.1, 1.8, 0.5])
    pose = frame_pose(robot, q, "panda_hand")
    kp = keypoints(robot, q)
    np.testing.assert_allclose(keypoints_at_pose(robot, "panda_hand", pose.translation(), pose.rotation().wxyz), kp, atol=1e-5)
    assert float(keypoint_distance(kp, kp)) == 0.0
    np.testing.assert_allclose(keypoint_distance(kp + jnp.array([0.03, 0.04, 0.0]), kp), 0.05, atol=1e-6)


def test_intrinsic_reward_matches_eqs_3_17_3_18_by_hand():
    cells, low, high = 4, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
    centres = cell_centres(cells, low, high)
    goal = jnp.array([0.125, 0.125, 0.125])  # the centre of cell 0
    a, _ = cell_index(jnp.array([0.1, 0.1, 0.1]), cells, low, high)
    b, _ = cell_index(jnp.array([0.9, 0.1, 0.1]), cells, low, high)
    assert int(a) == 0 and int(b) == 3 * 16
    counts = jnp.zeros(cells**3, jnp.int32)
    w_a, w_b = 1 / (0 + 0.25), 1 / (0.75 + 0.25)
    # step 1: a visited (n_a = 1); step 2: a again (n_a = 2) and b for the first time
    v1 = jnp.zeros(cells**3, bool).at[a].set(True)
    counts = counts + v1
    np.testing.assert_allclose(intrinsic_reward(counts, v1, centres, goal), w_a, rtol=1e-6)
    v2 = v1.at[b].set(True)
    counts = counts + v2
    np.testing.assert_allclose(intrinsic_reward(counts, v2, centres, goal), w_a * np.exp(-10.0) + w_b, rtol=1e-6)
    # a point outside the map is no visit
    assert not bool(cell_index(jnp.array([1.2, 0.5, 0.5]), cells, low, high)[1])


def test_switch_latches_only_in_stage_2_and_aims_at_the_goal(env, fns):
    reset, step = fns
    s = reset(jax.random.PRNGKey(7))
    on = jnp.zeros(env.action_size).at[-1].set(1.0)
    off = jnp.zeros(env.action_size).at[-1].set(-1.0)
    assert float(step(s, on).pipeline_state.switch) == 0.0  # stage 1 holds the switch at 0
    s2 = step(_stage(s, 2), on)
    assert bool(s2.pipeline_state.switch) and s2.obs["switch"][0] == 1.0
    assert bool(step(s2, off).pipeline_state.switch)  # latched for the rest of the episode
    ep = s2.pipeline_state
    params, switch = env.targets(ep, off, jnp.asarray(2))
    assert bool(switch)
    np.testing.assert_allclose(params["ee"]["target_pos"], ep.goal_pos, atol=1e-6)
    assert float(params["posture"]["weight"]) == 0.0
    free, _ = env.targets(s.pipeline_state, off, jnp.asarray(2))
    hand = frame_pose(env.robot, s.pipeline_state.fabric_q, env.fabric.goal_frame).translation()
    np.testing.assert_allclose(free["ee"]["target_pos"], hand, atol=1e-6)  # zero translation: the hand's own pose
    assert float(free["posture"]["weight"]) == 1.0


def test_success_at_the_goal_in_stage_2(env, fns):
    reset, step = fns
    s = _stage(reset(jax.random.PRNGKey(8)), 2)
    ep = s.pipeline_state
    s = s.replace(pipeline_state=ep.replace(q=ep.goal_q, fabric_q=ep.goal_q))
    out = step(s, jnp.zeros(env.action_size).at[-1].set(1.0))
    assert float(out.metrics["keypoint_distance"]) < env.cfg.success_distance
    assert out.metrics["success"] == 1.0 and out.done == 1.0
    assert float(out.reward) >= env.cfg.sparse_reward
    stage1 = step(_stage(s, 1), jnp.zeros(env.action_size))
    assert stage1.metrics["success"] == 0.0 and stage1.done == 0.0  # no sparse reward in stage 1


def test_a_collision_ends_the_episode_with_the_penalty(env, fns, box_on_hand):
    reset, step = fns
    s = box_on_hand(env, reset(jax.random.PRNGKey(9)))
    out = step(s, jnp.zeros(env.action_size))
    assert out.metrics["collision"] == 1.0 and out.done == 1.0
    assert float(out.reward) <= -env.cfg.collision_penalty + env.cfg.intrinsic_weight * 10.0


def test_sampled_starts_and_goals_are_valid(env):
    keys = jax.random.split(jax.random.PRNGKey(11), 64)
    i, start, goal, mode = jax.vmap(lambda k: sample_episode(env.pool, jnp.asarray(env.cfg.scenes.modes), k))(keys)
    assert np.all(np.asarray(mode) == 3)  # generated scenes only sample
    scenes = jax.tree.map(lambda a: a[i], env.pool.scene)
    for qs in (start, goal):
        e, s, ok = jax.vmap(lambda sc, q: state_clearances(env.robot, sc, q[None]))(scenes, qs)
        assert np.all(np.asarray(e) > 0) and np.all(np.asarray(s) > 0) and np.all(np.asarray(ok))
    assert not np.allclose(start, goal)


def test_dataset_modes_follow_table_3_1(env):
    pool = env.pool.replace(dataset=jnp.ones_like(env.pool.dataset))
    keys = jax.random.split(jax.random.PRNGKey(12), 4000)
    _, start, goal, mode = jax.vmap(lambda k: sample_episode(pool, jnp.asarray(env.cfg.scenes.modes), k))(keys)
    freq = np.bincount(np.asarray(mode), minlength=4) / 4000
    np.testing.assert_allclose(freq, env.cfg.scenes.modes, atol=0.03)


def test_bad_config_fails_before_any_jit(env):
    with pytest.raises(ValueError, match="unknown rl env keys"):
        env_config({"substep": 3})
    with pytest.raises(ValueError, match="env.substeps"):
        env_config({"substeps": 0})
    with pytest.raises(ValueError, match="env.backend"):
        env_config({"backend": "isaac"})
    with pytest.raises(ValueError, match="env.sim_steps"):
        env_config({"backend": "mjx", "sim_steps": 0})
    with pytest.raises(ValueError, match="generated kinds"):
        env_config({"scenes": {"generated": {"forest": 2}}})
    with pytest.raises(ValueError, match="no scene"):
        env_config({"scenes": {"generated": {"shelves": 0}}})
    small = env_config({"scenes": {"generated": {"shelves": 1}, "capacity": {"cuboids": 4}}})
    with pytest.raises(ValueError, match=r"shelves/0000.*capacity.cuboids=4"):
        build_pool(env.robot, small)


def test_pose_goals_keep_the_generators_goal_configuration(env):
    """A pose-goal problem carrying its generator's goal configuration (MπNets-faithful problems:
    meta["goal_q"]) enters the pool with that configuration, not another IK branch; the count of
    such problems is a checked setting."""
    from fabrax.problems.problem import Problem
    from fabrax.robot.kinematics import frame_pose as pose_of

    scene = jax.tree.map(lambda a: a[0], env.pool.scene)
    start, goal = np.asarray(env.pool.configs[0, 0]), np.asarray(env.pool.configs[0, 1])
    hand = pose_of(env.robot, jnp.asarray(goal), "panda_hand")
    p = Problem(start, scene, goal_pose=(np.asarray(hand.translation()), np.asarray(hand.rotation().wxyz)), meta={"goal_q": goal})
    none = {"shelves": 0, "cuboid_forest": 0, "flying_cuboids": 0}
    assert env_config({"scenes": {"generated": none, "mpinets": 3}}).scenes.mpinets == 3
    with pytest.raises(ValueError, match="env.scenes.mpinets"):
        env_config({"scenes": {"mpinets": -1}})
    cfg = env_config({"scenes": {"generated": {"shelves": 0, "cuboid_forest": 0, "flying_cuboids": 1}, "configs_per_scene": 2}})
    pool = build_pool(env.robot, cfg, [p])
    np.testing.assert_allclose(pool.start_q[0], start, atol=1e-6)
    np.testing.assert_allclose(pool.goal_q[0], goal, atol=1e-6)
    assert bool(pool.dataset[0]) and not bool(pool.dataset[1])


def test_cramped_dataset_scenes_sample_near_their_start_and_goal(env, monkeypatch):
    """Where uniform sampling finds too few valid configurations (a start inside a drawer), a
    dataset problem's sampled-mode configurations come from near its start and goal, valid."""
    from fabrax.problems import generators
    from fabrax.problems.problem import Problem

    uniform = generators.sample_configs

    def cramped(robot, scene, n, rng, margin=0.02, around=None, spread=1.0, **kw):
        if around is None:
            raise ValueError("could not find valid configurations")
        return uniform(robot, scene, n, rng, margin=margin, around=around, spread=spread, **kw)

    monkeypatch.setattr(generators, "sample_configs", cramped)
    scene = jax.tree.map(lambda a: a[0], env.pool.scene)
    start, goal = np.asarray(env.pool.configs[0, 0]), np.asarray(env.pool.configs[0, 1])
    none = {"shelves": 0, "cuboid_forest": 0, "flying_cuboids": 0}
    cfg = env_config({"scenes": {"generated": none, "mpinets": 1, "configs_per_scene": 4}})
    pool = build_pool(env.robot, cfg, [Problem(start, scene, goal_q=goal)])
    qs = np.asarray(pool.configs[0])
    span = np.asarray(env.robot.upper) - np.asarray(env.robot.lower)
    assert np.all(np.abs(qs[:2] - start) <= 0.125 * span + 1e-6) and np.all(np.abs(qs[2:] - goal) <= 0.125 * span + 1e-6)
    e, s, ok = state_clearances(env.robot, scene, jnp.asarray(qs, jnp.float32))
    assert np.all(np.asarray(e) > 0) and np.all(np.asarray(s) > 0) and np.all(np.asarray(ok))
    with pytest.raises(ValueError, match="could not find"):
        build_pool(env.robot, env_config({"scenes": {"generated": {"shelves": 1}}}))
