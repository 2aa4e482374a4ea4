"""Problem encoding x_c = [q0, qd0, q_goal, d_E] (gfcs_paper §IV-B).

d_E holds, for a fixed lattice of reference points (basis point sets), the
distance to the nearest obstacle surface; it is computed from the scene's
primitives (exact signed distances, negative inside) or a point cloud, so
scenes of any size give one fixed-length vector. Distances are clipped to
[-clip_inside, clip_outside] m so that far-away structure does not dominate.

`scene_scale` weighs d_E against the joint part of x_c. Trained on one class's
~50 scenes (Algorithm 2's setting), the energy model's first layer otherwise
fits the ~1,900 distances, which vary little within a class, before the start
and goal, and its samples generalise to new problems no better than the
class's buffered solutions drawn at random; at a small weight the start and
goal lead and the scene still enters (chosen on train problems the sampler
did not learn from, `experiments/gfcs_sampler.py`). 1 is the paper's plain
concatenation.
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
    scene_scale: float = 1.0  # multiplies d_E in x_c (0: condition on start, velocity and goal only)

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
        """x_c with joint positions normalised to [0, 1] within the limits, velocities by their limits,
        and d_E times `scene_scale`."""
        span = robot.upper - robot.lower
        return jnp.concatenate(
            [(start_q - robot.lower) / span, start_qd / robot.velocity, (goal_q - robot.lower) / span, self.scene_scale * self.scene_distances(scene)]
        )
