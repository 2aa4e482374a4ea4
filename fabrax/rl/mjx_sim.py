"""The MJX backend: MuJoCo MJX steps the arm's rigid-body dynamics while a PD + inverse-dynamics
controller tracks the fabric (thesis eq. 3.12),

    tau = ID(q, qd, qdd_e + K_p (q_e - q) + K_d (qd_e - qd)),   clipped to the URDF's effort limits,

where ID is MuJoCo's inverse dynamics (M(q) a + C(q, qd) qd + g(q), what `mjx.inverse` computes
without constraints; one position/velocity pass per physics step serves it and the step) and (q_e, qd_e,
qdd_e) is the fabric's state, integrated on its own (the fabric is the reference generator). Within
one fabric step of dt the reference follows the fabric's own second-order integration,
q_e(s) = q_e + qd_e s + qdd_e s^2 / 2, sampled at each of `sim_steps` physics steps.

The model comes from `fabrax.robot.mjcf` (the robot's spheres as collision geoms, the scene's
obstacles as primitives in padded slots, sized and placed per episode by `with_scene`). Physics
runs with constraints off: a collision ends the episode (judged by the exact checker), so contact
forces would never act on an episode that continues; `contacts` runs MJX's own collision pass on a
state to report what MuJoCo sees.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from fabrax.robot.mjcf import PARKED, obstacle_geom_names, to_mjcf
from fabrax.robot.robot import Robot
from fabrax.scene import Scene


class MJXArm:
    """A robot in MJX with obstacle slots of `capacity`; all methods are pure and batch with vmap."""

    def __init__(self, robot: Robot, capacity: dict[str, int], dt: float, sim_steps: int = 2, kp: float = 400.0, kd: float = 40.0):
        self.robot, self.dt, self.sim_steps, self.kp, self.kd = robot, dt, sim_steps, kp, kd
        self.xml = to_mjcf(robot, capacity, timestep=dt / sim_steps)
        mj = mujoco.MjModel.from_xml_string(self.xml)
        mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
        self.model = mjx.put_model(mj)
        contact = mujoco.MjModel.from_xml_string(self.xml)
        self.contact_model = mjx.put_model(contact)
        ids = lambda names: np.array([mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_GEOM, g) for g in names], np.int32)  # noqa: E731
        self.slots = {kind: ids(names) for kind, names in obstacle_geom_names(capacity).items()}
        effort = np.asarray(robot.effort if robot.effort is not None else np.full(robot.dof, np.inf), np.float32)
        self.effort = jnp.asarray(np.where(np.isfinite(effort), effort, 1e9), jnp.float32)

    def with_scene(self, model: mjx.Model, scene: Scene) -> mjx.Model:
        """`model` with the obstacle slots sized and placed as `scene`'s primitives (unused slots parked)."""
        pos, quat, size, rbound = model.geom_pos, model.geom_quat, model.geom_size, model.geom_rbound
        parked = jnp.asarray(PARKED, pos.dtype)
        c, y, s = scene.cuboids, scene.cylinders, scene.spheres
        parts = (
            ("cuboids", c.center, c.quat, c.half_extents, jnp.linalg.norm(c.half_extents, axis=-1), c.mask),
            (
                "cylinders",
                y.center,
                y.quat,
                jnp.stack([y.radius, y.half_length, jnp.zeros_like(y.radius)], -1),
                jnp.hypot(y.radius, y.half_length),
                y.mask,
            ),
            (
                "spheres",
                s.center,
                jnp.tile(jnp.array([1.0, 0.0, 0.0, 0.0]), (s.radius.shape[0], 1)),
                s.radius[:, None] * jnp.array([1.0, 0.0, 0.0]),
                s.radius,
                s.mask,
            ),
        )
        for kind, center, q, sz, rb, mask in parts:
            ids = self.slots[kind]
            if len(ids) == 0:
                continue
            if center.shape[0] > len(ids):
                raise ValueError(f"scene has {center.shape[0]} {kind} slots, the MJX model {len(ids)}")
            k = center.shape[0]
            ids = ids[:k]
            pos = pos.at[ids].set(jnp.where(mask[:, None], center, parked))
            quat = quat.at[ids].set(q)
            size = size.at[ids].set(jnp.where(mask[:, None], sz, 0.01))
            rbound = rbound.at[ids].set(jnp.where(mask, rb, 0.01))
        return model.replace(geom_pos=pos, geom_quat=quat, geom_size=size, geom_rbound=rbound)

    def track(self, model: mjx.Model, q, qd, ref_q, ref_qd, ref_qdd):
        """`sim_steps` physics steps of dt / sim_steps from the robot state (q, qd), tracking the fabric
        step that starts at (ref_q, ref_qd) with acceleration ref_qdd. Returns (q, qd, tau of the last step)."""
        h = self.dt / self.sim_steps
        data = mjx.make_data(model)

        def one(carry, j):
            q, qd, _ = carry
            s = j * h
            target_q = ref_q + ref_qd * s + 0.5 * ref_qdd * s * s
            target_qd = ref_qd + ref_qdd * s
            acc = ref_qdd + self.kp * (target_q - q) + self.kd * (target_qd - qd)
            # one position/velocity pass serves both the inverse dynamics and the forward step
            d = mjx.fwd_velocity(model, mjx.fwd_position(model, data.replace(qpos=q, qvel=qd)))
            tau = d.qfrc_bias + mjx.mul_m(model, d, acc) - d.qfrc_passive  # mjx.inverse without constraints
            tau = jnp.clip(tau, -self.effort, self.effort)
            d = mjx.fwd_acceleration(model, d.replace(qfrc_applied=tau))
            d = mjx.euler(model, d.replace(qacc=d.qacc_smooth))  # mjx.step's integration (no constraint forces)
            return (d.qpos, d.qvel, tau), None

        (q, qd, tau), _ = jax.lax.scan(one, (q, qd, jnp.zeros_like(q)), jnp.arange(self.sim_steps, dtype=q.dtype))
        return q, qd, tau

    def contacts(self, model: mjx.Model, q) -> tuple[jax.Array, jax.Array]:
        """MJX's robot-obstacle contacts at configuration q: (number of penetrating sphere-obstacle
        pairs, deepest penetration in m, 0 without one). MJX's box test reports a distance only for
        touching pairs, so a clearance is not read from it."""
        m = self.contact_model.replace(geom_pos=model.geom_pos, geom_quat=model.geom_quat, geom_size=model.geom_size, geom_rbound=model.geom_rbound)
        dist = mjx.collision(m, mjx.kinematics(m, mjx.make_data(m).replace(qpos=q)))._impl.contact.dist
        if dist.shape[0] == 0:
            return jnp.zeros((), jnp.int32), jnp.zeros(())
        return jnp.sum(dist < 0.0).astype(jnp.int32), jnp.maximum(-jnp.min(dist), 0.0)
