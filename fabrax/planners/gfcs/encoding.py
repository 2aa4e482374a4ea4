"""Problem encoding x_c = [q0, qd0, q_goal, d_E] (gfcs_paper §IV-B).

d_E holds, for a fixed lattice of reference points (basis point sets), the
distance to the nearest obstacle surface; it is computed from the scene's
primitives (exact signed distances, negative inside) or a point cloud, so
scenes of any size give one fixed-length vector. Distances are clipped to
[-clip_inside, clip_outside] m so that far-away structure does not dominate.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from fabrax.scene import Scene
from fabrax.scene.sdf import distance


@dataclasses.dataclass(frozen=True)
class Encoding:
    low: tuple = (-0.9, -0.9, -0.3)  # m, workspace box of the lattice
    high: tuple = (0.9, 0.9, 1.2)
    spacing: float = 0.15  # m (gfcs_paper)
    clip_inside: float = 0.15
    clip_outside: float = 1.0

    def lattice(self) -> np.ndarray:
        axes = [np.arange(lo, hi + 1e-9, self.spacing) for lo, hi in zip(self.low, self.high, strict=True)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)

    @property
    def n_reference(self) -> int:
        return len(self.lattice())

    def scene_distances(self, scene: Scene) -> jax.Array:
        """d_E: (N_R,) clipped distances from the lattice points to the scene."""
        d = distance(scene, jnp.asarray(self.lattice(), jnp.float32))
        return jnp.clip(d, -self.clip_inside, self.clip_outside)

    def context(self, robot, start_q, start_qd, goal_q, scene: Scene) -> jax.Array:
        """x_c with joint positions normalised to [0, 1] within the limits and velocities by their limits."""
        span = robot.upper - robot.lower
        return jnp.concatenate(
            [(start_q - robot.lower) / span, start_qd / robot.velocity, (goal_q - robot.lower) / span, self.scene_distances(scene)]
        )
