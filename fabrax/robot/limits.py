"""Limits that follow from the robot's own data alone, shared by the fabric's solve and the
problem generators.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fabrax.robot.robot import Robot


def max_acceleration(robot: Robot, dt: float) -> jax.Array:
    """a' = min(a_max, dt j_max / 2) per joint (thesis eq. 3.8): the acceleration bound under which
    a step of length dt never exceeds the jerk limit."""
    return jnp.minimum(robot.acceleration, 0.5 * dt * robot.jerk)
