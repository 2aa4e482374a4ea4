"""Clearances of robot configurations in a scene: collision spheres against primitives and self pairs."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fabrax.robot.kinematics import sphere_centers
from fabrax.robot.robot import Robot
from fabrax.scene import Scene
from fabrax.scene.sdf import distance


@jax.jit
def state_clearances(robot: Robot, scene: Scene, qs: jax.Array):
    """Per configuration (M, n): smallest sphere-scene distance, smallest self-pair distance, within joint limits."""

    def one(q):
        x = sphere_centers(robot, q)
        env = jnp.min(distance(scene, x) - robot.collision.radius, initial=jnp.inf)
        i, j = robot.collision.pair_i, robot.collision.pair_j
        gap = jnp.linalg.norm(x[i] - x[j], axis=-1) - robot.collision.radius[i] - robot.collision.radius[j]
        return env, jnp.min(gap, initial=jnp.inf), robot.within_limits(q, 1e-6)

    return jax.vmap(one)(qs)
