"""Arms other than the Panda, end to end: every shipped arm (configs/robot) builds from its URDF in
example-robot-data, its kinematics is the URDF's, its fabric keeps the theory's properties, the
generators pose problems in its workspace and its fabric solves one, the RL env (kinematic and
MJX) steps it, GFCS plans for it, and MotionBenchMaker's Panda problems are refused for it."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fabrax import config
from fabrax import scene as sc
from fabrax.check.checker import check_path
from fabrax.fabrics import unforced
from fabrax.problems import batch, procedural
from fabrax.robot import resolve_urdf
from fabrax.robot.kinematics import frame_pose
from fabrax.rollout import integrate, reach

ARMS = ("ur5", "xarm7", "kinova")


@pytest.fixture(scope="module", params=ARMS)
def arm(request):
    robot = config.load_robot(request.param)
    fabric, params = config.load_fabric(robot)
    return request.param, robot, fabric, params


def test_each_arm_builds_with_its_end_effector(arm):
    name, robot, fabric, _ = arm
    cfg = config.load("robot", name)
    assert robot.dof == len(cfg["active_joints"]) and tuple(robot.joint_names) == tuple(cfg["active_joints"])
    assert robot.ee_frame == cfg["ee_frame"] and fabric.goal_frame == robot.ee_frame  # the fabric's goal frame derives from it
    assert np.all(np.isfinite(np.asarray(robot.lower))) and np.all(np.asarray(robot.lower) < np.asarray(robot.upper))
    np.testing.assert_allclose(np.asarray(robot.ready_q), cfg["default_q"], atol=1e-6)
    assert robot.n_spheres > 20 and len(robot.collision.pair_i) > 0  # collision spheres and self-collision pairs
    assert np.asarray(robot.keypoint_local).shape == (8, 3)


def test_forward_kinematics_is_the_urdfs(arm):
    """Every link pose from fabrax's kinematics equals yourdfpy's for random configurations."""
    yourdfpy = pytest.importorskip("yourdfpy")
    name, robot, _, _ = arm
    urdf = yourdfpy.URDF.load(str(resolve_urdf(config.load("robot", name)["urdf"])), load_meshes=False, build_scene_graph=True)
    actuated = list(urdf.actuated_joint_names)
    rng = np.random.default_rng(0)
    links = [lk for lk in robot.frame_names if lk in urdf.link_map]
    for q in rng.uniform(np.asarray(robot.lower), np.asarray(robot.upper), (4, robot.dof)):
        cfg = np.zeros(len(actuated))
        for j, jn in enumerate(robot.joint_names):
            cfg[actuated.index(jn)] = q[j]
        urdf.update_cfg(cfg)
        base = np.linalg.inv(urdf.get_transform(urdf.base_link))  # fabrax's world is the URDF's root link
        for lk in links:
            want = base @ urdf.get_transform(lk)
            got = frame_pose(robot, jnp.asarray(q, jnp.float32), lk).as_matrix()
            np.testing.assert_allclose(np.asarray(got), want, atol=2e-5, err_msg=f"{name}: {lk}")


def test_fabric_conserves_energy_and_its_metric_is_positive_definite(arm):
    """Thesis eq. 2.29 on this arm: the unforced, undamped fabric with eq. 2.26's energization
    conserves H_e next to an obstacle, and its metric is symmetric positive definite. Self-collision
    at sphere resolution: the link resolution's distance is the closest sphere pair's, whose
    direction jumps where that pair changes (a min, not smooth), and H_e jumps with it."""
    _, robot, _, _ = arm
    fabric_cfg = config.load("fabric", "panda")
    fabric_cfg["terms"]["self_collision"]["resolution"] = "sphere"
    fab, params = config.load_fabric(robot, fabric_cfg)
    hand = np.asarray(frame_pose(robot, robot.ready_q, robot.ee_frame).translation())
    bar = sc.from_dict({"obstacles": [{"type": "cuboid", "center": (hand + [0.0, 0.2, 0.0]).tolist(), "size": [0.1, 0.06, 0.1]}]})
    fab = dataclasses.replace(fab, energization="conservative")
    with jax.enable_x64(True):
        to64 = lambda t: jax.tree.map(lambda a: jnp.asarray(a, jnp.float64) if jnp.issubdtype(jnp.asarray(a).dtype, jnp.floating) else a, t)  # noqa: E731
        p = fab.with_pose_goal(params, jnp.asarray(hand + [0.1, 0.1, -0.05]), jnp.asarray([0.0, 1.0, 0.0, 0.0]))
        p = to64(unforced(p, fab))
        scene = to64(bar)
        q0 = jnp.asarray(robot.ready_q, jnp.float64)
        qd0 = jnp.asarray(np.random.default_rng(2).normal(scale=0.4, size=robot.dof), jnp.float64)

        def body(c, _):
            q, qd = c
            qn, qdn, _, clearance = integrate(fab, p, scene, q, qd, 1e-3, "rk4", limits=False)
            return (qn, qdn), (fab.evaluate(p, scene, qn, qdn).energy, clearance)

        energy, clearance = jax.jit(lambda q, qd: jax.lax.scan(body, (q, qd), None, length=600)[1])(q0, qd0)
        e0 = fab.evaluate(p, scene, q0, qd0).energy
        assert 0.0 < float(clearance.min()) < 0.15, "the repulsion terms should be active in this check, without contact"
        assert float(jnp.max(jnp.abs(energy - e0)) / e0) <= 1e-3
    rng = np.random.default_rng(1)
    qs = jnp.asarray(rng.uniform(np.asarray(robot.lower), np.asarray(robot.upper), (32, robot.dof)), jnp.float32)
    qds = jnp.asarray(rng.normal(size=(32, robot.dof)), jnp.float32)
    metric = jax.jit(jax.vmap(lambda q, qd: fab.evaluate(params, bar, q, qd).metric))(qs, qds)
    assert jnp.allclose(metric, jnp.swapaxes(metric, 1, 2), atol=1e-5) and float(jnp.linalg.eigvalsh(metric).min()) > 0.0


def test_generated_problems_sit_in_the_arms_workspace_and_the_fabric_solves_one(arm):
    """MBM-like problems carried into the arm's workspace are valid; the fabric reaches a cage
    goal (an open enclosure) from the ready posture without collision."""
    _, robot, fab, params = arm
    problems = procedural.generate(robot, "mbm_like", ["cage", "box"], 2, seed=0)
    assert len(problems) == 4 and all(p.valid for p in problems)
    assert all(np.allclose(p.start_q, np.asarray(robot.ready_q), atol=1e-6) for p in problems)  # the arm's own ready posture
    tr = reach(fab, params, batch(problems), dt=0.01, steps=700)
    reached = np.asarray(tr.reached)
    assert reached.sum() >= 2, f"reached {reached.tolist()}"
    for k, p in enumerate(problems):
        q = np.asarray(tr.q[k, : int(tr.length[k])])
        assert not check_path(robot, p.scene, q).collision, p.name


def test_rl_env_steps_the_arm_in_both_backends():
    """The guide's environment for the UR5 (6 joints): both backends reset and step; MJX's arm
    tracks the fabric's."""
    from fabrax.rl import make_env

    cfg = {"substeps": 5, "scenes": {"generated": {"cuboid_forest": 1, "flying_cuboids": 1}, "configs_per_scene": 2}}
    qs = {}
    for backend in ("kinematic", "mjx"):
        env = make_env({**cfg, "backend": backend}, config.load("robot", "ur5"), config.load("fabric", "panda"))
        assert env.robot.dof == 6
        s = jax.jit(env.reset)(jax.random.PRNGKey(0))
        step = jax.jit(env.step)
        for a in jax.random.uniform(jax.random.PRNGKey(1), (4, env.action_size), minval=-1, maxval=1):
            s = step(s, a)
        assert np.all(np.isfinite(np.asarray(s.obs["state"] if isinstance(s.obs, dict) and "state" in s.obs else s.pipeline_state.q)))
        qs[backend] = np.asarray(s.pipeline_state.q)
    assert np.abs(qs["kinematic"] - qs["mjx"]).max() < 0.03


def test_gfcs_plans_for_a_six_joint_arm():
    """GFCS (gfcs_paper) on one generated Kinova problem: commands of the arm's size, a clean arrival."""
    from fabrax.planners.gfcs import GFCSConfig, solve
    from fabrax.problems import ProblemBatch

    robot = config.load_robot("kinova")
    fab, params = config.load_fabric(robot)
    p = procedural.generate(robot, "mbm_like", ["box"], 1, seed=3)[0]
    res = solve(fab, params, ProblemBatch.of(p), jax.random.PRNGKey(0), GFCSConfig(population=16, batches=2))
    assert np.asarray(res.best_commands).shape[-1] == robot.dof
    tr = res.trajectory
    assert bool(tr.reached)
    assert not check_path(robot, p.scene, np.asarray(tr.q[: int(tr.length)])).collision


def test_motionbenchmaker_problems_are_refused_for_another_arm(capsys):
    from fabrax.bench.cli import main

    with pytest.raises(SystemExit, match="problems=mbm are MotionBenchMaker's Panda problems; robot=ur5 cannot run them"):
        main(["robot=ur5", "method=gf", "problems=mbm", "limit=1", "progress=false", "out=/nonexistent/never"])


def test_a_continuous_joint_without_limits_is_one_line():
    cfg = config.load("robot", "kinova")
    cfg["limits"] = {k: v for k, v in cfg["limits"].items() if k != "j2s6s200_joint_4"}
    with pytest.raises(ValueError, match=r"robot.limits.j2s6s200_joint_4: the URDF gives this joint no limits"):
        config.load_robot(cfg)
    with pytest.raises(ValueError, match="robot.urdf: 'nowhere/arm.urdf' not found: neither a file nor a path inside example-robot-data"):
        config.load_robot({**cfg, "urdf": "nowhere/arm.urdf"})


def test_viewer_shows_another_arm_and_solves_its_demo(free_port):
    """`fabrax view demo --robot kinova`: the arm's meshes load, the camera frames its own end
    effector and the demo's shelf goal, carried into its workspace, is reached."""
    from fabrax.viz.app import Viewer, view_demo

    viewer = Viewer("kinova", port=free_port)
    try:
        assert viewer.frame == "kinova_hand"
        info = view_demo(viewer)
        assert info["reached"] and len(viewer.ghosts) == 1
    finally:
        viewer.close()


def test_mpinets_faithful_problems_are_carried_to_another_arm():
    """The MπNets-faithful families for the xArm7 (scaled by its reach, no tool): each problem is
    valid, its goal configuration puts `ee_frame` on the goal pose and its tool centre point on the
    TCP goal, and the problems differ from the Panda's only by the carry (same families and types)."""
    from fabrax.problems import mpinets
    from fabrax.problems.workspace import _z_axis

    robot = config.load_robot("xarm7")
    fit = mpinets.Fit.of(robot, robot.ee_frame)
    assert 0.7 < fit.scale < 0.9 and fit.offset == 0.0 and fit != mpinets.Fit()
    drawn = mpinets.generate(robot, 3, seed=0, classes=["cubby", "tabletop"])
    assert len(drawn.problems) == 3
    for p in drawn.problems:
        assert p.valid, p.reason
        pose = frame_pose(robot, jnp.asarray(p.meta["goal_q"], jnp.float32), robot.ee_frame)
        np.testing.assert_allclose(np.asarray(pose.translation()), p.goal_pose[0], atol=2e-3)
        tcp = np.asarray(p.goal_pose[0]) + fit.offset * _z_axis(np.asarray(p.goal_pose[1]))
        np.testing.assert_allclose(tcp, p.meta["tcp_goal"][0], atol=1e-6)
        assert (p.meta["family"], p.meta["problem_type"]) == mpinets.draw(0, int(p.name.split("/")[-1]))


def test_a_problem_the_generator_cannot_pose_is_one_invalid_problem(panda):
    """A class that finds no valid problem in its tries is reported invalid with the reason; the set
    goes on (the bench counts it in its summary)."""
    p = procedural._one(panda, "bookshelf", np.random.default_rng(0), "bookshelf/0000", "panda_hand", tries=0)
    assert not p.valid and p.reason == "could not generate a valid 'bookshelf' problem in 0 tries" and p.name == "bookshelf/0000"
