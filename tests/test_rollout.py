import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fabrax import config
from fabrax import scene as sc
from fabrax.bench import check_path
from fabrax.fabrics import max_acceleration
from fabrax.problems import batch, make_problem
from fabrax.robot import frame_pose
from fabrax.rollout import reach, rollout, rollout_population, rollout_sequence

READY = jnp.asarray([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
GOAL = jnp.asarray([1.2, 0.3, 0.2, -1.6, 0.1, 1.9, 0.8])
BOX = {"obstacles": [{"type": "cuboid", "center": [0.45, 0.3, 0.45], "size": [0.12, 0.12, 0.12]}]}


@pytest.fixture(scope="module")
def fabric(panda):
    return config.load_fabric(panda)


@pytest.fixture(scope="module")
def run(fabric):
    fab, _ = fabric
    return jax.jit(lambda p, s, q0, qd0: rollout(fab, p, s, q0, qd0, fab.reached, dt=0.01, steps=700))


def test_converges_to_free_space_joint_goal(fabric, run):
    fab, params = fabric
    tr = run(fab.with_joint_goal(params, GOAL), sc.empty(cuboids=1), READY, jnp.zeros(7))
    assert bool(tr.reached) and float(tr.t_goal) < 4.0
    full = jax.jit(lambda p: rollout(fab, p, sc.empty(cuboids=1), READY, jnp.zeros(7), fab.reached, steps=700, stop_at_goal=False))
    settled = full(fab.with_joint_goal(params, GOAL))
    assert float(jnp.linalg.norm(settled.q[-1] - GOAL)) < 0.01  # converges, not only passes by
    assert float(jnp.abs(settled.qd[-1]).max()) < 0.01


def test_converges_to_free_space_pose_goal(fabric, run):
    fab, params = fabric
    target = frame_pose(fab.robot, GOAL, fab.goal_frame)
    p = fab.with_pose_goal(params, target.translation(), target.rotation().wxyz)
    tr = run(p, sc.empty(cuboids=1), READY, jnp.zeros(7))
    assert bool(tr.reached)
    _, pos, rot = fab.goal_errors(p, tr.final_q())
    assert float(pos) <= 0.01 and float(rot) <= np.deg2rad(15)


def test_avoids_obstacle_between_start_and_goal(fabric, run, panda):
    """The straight joint-space path hits the box; the fabric goes around it and still arrives."""
    fab, params = fabric
    scene = sc.from_dict(BOX)
    assert check_path(panda, scene, np.linspace(np.asarray(READY), np.asarray(GOAL), 50)).collision
    tr = run(fab.with_joint_goal(params, GOAL), scene, READY, jnp.zeros(7))
    n = int(tr.length)
    assert bool(tr.reached)
    result = check_path(panda, scene, np.asarray(tr.q[:n]))
    assert not result.collision and result.limits_ok


def test_limits_never_exceeded(fabric, panda):
    """Goals beyond the joint limits and fast starts toward them: position, velocity,
    acceleration and jerk limits hold at every step (thesis §3.3.4)."""
    fab, params = fabric
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(panda.lower), np.asarray(panda.upper)
    starts = rng.uniform(lo + 0.05, hi - 0.05, (32, 7))
    towards = np.where(rng.random((32, 7)) < 0.5, lo - 1.0, hi + 1.0)  # attractor targets outside the limits
    amax = np.asarray(max_acceleration(panda, 0.01))
    room = np.where(towards > starts, hi - starts, starts - lo)
    speed = np.minimum(np.minimum(2.0, np.asarray(panda.velocity)), 0.95 * np.sqrt(2.0 * amax * room))  # can still brake
    qd0 = np.sign(towards - starts) * speed

    def one(q0, qd0, target):
        p = fab.with_joint_goal(params, target)
        return rollout(fab, p, sc.empty(cuboids=1), q0, qd0, fab.reached, dt=0.01, steps=300, stop_at_goal=False)

    tr = jax.jit(jax.vmap(one))(*(jnp.asarray(a, jnp.float32) for a in (starts, qd0, towards)))
    q, qd, qdd = np.asarray(tr.q), np.asarray(tr.qd), np.asarray(tr.qdd)
    tol = 1e-5
    assert np.all(q >= lo - tol) and np.all(q <= hi + tol)
    assert np.all(np.abs(qd) <= np.asarray(panda.velocity) + tol)
    assert np.all(np.abs(qdd) <= amax + tol)
    assert np.all(amax <= np.asarray(panda.acceleration))
    jerk = np.abs(np.diff(qdd[:, :-1], axis=1)) / 0.01  # the last row pads the final state
    assert np.all(jerk <= np.asarray(panda.jerk) + 1e-2)
    assert np.abs(qdd).max() > 0.5 * amax.min()  # the limits were actually reached, not avoided


def test_command_sequence_segments(fabric):
    """Two commands then the goal: segments run in order, each starting from the previous end state."""
    fab, params = fabric
    mid = jnp.asarray([0.6, -0.3, 0.1, -2.0, 0.0, 1.7, 0.8])
    seq = jax.tree.map(lambda *a: jnp.stack(a), *(fab.with_joint_goal(params, g) for g in (mid, GOAL)))
    tr = jax.jit(lambda s: rollout_sequence(fab, s, sc.empty(cuboids=1), READY, jnp.zeros(7), fab.reached, steps=700))(seq)
    assert bool(tr.reached)
    times = np.asarray(tr.segment_times)
    assert np.all(times < 7.0) and np.isclose(times.sum(), float(tr.t_goal), atol=1e-4)
    # the arm passed near the command before heading to the goal
    k = int(round(times[0] / 0.01))
    assert float(jnp.linalg.norm(tr.q[k] - mid)) <= fab.joint_tolerance + 1e-6
    n = int(tr.length)
    assert np.abs(np.diff(np.asarray(tr.q[:n]), axis=0)).max() < 0.05  # continuous


def test_batched_matches_single_and_exits_early(fabric, run, panda):
    """vmap over problems (goals, scenes of different sizes) equals one-by-one rollouts."""
    fab, params = fabric
    target = frame_pose(panda, GOAL, fab.goal_frame)
    problems = [
        make_problem(panda, READY, BOX, goal_q=GOAL),
        make_problem(panda, READY, {"obstacles": []}, goal_pose=(np.asarray(target.translation()), np.asarray(target.rotation().wxyz))),
        make_problem(panda, GOAL, {"obstacles": BOX["obstacles"] * 3}, goal_q=READY),
    ]
    tr = jax.jit(lambda b: reach(fab, params, b, dt=0.01, steps=700))(batch(problems))
    assert np.all(np.asarray(tr.reached))
    assert int(jnp.max(tr.length)) < 701  # the batch stopped once every arm was done
    one = run(fab.with_joint_goal(params, GOAL), sc.from_dict(BOX), READY, jnp.zeros(7))
    n = int(one.length)
    assert int(tr.length[0]) == n
    assert np.allclose(np.asarray(tr.q[0, :n]), np.asarray(one.q[:n]), atol=1e-4)


def _sequences(fab, params, goals):
    """Command sequences [mid_i, GOAL] as stacked params (P, 2, ...)."""
    seq = lambda g: jax.tree.map(lambda *a: jnp.stack(a), fab.with_joint_goal(params, g), fab.with_joint_goal(params, GOAL))  # noqa: E731
    return jax.tree.map(lambda *a: jnp.stack(a), *(seq(g) for g in goals))


def test_population_matches_vmap_and_stops_when_enough_arrived(fabric):
    """rollout_population == vmap(rollout_sequence); with enough=1 it stops at the first clean arrival."""
    fab, params = fabric
    mids = [READY + 0.5 * (GOAL - READY), jnp.asarray([-1.5, 0.5, 1.0, -1.0, 1.0, 2.5, -1.0]), GOAL + 0.2]
    seqs, scene = _sequences(fab, params, mids), sc.empty(cuboids=1)
    kw = dict(dt=0.01, steps=300)
    one = jax.jit(jax.vmap(lambda s: rollout_sequence(fab, s, scene, READY, jnp.zeros(7), fab.reached, **kw)))(seqs)
    pop = jax.jit(lambda s: rollout_population(fab, s, scene, READY, jnp.zeros(7), fab.reached, **kw))(seqs)
    assert np.array_equal(np.asarray(one.length), np.asarray(pop.length))
    assert np.allclose(np.asarray(one.q), np.asarray(pop.q), atol=1e-5)
    # only the goal terms per arm and segment, the rest shared: the same rollouts
    part = jax.jit(lambda s: rollout_population(fab, fab.aimed(s), scene, READY, jnp.zeros(7), fab.reached, shared=params, **kw))(seqs)
    assert set(fab.aimed(seqs)) < set(params) and np.array_equal(np.asarray(one.length), np.asarray(part.length))
    assert np.allclose(np.asarray(one.q), np.asarray(part.q), atol=1e-4)
    with pytest.raises(ValueError, match="not in `shared`"):
        rollout_population(fab, fab.aimed(seqs), scene, READY, jnp.zeros(7), fab.reached, shared={"goal": params["goal"]}, **kw)
    first = int(np.argmin(np.where(np.asarray(one.reached), np.asarray(one.length), 10**6)))
    early = jax.jit(lambda s: rollout_population(fab, s, scene, READY, jnp.zeros(7), fab.reached, enough=1, **kw))(seqs)
    assert bool(early.reached[first]) and int(early.reached.sum()) < int(one.reached.sum())
    assert int(jnp.max(early.length)) <= int(one.length[first]) + 25  # stopped at the chunk after the first arrival
    stopped = ~np.asarray(early.reached)
    assert np.all(np.asarray(early.segment_times)[stopped, -1] == pytest.approx(3.0))  # unfinished: charged the budget


def test_population_shrinks_to_its_running_arms(fabric):
    """32 commands that take from a few to hundreds of steps: the population that goes on with its
    running arms alone (shrink=2, sub-batch of 16) returns the unshrunk population's trajectories,
    with and without a stop once `enough` (28) arrived."""
    fab, params = fabric
    rng = np.random.default_rng(5)
    mids = [READY + s * (GOAL - READY) + rng.normal(scale=0.3 * s, size=7) for s in rng.uniform(0.0, 1.5, 32)]
    seqs, scene = _sequences(fab, params, [jnp.asarray(m, jnp.float32) for m in mids]), sc.from_dict(BOX)
    for enough in (None, 28):
        kw = dict(dt=0.01, steps=300, enough=enough)
        run = lambda k: jax.jit(lambda s: rollout_population(fab, s, scene, READY, jnp.zeros(7), fab.reached, shrink=k, **kw))(seqs)  # noqa: E731
        plain, shrunk = run(1), run(2)
        lengths = np.asarray(plain.length)
        assert np.sort(lengths)[-17] < np.max(lengths) - 50  # the last 16 arms run 50 steps or more alone
        assert np.array_equal(lengths, np.asarray(shrunk.length))
        assert np.allclose(np.asarray(plain.q), np.asarray(shrunk.q), atol=1e-4)
        assert np.array_equal(np.asarray(plain.reached), np.asarray(shrunk.reached))
    with pytest.raises(ValueError, match="shrink"):
        rollout_population(fab, seqs, scene, READY, jnp.zeros(7), fab.reached, shrink=0)


def test_patience_ends_a_segment_that_makes_no_progress(fabric, panda):
    """A box around the hand at the command: the arm presses on it; with patience the segment
    ends early and is charged t_max, and the next command runs from there."""
    fab, params = fabric
    hand = np.asarray(frame_pose(panda, GOAL, fab.goal_frame).translation())
    scene = sc.from_dict({"obstacles": [{"type": "cuboid", "center": hand.tolist(), "size": [0.25, 0.25, 0.25]}]})
    seqs = _sequences(fab, params, [GOAL])
    dist = lambda p, q: jnp.linalg.norm(q - p["goal"]["target"])  # noqa: E731
    kw = dict(dt=0.01, steps=500)
    full = jax.jit(lambda s: rollout_population(fab, s, scene, READY, jnp.zeros(7), fab.reached, **kw))(seqs)
    cut = jax.jit(lambda s: rollout_population(fab, s, scene, READY, jnp.zeros(7), fab.reached, patience=(dist, 0.5, 0.01), **kw))(seqs)
    assert not bool(full.reached[0])  # trapped: the test needs a blocked command
    assert int(cut.length[0]) < int(full.length[0]) // 2
    assert np.allclose(np.asarray(cut.segment_times[0]), 5.0)  # both segments charged their budget


def test_full_speed_sweeps_never_penetrate(fabric, panda):
    """Every joint at its velocity limit toward a wall, a thin board or a box edge, the joint goal
    beyond it: the fabric stops every sweep that the joint acceleration limits can stop (the exact
    checker finds no penetration), where the thesis' eq. 3.9 limiter lets some through."""
    from fabrax.problems.sweeps import sweeps

    fab, params = fabric
    problems = sweeps(panda, 45, seed=11, default_q=READY)
    assert {p.kind for p in problems} == {"sweep_wall", "sweep_board", "sweep_edge"}

    def run_all(limits):
        tr = jax.jit(lambda b: reach(fab, params, b, "joint", dt=0.01, steps=200, stop_at_goal=False, limits=limits))(batch(problems))
        q = np.asarray(tr.q)
        return [check_path(panda, p.scene, q[k]) for k, p in enumerate(problems)]

    checks = run_all(True)
    assert not any(c.scene_collision for c in checks), [round(c.min_clearance * 1000, 1) for c in checks if c.scene_collision]
    assert min(c.min_clearance for c in checks) < 0.05  # the sweeps did come close
    assert any(c.scene_collision for c in run_all("shrink"))


def test_goals_on_joint_limits_are_reached(fabric, panda):
    """Joint goals with joints exactly at their limits (as many MotionBenchMaker goals are): reached, limits kept."""
    fab, params = fabric
    lo, hi = np.asarray(panda.lower), np.asarray(panda.upper)
    goals = [np.asarray(GOAL).copy() for _ in range(3)]
    goals[0][1], goals[1][5], goals[2][4] = hi[1], hi[5], lo[4]
    goals[2][6] = hi[6]
    for g in goals:
        tr = jax.jit(lambda p: rollout(fab, p, sc.empty(cuboids=1), READY, jnp.zeros(7), fab.reached, dt=0.01, steps=700))(
            fab.with_joint_goal(params, jnp.asarray(g))
        )
        assert bool(tr.reached), g
        q = np.asarray(tr.q[: int(tr.length)])
        assert np.all(q >= lo - 1e-5) and np.all(q <= hi + 1e-5)


def test_no_chattering_at_rest(fabric, panda):
    """Started at rest on its goal, beside an obstacle, the fabric stays there (joint and pose aims)."""
    fab, params = fabric
    hand = np.asarray(frame_pose(panda, GOAL, fab.goal_frame).translation())
    wall = sc.from_dict({"obstacles": [{"type": "cuboid", "center": (hand + [0.0, 0.0, -0.17]).tolist(), "size": [0.3, 0.3, 0.02]}]})
    target = frame_pose(panda, GOAL, fab.goal_frame)
    for p in (fab.with_joint_goal(params, GOAL), fab.with_pose_goal(params, target.translation(), target.rotation().wxyz, GOAL)):
        tr = jax.jit(lambda pp: rollout(fab, pp, wall, GOAL, jnp.zeros(7), fab.reached, dt=0.01, steps=300, stop_at_goal=False))(p)
        assert float(tr.min_clearance) < 0.1  # the repulsion acts
        assert float(jnp.abs(tr.q - GOAL).max()) < 2e-3
        assert float(jnp.abs(tr.qd[-2]).max()) < 1e-3


def test_sliding_along_a_surface_is_pushed_off(panda):
    """k_slide: a sphere moving along a wall (distance rate 0) gets a geometric push away from it."""
    from fabrax.fabrics.terms import TermInputs, obstacle_repulsion
    from fabrax.robot import point_kinematics

    q = jnp.asarray(READY)
    kin0 = point_kinematics(panda, q, jnp.zeros(7), panda.collision.frame, panda.collision.local)
    s = 40
    c, r = np.asarray(kin0.x[:, s]), float(panda.collision.radius[s])
    wall = sc.from_dict(
        {"obstacles": [{"type": "cuboid", "center": [float(c[0]), float(c[1]), float(c[2]) - r - 0.03 - 0.01], "size": [2.0, 2.0, 0.02]}]}
    )
    jac = np.asarray(kin0.jac[:, :, s])
    qd = jnp.asarray(np.linalg.lstsq(jac, np.array([0.5, 0.0, 0.0]), rcond=None)[0], jnp.float32)  # sphere s slides along x
    kin = point_kinematics(panda, q, qd, panda.collision.frame, panda.collision.local)
    inputs = TermInputs(q, qd, kin, wall, panda)
    pushes = []
    for k_slide in (0.0, 0.5):
        t = obstacle_repulsion(k_slide=k_slide)
        pushes.append(-(jac[2] @ np.asarray(t.apply(t.init(), inputs).f_geom)))  # upward part of -f_geom through sphere s
    assert abs(float(kin.xd[2, s])) < 1e-3
    assert pushes[1] > pushes[0] + 1e-3


def test_bad_start_and_goal_raise_named_field(fabric):
    """A NaN start (concrete, even when closed over inside jit) and wrong-length goals are refused at
    the call, naming the argument, instead of an all-NaN trajectory or an XLA broadcasting error."""
    fab, params = fabric
    p = fab.with_joint_goal(params, GOAL)
    nan_start = READY.at[2].set(jnp.nan)
    with pytest.raises(ValueError, match="q0: NaN"):
        jax.jit(lambda p: rollout(fab, p, sc.empty(cuboids=1), nan_start, jnp.zeros(7), fab.reached, steps=10))(p)
    with pytest.raises(ValueError, match="qd0: expected 7 values"):
        rollout(fab, p, sc.empty(cuboids=1), READY, jnp.zeros(6), fab.reached, steps=10)
    with pytest.raises(ValueError, match="q_goal: expected 7 values"):
        fab.with_joint_goal(params, GOAL[:6])
    with pytest.raises(ValueError, match="quat_wxyz: expected 4"):
        fab.with_pose_goal(params, jnp.zeros(3), jnp.zeros(3))
