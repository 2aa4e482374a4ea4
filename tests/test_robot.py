import json
import re

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from scipy.spatial import cKDTree

from fabrax import config
from fabrax.robot import build_robot, link_poses, panda_urdf, parse_urdf, point_kinematics, points, sphere_centers
from fabrax.robot import spheres as sphere_lib

TWO_LINK = """<?xml version="1.0"?>
<robot name="planar">
  <link name="base"><collision><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision></link>
  <link name="upper"><collision><origin xyz="0.15 0 0" rpy="0 1.5707963 0"/><geometry><cylinder radius="0.03" length="0.3"/></geometry></collision>
    <inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="fore"><collision><origin xyz="0.1 0 0"/><geometry><box size="0.2 0.04 0.04"/></geometry></collision>
    <inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="slider"><collision><geometry><sphere radius="0.03"/></geometry></collision>
    <inertial><mass value="0.1"/><inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.1" rpy="0.3 0 0"/>
    <axis xyz="0 0.6 0.8"/><limit lower="-2" upper="2" velocity="1" effort="1"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/><origin xyz="0.3 0 0" rpy="0 0 0.2"/>
    <axis xyz="0 0 1"/><limit lower="-2" upper="2" velocity="1" effort="1"/></joint>
  <joint name="slide" type="prismatic"><parent link="fore"/><child link="slider"/><origin xyz="0.2 0 0"/>
    <axis xyz="1 0 0"/><limit lower="0" upper="0.1" velocity="1" effort="1"/></joint>
</robot>
"""


def mujoco_model(urdf_text: str) -> mujoco.MjModel:
    xml = re.sub(r"<visual>.*?</visual>", "", urdf_text, flags=re.S)
    xml = re.sub(r"<collision>.*?</collision>", "", xml, flags=re.S)
    xml = re.sub(r"<robot ([^>]*)>", r'<robot \1><mujoco><compiler fusestatic="false" discardvisual="true"/></mujoco>', xml, count=1)
    return mujoco.MjModel.from_xml_string(xml)


def compare_with_mujoco(robot, urdf_text, held, n=50, seed=0):
    model = mujoco_model(urdf_text)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    poses = jax.jit(jax.vmap(lambda q: link_poses(robot, q)))
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    qs = rng.uniform(lo, hi, (n, robot.dof))
    ours = poses(jnp.asarray(qs, jnp.float32))
    names = [model.body(i).name for i in range(model.nbody)]
    worst = 0.0
    for k, q in enumerate(qs):
        for i, jname in enumerate(robot.joint_names):
            data.qpos[model.joint(jname).qposadr[0]] = q[i]
        for jname, v in held.items():
            data.qpos[model.joint(jname).qposadr[0]] = v
        mujoco.mj_kinematics(model, data)
        for li, lname in enumerate(robot.frame_names[: len(ours.translation()[0])]):
            if lname not in names:
                continue
            b = names.index(lname)
            worst = max(worst, float(np.abs(np.asarray(ours.translation()[k, li]) - data.xpos[b]).max()))
            rot = np.asarray(ours.rotation().as_matrix()[k, li])
            assert np.allclose(rot, data.xmat[b].reshape(3, 3), atol=1e-5), lname
    return worst


def test_fk_matches_mujoco_panda(panda):
    held = {"panda_finger_joint1": 0.04, "panda_finger_joint2": 0.04}
    worst = compare_with_mujoco(panda, panda_urdf().read_text(), held)
    assert worst <= 1e-5


@pytest.fixture(scope="module")
def planar(tmp_path_factory):
    """`TWO_LINK` built from its URDF: tilted axes, a prismatic joint, primitive collisions."""
    path = tmp_path_factory.mktemp("planar") / "planar.urdf"
    path.write_text(TWO_LINK)
    return build_robot({"urdf": str(path), "spheres": {"budget": 8}, "self_collision": {"samples": 100}})


def test_any_urdf_arm(planar):
    """A non-Panda arm with tilted axes, a prismatic joint and primitive collisions."""
    robot = planar
    assert robot.dof == 3 and robot.joint_revolute == (True, True, False)
    assert compare_with_mujoco(robot, TWO_LINK, {}) <= 1e-5
    assert robot.n_spheres <= 8 and set(robot.collision.link_names) == {"base", "upper", "fore", "slider"}


def test_point_kinematics_against_finite_differences(panda):
    with jax.enable_x64(True):
        rng = np.random.default_rng(1)
        q = jnp.asarray(rng.uniform(panda.lower, panda.upper), jnp.float64)
        qd = jnp.asarray(rng.normal(size=7), jnp.float64)
        frame, local = panda.collision.frame, panda.collision.local.astype(jnp.float64)
        kin = point_kinematics(panda, q, qd, frame, local)
        x, xd, jdqd, jac = kin.x.T, kin.xd.T, kin.jdqd.T, kin.jac.transpose(2, 0, 1)  # (N, 3), (N, 3, n)
        f = lambda q_: sphere_centers(panda, q_)  # noqa: E731
        eps = 1e-6
        fd_jac = jnp.stack([(f(q + eps * e) - f(q - eps * e)) / (2 * eps) for e in jnp.eye(7)], -1)
        assert jnp.allclose(x, f(q), atol=1e-6)
        assert jnp.allclose(jac, fd_jac, atol=1e-5)
        assert jnp.allclose(xd, jnp.einsum("sij,j->si", jac, qd), atol=1e-9)
        # Jdot qd = d/dt (J qd) along qd: second directional difference of positions
        fd_curv = (f(q + 1e-4 * qd) - 2 * f(q) + f(q - 1e-4 * qd)) / 1e-8
        assert jnp.allclose(jdqd, fd_curv, atol=1e-4)


def test_limits_from_urdf_and_config(panda):
    assert np.allclose(panda.lower, [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
    assert np.allclose(panda.velocity, [2.175] * 4 + [2.61] * 3)
    assert np.allclose(panda.acceleration, [15, 7.5, 10, 12.5, 15, 20, 20])
    assert np.allclose(panda.jerk, [7500, 3750, 5000, 6250, 7500, 10000, 10000])


def test_limits_match_shared_file(panda, shared_data):
    limits = json.loads((shared_data / "panda_limits.json").read_text())
    for key in ("position_lower", "position_upper", "velocity", "acceleration", "jerk"):
        ours = {"position_lower": panda.lower, "position_upper": panda.upper}.get(key, getattr(panda, key, None))
        assert np.allclose(ours, limits[key], atol=1e-6), key


def test_fitted_spheres_cover_collision_meshes():
    """Every surface sample (drawn independently of the fit) lies within 5 mm of a sphere."""
    tree = parse_urdf(panda_urdf(), held={"panda_finger_joint1": 0.04})
    spheres = sphere_lib.fitted_spheres(tree, 60)
    assert sum(map(len, spheres.values())) <= 60
    for link, meshes in sphere_lib.link_meshes(tree).items():
        pts, _ = sphere_lib.sample_surface(meshes, 0.002, seed=12345)
        c = np.array([s["center"] for s in spheres[link]])
        r = np.array([s["radius"] for s in spheres[link]])
        gap = (np.sqrt(((pts[:, None] - c[None]) ** 2).sum(-1)) - r).min(1)
        assert gap.max() <= 0.005, f"{link}: a surface point is {gap.max() * 1000:.1f} mm outside every sphere"
        # and the cover is tight: no sphere centre lies outside the link's geometry
        inside = np.zeros(len(c), bool)
        for m in meshes:
            inside |= m.contains(c)
        assert inside.all(), link
        assert cKDTree(pts).query(c)[0].min() >= 0.0


def test_sphere_set_from_file(shared_data):
    cfg = config.load("robot", "panda")
    cfg["spheres"] = {"source": "file", "file": str(shared_data / "panda_spheres.json"), "set": "curobo"}
    robot = build_robot(cfg)
    assert robot.n_spheres == 61
    assert robot.collision.pair_i.shape[0] > 0


def test_self_collision_pairs(panda):
    frame = np.asarray(panda.collision.frame)
    i, j = np.asarray(panda.collision.pair_i), np.asarray(panda.collision.pair_j)
    assert len(i) > 100
    assert np.all(frame[i] != frame[j])
    parents = np.concatenate([[-1], np.asarray(panda.joint_parent) + 1])
    assert not np.any(parents[frame[i]] == frame[j]) and not np.any(parents[frame[j]] == frame[i])
    # the ready posture is free of self-collision under the kept pairs
    x = sphere_centers(panda, jnp.asarray(config.load("robot", "panda")["default_q"], jnp.float32))
    gap = jnp.linalg.norm(x[i] - x[j], axis=-1) - panda.collision.radius[i] - panda.collision.radius[j]
    assert float(gap.min()) > 0


@pytest.mark.parametrize("robot_name", ["panda", "panda_mbm"])
def test_closest_link_pairs_is_the_brute_force_minimum(robot_name, panda, request):
    """The closest-pair search finds, for every checked pair of links, a checked sphere pair of that
    link pair whose gap is the smallest over all of its checked sphere pairs (random states, within
    the packing's resolution), per arm and arms-minor alike. panda_mbm (the MotionBenchMaker spheres, up to 15 chunks per link
    pair) reads its spheres from FABRAX_DATA."""
    from fabrax.robot.collision import closest_link_pairs, closest_minor, search_tables

    if robot_name == "panda_mbm":
        request.getfixturevalue("shared_data")  # skips without the data
    robot = panda if robot_name == "panda" else config.load_robot("panda_mbm")
    i, j = np.asarray(robot.collision.pair_i), np.asarray(robot.collision.pair_j)
    link, r = np.asarray(robot.collision.link), np.asarray(robot.collision.radius)
    key = link[i] * 1000 + link[j]
    groups = [np.nonzero(key == k)[0] for k in np.unique(key)]
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    qs = jnp.asarray(rng.uniform(lo, hi, (64, robot.dof)), jnp.float32)
    xs = jax.vmap(lambda q: sphere_centers(robot, q))(qs)  # (B, S, 3)
    bi, bj = jax.jit(jax.vmap(lambda x: closest_link_pairs(robot.collision, x.T)))(xs)
    assert bi.shape == (64, len(groups))
    # the arms-minor search (the self-collision term's under vmap) picks the very same pairs
    mi, mj = jax.jit(lambda xt: closest_minor(xt, *search_tables(robot.collision)))(jnp.moveaxis(xs, 0, -1).swapaxes(0, 1))
    assert np.array_equal(np.asarray(mi).T, np.asarray(bi)) and np.array_equal(np.asarray(mj).T, np.asarray(bj))
    for x, ci, cj in zip(np.asarray(xs, np.float64), np.asarray(bi), np.asarray(bj)):
        gap = lambda a, b: np.linalg.norm(x[a] - x[b], axis=-1) - r[a] - r[b]  # noqa: E731
        for g, a, b in zip(groups, ci, cj):
            assert link[a] * 1000 + link[b] == key[g[0]]  # a sphere pair of this link pair
            assert gap(a, b) <= gap(i[g], j[g]).min() + 1e-4


def test_bad_robot_inputs(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot><link name='a'>")
    with pytest.raises(ValueError, match="malformed URDF"):
        build_robot({"urdf": str(bad)})
    with pytest.raises(ValueError, match="unknown robot config keys"):
        build_robot({"urdf": None, "budget": 3})
    with pytest.raises(ValueError, match="not found"):
        build_robot({"urdf": str(tmp_path / "missing.urdf")})
    with pytest.raises(ValueError, match="acceleration"):
        build_robot({"acceleration": [-1.0] * 7})


def test_self_collision_rows_are_the_jacobians_difference(panda, planar):
    """The self-collision rows u_a = (J_i - J_j)[:, a]^T n, built from the joint axes and origins alone
    (`terms.self_collision._pair_rows`), equal the difference of the point Jacobians for every pair of spheres on
    two frames, with a revolute and a prismatic arm; a joint that moves both spheres gives exactly 0."""
    from fabrax.fabrics.terms.self_collision import _pair_rows
    from fabrax.soa import cross0, dot0

    with jax.enable_x64(True):
        for robot in (panda, planar):
            rng = np.random.default_rng(4)
            q = jnp.asarray(rng.uniform(robot.lower, robot.upper))
            kin = point_kinematics(robot, q, jnp.zeros(robot.dof), robot.collision.frame, robot.collision.local.astype(jnp.float64))
            frame = np.asarray(robot.collision.frame)
            i, j = np.triu_indices(len(frame), 1)
            i, j = i[frame[i] != frame[j]], j[frame[i] != frame[j]]
            rel = kin.x[:, i] - kin.x[:, j]
            n = rel / jnp.linalg.norm(rel, axis=0)
            mi, mj = robot.ancestors[frame[i]].T, robot.ancestors[frame[j]].T
            rows = _pair_rows(
                robot.joint_revolute, mi & ~mj, mj & ~mi, kin.axes[:, :, None], cross0(kin.axes, kin.origins)[:, :, None], kin.x[:, i], kin.x[:, j], n
            )
            want = [dot0(kin.jac[:, a, i] - kin.jac[:, a, j], n) for a in range(robot.dof)]
            assert jnp.allclose(jnp.stack(rows), jnp.stack(want), atol=1e-12)
            assert not jnp.any(jnp.stack(rows)[np.asarray(mi & mj)])  # rigidly moved together: exactly 0


def test_point_kinematics_matches_forward_autodiff(panda, planar):
    """The recursive (analytic) kinematics equal nested jvps of FK, also with a prismatic joint."""
    with jax.enable_x64(True):
        for robot in (panda, planar):
            rng = np.random.default_rng(3)
            q = jnp.asarray(rng.uniform(robot.lower, robot.upper))
            qd = jnp.asarray(rng.normal(size=robot.dof))
            frame, local = robot.collision.frame, robot.collision.local.astype(jnp.float64)
            f = lambda q_: points(robot, q_, frame, local)  # noqa: E731
            (x, xd), (_, jdqd) = jax.jvp(lambda q_: jax.jvp(f, (q_,), (qd,)), (q,), (qd,))
            ours = point_kinematics(robot, q, qd, frame, local)
            assert jnp.allclose(ours.x, x.T, atol=1e-10)
            assert jnp.allclose(ours.jac, jnp.moveaxis(jax.jacfwd(f)(q), 0, -1), atol=1e-10)
            assert jnp.allclose(ours.xd, xd.T, atol=1e-10)
            assert jnp.allclose(ours.jdqd, jdqd.T, atol=1e-10)


def test_orientation_error_is_the_relative_rotation_angle():
    """`robot.goal.orientation_error` is the angle of target^-1 * q (jaxlie's log), for either
    quaternion sign and any norm, accurate near 0 (1e-6 rad) where 2 arccos|<a, b>| loses half
    its digits; the fabric's goal test, the bench's metrics and the RL env share one set of
    tolerances."""
    import jaxlie

    from fabrax.bench.metrics import Goal
    from fabrax.fabrics.arm import ArmFabric
    from fabrax.rl.config import EnvConfig
    from fabrax.robot.goal import TOLERANCE, orientation_error

    with jax.enable_x64(True):
        rng = np.random.default_rng(3)
        for k in range(20):
            target = jaxlie.SO3(jnp.asarray(rng.normal(size=4))).normalize()
            angle = 1e-6 if k == 0 else rng.uniform(0, np.pi)
            axis = rng.normal(size=3)
            q = target @ jaxlie.SO3.exp(jnp.asarray(angle * axis / np.linalg.norm(axis)))
            sign = -1.0 if k % 2 else 1.0
            got = orientation_error(sign * 3.0 * q.wxyz, target.wxyz)
            assert abs(float(got) - angle) < 1e-9 * max(1.0, angle / 1e-6)
    assert Goal().orientation_deg == TOLERANCE.orientation_deg and Goal().position == TOLERANCE.position
    assert ArmFabric.position_tolerance == TOLERANCE.position and ArmFabric.joint_tolerance == Goal().joint == TOLERANCE.joint
    assert EnvConfig().success_distance == Goal().keypoints == TOLERANCE.keypoints


def test_sphere_candidates_do_not_depend_on_trimesh_shared_generator():
    """trimesh re-casts ambiguous containment rays in a direction from its shared, entropy-seeded
    generator; the fit must not depend on it (the UR5's shoulder mesh has such rays), or one robot
    config gives other spheres, and other benchmark figures, in every fresh cache."""
    import trimesh

    from fabrax.robot.robot import resolve_urdf

    tree = parse_urdf(resolve_urdf("ur_description/urdf/ur5_joint_limited_robot.urdf"))
    meshes = sphere_lib.link_meshes(tree)["shoulder_link"]
    pts, normals = sphere_lib.sample_surface(meshes, 0.004, seed=0)
    runs, shared = [], trimesh.util._RANDOM_DEFAULT
    try:
        for shared_seed in (1, 2):
            trimesh.util._RANDOM_DEFAULT = np.random.default_rng(shared_seed)
            cand, _ = sphere_lib._candidates(meshes, pts, normals, np.random.default_rng(0), 5000)
            runs.append(cand)
    finally:
        trimesh.util._RANDOM_DEFAULT = shared
    assert np.array_equal(*runs)
