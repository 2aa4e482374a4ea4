import numpy as np
import pytest

from fabrax import config
from fabrax.bench import check_path
from fabrax.demo import main as demo_main
from fabrax.fabrics import build_arm_fabric
from fabrax.problems import make_problem
from fabrax.problems.generators import demo_problem, flying_cuboids, random_problems

READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
WALL = {"obstacles": [{"type": "cuboid", "center": [0.3, 0.0, 0.6], "size": [0.3, 0.3, 0.3]}]}


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(start_q=[0, 0, 0, -5.0, 0, 1.5, 0], goal_q=READY), r"start_q\[3\]"),
        (dict(start_q=READY, goal_q=[3.5, 0, 0, -1, 0, 1.5, 0]), r"goal_q\[0\]"),
        (dict(start_q=[0, float("nan"), 0, -2, 0, 1.5, 0], goal_q=READY), "start_q: NaN"),
        (dict(start_q=READY, goal_q=READY[:6]), "goal_q: expected 7"),
        (dict(start_q=READY), "needs goal_q or goal_pose"),
        (dict(start_q=READY, goal_pose=([0.4, 0, 0.5], [2.0, 0, 0, 0])), "unit quaternion"),
    ],
)
def test_bad_problem_raises_named_field(panda, kwargs, field):
    with pytest.raises(ValueError, match=field):
        make_problem(panda, scene={"obstacles": []}, **kwargs)


def test_loaded_problem_with_nan_is_flagged_not_run(panda):
    """Loaders build Problems directly and `flag` them: NaN in a state or the scene (which fails no
    comparison) marks the problem invalid with the field's name instead of crashing a run later."""
    import dataclasses

    from fabrax.problems import flag

    p = make_problem(panda, READY, {"obstacles": [{"type": "cuboid", "center": [1.0, 1.0, 0.6], "size": [0.1] * 3}]}, goal_q=READY)
    q = np.array(READY)
    q[2] = np.nan
    assert flag(panda, p).valid
    bad = flag(panda, dataclasses.replace(p, start_q=q))
    assert not bad.valid and "start_q" in bad.reason
    center = np.asarray(p.scene.cuboids.center).copy()
    center[0, 0] = np.inf
    bad = flag(panda, dataclasses.replace(p, scene=p.scene.replace(cuboids=p.scene.cuboids.replace(center=center))))
    assert not bad.valid and "scene.cuboids.center" in bad.reason


def test_start_in_collision_is_rejected(panda):
    with pytest.raises(ValueError, match="start_q is in collision"):
        make_problem(panda, READY, WALL, goal_q=READY)


def test_bad_scene_and_config_keys(panda):
    with pytest.raises(ValueError, match=r"obstacles\[0\]\.size"):
        make_problem(panda, READY, {"obstacles": [{"type": "cuboid", "center": [2, 2, 2], "size": [-1, 1, 1]}]}, goal_q=READY)
    cfg = config.load("fabric", "panda")
    cfg["terms"]["goal"]["k_forcee"] = 1.0
    with pytest.raises(ValueError, match="unknown fabric term 'goal' parameter keys.*k_forcee"):
        build_arm_fabric(panda, cfg)
    with pytest.raises(ValueError, match="unknown fabric config keys"):
        build_arm_fabric(panda, {"terms": {}, "gains": 1})
    with pytest.raises(ValueError, match="no config 'nope'"):
        config.load("fabric", "nope")


def test_random_problems_are_deterministic_and_valid(panda):
    rng = np.random.default_rng(3)
    scenes = [flying_cuboids(rng) for _ in range(3)]
    a = random_problems(panda, scenes, seed=5)
    b = random_problems(panda, scenes, seed=5)
    for pa, pb in zip(a, b):
        assert np.array_equal(pa.start_q, pb.start_q) and np.array_equal(pa.goal_q, pb.goal_q)
        for q in (pa.start_q, pa.goal_q):
            assert not check_path(panda, pa.scene, q[None]).collision
    c = random_problems(panda, scenes, seed=6)
    assert not np.array_equal(a[0].start_q, c[0].start_q)
    poses = random_problems(panda, scenes[:1], seed=5, goal="pose")
    assert poses[0].goal_pose is not None and poses[0].goal_q is None


def test_demo_reaches_without_collision(tmp_path, panda):
    problem = demo_problem(panda)
    assert not check_path(panda, problem.scene, problem.goal_q[None]).collision
    out = tmp_path / "demo.npz"
    assert demo_main(["--out", str(out)]) == 0
    data = np.load(out)
    assert data["q"].shape[1] == 7 and np.allclose(data["q"][0], READY, atol=1e-6)
    assert np.linalg.norm(data["q"][-1] - problem.goal_q) <= 0.05


def test_problem_batch_gives_every_problem_a_goal_pose(panda):
    """`batch` stacks problems into one typed `ProblemBatch`; `with_goal_poses` keeps a pose goal as
    given and gives a joint goal the pose of the goal frame at that configuration (forward kinematics)."""
    import jax.numpy as jnp

    from fabrax.problems import ProblemBatch, batch
    from fabrax.robot.kinematics import frame_pose

    goal_q = np.asarray([0.3, -0.5, 0.2, -2.0, 0.1, 1.8, 0.5])
    pose = (np.asarray([0.45, 0.1, 0.4]), np.asarray([0.0, 1.0, 0.0, 0.0]))
    empty = {"obstacles": []}
    joint = make_problem(panda, scene=empty, start_q=READY, goal_q=goal_q, name="joint")
    posed = make_problem(panda, scene=empty, start_q=READY, goal_pose=pose, name="pose")
    b = batch([joint, posed])
    assert isinstance(b, ProblemBatch) and len(b) == 2
    assert b.joint_goal.tolist() == [True, False] and b.has_pose.tolist() == [False, True]
    full = b.with_goal_poses(panda, "panda_hand")
    want = frame_pose(panda, jnp.asarray(goal_q, jnp.float32), "panda_hand")
    np.testing.assert_allclose(full.goal_pos[0], want.translation(), atol=1e-5)
    np.testing.assert_allclose(abs(float(jnp.dot(full.goal_quat[0], want.rotation().wxyz))), 1.0, atol=1e-5)
    np.testing.assert_allclose(full.goal_pos[1], pose[0], atol=1e-6)
    np.testing.assert_allclose(full.goal_quat[1], pose[1], atol=1e-6)
    assert bool(full.has_pose.all())
