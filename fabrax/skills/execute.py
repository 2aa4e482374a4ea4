"""From a latent geodesic to motion on the robot: decode it to a joint path and let the fabric follow it.

The decoded path becomes a sequence of joint-space attractor commands (its
waypoints, equally spaced along the path); the fabric passes each within
`via_tolerance` and stops at the last. Its collision terms stay active, so the
arm follows the skill and still reacts to obstacles the skill never saw.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from fabrax import sharding
from fabrax.robot.kinematics import sphere_centers
from fabrax.rollout import rollout_sequence
from fabrax.skills.demos import ik_path
from fabrax.skills.vae import JointVAE, TaskVAE


def decode_path(model, z, robot=None, frame: str = "panda_tcp", seed=None):
    """Joint path (T, n) of latent points z (T, d): the decoder mean for a joint-space skill; for a task-space
    skill the decoded poses through continuation IK from `seed`."""
    if isinstance(model, JointVAE):
        return jax.vmap(model.decode)(z)
    if isinstance(model, TaskVAE):
        if robot is None or seed is None:
            raise ValueError("decode_path: a task-space skill needs the robot and an IK seed")
        qs, _ = ik_path(robot, frame, jax.vmap(model.decode_x)(z), jax.vmap(model.decode_q)(z), jnp.asarray(seed, jnp.float32))
        return qs
    raise TypeError(f"decode_path: not a skill model: {type(model).__name__}")


@jax.jit
def sphere_clearance(robot, q_path, centers, radii):
    """Smallest distance (m) between the robot's collision spheres along q_path (T, n) and spheres (O, 3), (O,)."""
    c = jax.vmap(lambda q: sphere_centers(robot, q))(q_path)  # (T, S, 3)
    d = jnp.linalg.norm(c[:, :, None] - centers[None, None], axis=-1) - robot.collision.radius[None, :, None] - radii[None, None]
    return jnp.min(d)


@dataclass(frozen=True)
class FollowConfig:
    waypoints: int = 8  # attractor commands along the path
    via_tolerance: float = 0.3  # rad: an intermediate command counts as passed within this
    dt: float = 0.01
    t_max: float = 4.0  # s per command
    margin: float = 0.05  # rad: waypoints are kept this far inside the joint limits (the fabric's limit terms repel there)


def follower(fabric, params, cfg: FollowConfig = FollowConfig()):
    """jitted (paths (B, T, n), scene) -> batched Trajectory: for each path, the fabric follows its waypoints
    from its first point; all paths in one loop."""
    steps = int(round(cfg.t_max / cfg.dt))

    def via(p, q, qd):
        return fabric.joint_reached(p, q, qd, cfg.via_tolerance)

    def run(path, scene):
        path = jnp.clip(path, fabric.robot.lower + cfg.margin, fabric.robot.upper - cfg.margin)
        idx = np.round(np.linspace(0, path.shape[0] - 1, cfg.waypoints + 1)[1:]).astype(int)
        seq = jax.vmap(lambda g: fabric.with_joint_goal(params, g))(path[idx])
        return rollout_sequence(fabric, seq, scene, path[0], jnp.zeros_like(path[0]), fabric.reached, dt=cfg.dt, steps=steps, via=via)

    return jax.jit(lambda paths, scene: sharding.batched(jax.vmap(lambda path: run(path, scene)))(paths))
