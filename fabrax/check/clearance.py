"""Clearances of robot configurations in a scene: collision spheres against primitives and self pairs."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

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


def clearances(robot: Robot, scene: Scene, qs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`state_clearances` for callers on the host (problem loading, rejection sampling, path checks):
    numpy results, the scene `rounded` to 8 slots per primitive kind (at least 8: scenes read from
    files or drawn by generators each have their own obstacle counts) and the rows padded with the
    last one to a power of two (at least 8), so that one compiled program serves scenes and batches
    of similar size. Padded slots are masked out: every row's values are the unpadded call's."""
    qs = np.asarray(qs, np.float32).reshape(-1, robot.dof)
    m = len(qs)
    if m == 0:
        return np.zeros(0, np.float32), np.zeros(0, np.float32), np.zeros(0, bool)
    rows = max(8, 1 << (m - 1).bit_length())
    padded = np.concatenate([qs, np.repeat(qs[-1:], rows - m, 0)]) if rows > m else qs
    env, slf, ok = state_clearances(robot, scene.rounded(at_least=8), jnp.asarray(padded))
    return np.asarray(env)[:m], np.asarray(slf)[:m], np.asarray(ok)[:m]
