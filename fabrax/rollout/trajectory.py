"""`Trajectory`: the joint-space motion every method returns."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Trajectory:
    q: jax.Array  # (T, n); rows past `length` repeat the last state
    qd: jax.Array  # (T, n)
    qdd: jax.Array  # (T, n) acceleration applied from each state
    dt: jax.Array  # () step
    length: jax.Array  # () number of valid states
    reached: jax.Array  # () bool: the goal test held at some step
    t_goal: jax.Array  # () time at which the final goal test first held (total budget if never)
    segment_times: jax.Array  # (m,) t*_i of every command segment (gfcs_paper eq. 2)
    min_clearance: jax.Array  # () smallest obstacle/self distance the fabric saw (m)

    @property
    def valid(self) -> jax.Array:
        """(T,) mask of valid states."""
        return jnp.arange(self.q.shape[-2]) < self.length[..., None]

    @property
    def duration(self) -> jax.Array:
        return (self.length - 1) * self.dt

    def final_q(self) -> jax.Array:
        return jnp.take_along_axis(self.q, (self.length - 1)[..., None, None], axis=-2)[..., 0, :]


def to_numpy(traj: Trajectory) -> dict:
    """Plain arrays (valid states only) of one unbatched trajectory, for saving."""
    n = int(traj.length)
    return {
        "q": jax.device_get(traj.q[:n]),
        "qd": jax.device_get(traj.qd[:n]),
        "qdd": jax.device_get(traj.qdd[:n]),
        "dt": float(traj.dt),
        "reached": bool(traj.reached),
        "t_goal": float(traj.t_goal),
        "segment_times": jax.device_get(traj.segment_times),
        "min_clearance": float(traj.min_clearance),
    }
