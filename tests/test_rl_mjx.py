"""The RL environment's MJX backend: the generated MJCF is the robot, the PD + inverse-dynamics
controller (thesis eq. 3.12) tracks the fabric, both backends follow the same actions, and MJX's
contacts agree with the exact checker."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fabrax import config
from fabrax.check.clearance import state_clearances
from fabrax.rl import make_env
from fabrax.robot.kinematics import sphere_centers
from fabrax.robot.mjcf import to_mjcf

CFG = {"substeps": 5, "scenes": {"generated": {"cuboid_forest": 1, "shelves": 1, "flying_cuboids": 1}, "configs_per_scene": 4}}


@pytest.fixture(scope="module")
def envs():
    arm = config.load("robot", "panda"), config.load("fabric", "panda")
    kin, mj = make_env(CFG, *arm), make_env({**CFG, "backend": "mjx"}, *arm)
    return {name: (env, jax.jit(env.reset), jax.jit(env.step)) for name, env in (("kinematic", kin), ("mjx", mj))}


def test_mjcf_is_the_robot(panda):
    """Sphere geoms of the generated MJCF sit where the robot's FK puts them; the bodies carry the
    URDF's masses (example-robot-data's Panda: 17.45 kg with the base)."""
    model = mujoco.MjModel.from_xml_string(to_mjcf(panda, {"cuboids": 2, "cylinders": 1, "spheres": 1}))
    data = mujoco.MjData(model)
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"sphere_{s}") for s in range(panda.n_spheres)]
    rng = np.random.default_rng(0)
    for q in rng.uniform(np.asarray(panda.lower), np.asarray(panda.upper), (5, panda.dof)):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(data.geom_xpos[ids], sphere_centers(panda, jnp.asarray(q, jnp.float32)), atol=1e-5)
    assert model.nq == panda.dof
    np.testing.assert_allclose(model.body_mass[1:].sum() + float(panda.frame_mass[0]), float(np.sum(panda.frame_mass)), rtol=1e-6)
    assert 17.0 < float(np.sum(panda.frame_mass)) < 18.0
    assert np.all(model.geom_contype[ids] == 1) and np.all(model.geom_conaffinity[ids] == 2)


def test_backends_follow_the_same_scripted_actions(envs):
    """The same actions from the same reset: MJX's arm stays within millimetres of the kinematic
    backend's (the fabric's own state), and both judge the same collisions."""
    actions = jax.random.uniform(jax.random.PRNGKey(3), (6, envs["mjx"][0].action_size), minval=-1, maxval=1)
    paths, verdicts = {}, {}
    for name, (env, reset, step) in envs.items():
        s = reset(jax.random.PRNGKey(0))
        qs, hits = [], []
        for a in actions:
            s = step(s, a)
            qs.append(np.asarray(s.pipeline_state.q))
            hits.append(float(s.metrics["collision"]))
        paths[name], verdicts[name] = np.stack(qs), hits
        if name == "mjx":
            assert 0.0 < float(s.metrics["tracking_error"]) < 0.01  # it tracks, and it is a simulation, not a copy
    assert np.abs(paths["kinematic"] - paths["mjx"]).max() < 0.03
    assert np.abs(paths["kinematic"][-1] - paths["kinematic"][0]).max() > 0.1  # the arm did move
    assert verdicts["kinematic"] == verdicts["mjx"]


def test_mjx_contacts_agree_with_the_checker(envs, box_on_hand):
    """A box placed on the hand: the checker ends the episode, and MJX sees penetrating contacts as
    deep as the checker's deepest penetration."""
    env, reset, step = envs["mjx"]
    s = box_on_hand(env, reset(jax.random.PRNGKey(9)))
    out, qs, _ = jax.jit(env.step_with_path)(s, jnp.zeros(env.action_size))
    assert out.metrics["collision"] == 1.0 and out.done == 1.0
    env_clear, _, _ = state_clearances(env.robot, out.pipeline_state.scene, qs)
    assert float(out.metrics["mjx_contacts"]) > 0
    np.testing.assert_allclose(float(out.metrics["mjx_penetration"]), -float(jnp.min(env_clear)), atol=1e-3)
    free = step(reset(jax.random.PRNGKey(0)), jnp.zeros(env.action_size))
    assert float(free.metrics["mjx_contacts"]) == 0.0 and float(free.metrics["collision"]) == 0.0
