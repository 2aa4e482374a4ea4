"""Goal tolerances and the orientation error, defined once for every goal test: the fabric's
time-to-goal (`ArmFabric.reached`), the bench's success (`fabrax.bench.metrics`) and the RL env's
keypoint success.

Defaults follow the seeds: 0.05 rad joint error, 1 cm and 15 degrees for a pose (MπNets'
and gfcs_paper's pose test), 8 cm mean keypoint distance (thesis §3.4.5, Table 3.5).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class Tolerance:
    joint: float = 0.05  # rad, |q - q_goal|_2
    position: float = 0.01  # m
    orientation_deg: float = 15.0  # degrees, the angle of the relative rotation
    keypoints: float = 0.08  # m, mean keypoint distance


TOLERANCE = Tolerance()


def orientation_error(quat, target_quat):
    """The angle (rad, in [0, pi]) of the rotation between two wxyz quaternions (either sign, any
    norm): 2 atan2(|v|, |w|) of target^-1 * quat, accurate near 0 where 2 arccos|<a, b>| is not."""
    a = quat / jnp.linalg.norm(quat, axis=-1, keepdims=True)
    b = target_quat / jnp.linalg.norm(target_quat, axis=-1, keepdims=True)
    # the relative rotation b^-1 a = (w, v): w = <a, b>, v = b_w a_v - a_w b_v - b_v x a_v
    w = jnp.sum(a * b, axis=-1)
    v = b[..., :1] * a[..., 1:] - a[..., :1] * b[..., 1:] - jnp.cross(b[..., 1:], a[..., 1:])
    return 2.0 * jnp.arctan2(jnp.linalg.norm(v, axis=-1), jnp.abs(w))
