"""Observation and reward pieces of the guide's environment (thesis §3.4.2, §3.4.5).

- static basis point set (eqs. 3.15-3.16): a fixed grid of points, each with the vector to the
  nearest obstacle surface point, x~_i - b_i = -d_i n_i from the exact signed distance d_i and
  its unit gradient n_i;
- dynamic basis points: the collision spheres' centres, each with its distance to the scene;
- the exploration map: visit counts of a grid of cells the hand passed through;
- the goal-weighted count-based intrinsic reward (eqs. 3.17-3.18).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fabrax.scene import Scene
from fabrax.scene.sdf import nearest_distance


def grid_points(cells: int, low, high) -> np.ndarray:
    """(cells, cells, cells, 3) points evenly spaced from `low` to `high` inclusive (eq. 3.15), x-major.

    A host array: inside a jitted function it is a constant. Traced (linspace and meshgrid), XLA
    fused the grid's arithmetic into the per-(point, obstacle) distance loop of `bps_vectors`,
    which then ran slower (experiments/bench_reaction.py times a new scene's BPS)."""
    axes = [np.linspace(lo, hi, cells, dtype=np.float32) for lo, hi in zip(low, high)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def cell_centres(cells: int, low, high) -> jax.Array:
    """(cells^3, 3) centres of the exploration map's cells, in the flat order of `cell_index`."""
    low, high = jnp.asarray(low), jnp.asarray(high)
    size = (high - low) / cells
    axes = [low[k] + size[k] * (jnp.arange(cells) + 0.5) for k in range(3)]
    return jnp.stack(jnp.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def cell_index(x: jax.Array, cells: int, low, high) -> tuple[jax.Array, jax.Array]:
    """Flat index of the cell holding each point x (..., 3) and whether it is inside the map."""
    low, high = jnp.asarray(low, x.dtype), jnp.asarray(high, x.dtype)
    ijk = jnp.floor((x - low) / (high - low) * cells).astype(jnp.int32)
    inside = jnp.all((ijk >= 0) & (ijk < cells), axis=-1)
    ijk = jnp.clip(ijk, 0, cells - 1)
    return (ijk[..., 0] * cells + ijk[..., 1]) * cells + ijk[..., 2], inside


def bps_vectors(scene: Scene, points: jax.Array, clip: float) -> jax.Array:
    """Vectors (..., 3) from each point to the nearest obstacle surface point (eq. 3.16), at most `clip` long."""
    flat = points.reshape(-1, 3)
    near = nearest_distance(scene, flat.T, jnp.zeros_like(flat.T), skip_empty=True)  # scenes padded to a common capacity
    v = -(near.d * near.n).T
    norm = jnp.linalg.norm(v, axis=-1, keepdims=True)
    v = jnp.where(norm > clip, v * clip / jnp.maximum(norm, 1e-9), v)
    return v.reshape(points.shape)


def point_distances(scene: Scene, points: jax.Array, clip: float) -> jax.Array:
    """Signed distances (N,) of points (N, 3) to the scene, clipped to `clip` (the dynamic basis points)."""
    return jnp.minimum(nearest_distance(scene, points.T, jnp.zeros_like(points.T)).d, clip)


def keypoint_distance(keypoints: jax.Array, goal_keypoints: jax.Array) -> jax.Array:
    """Mean Euclidean distance between corresponding keypoints (8, 3) (the success test of Table 3.5)."""
    return jnp.mean(jnp.linalg.norm(keypoints - goal_keypoints, axis=-1))


def intrinsic_reward(counts: jax.Array, visited: jax.Array, centres: jax.Array, goal_position: jax.Array) -> jax.Array:
    """Eqs. 3.17-3.18: sum over the cells V visited since the last policy step of
    w_ijk exp(-10 (n_ijk - 1)), w_ijk = 1 / (d_ijk + 0.25), with n_ijk the visit count including
    this step and d_ijk the cell centre's distance to the goal position."""
    w = 1.0 / (jnp.linalg.norm(centres - goal_position, axis=-1) + 0.25)
    return jnp.sum(jnp.where(visited, w * jnp.exp(-10.0 * (counts.astype(w.dtype) - 1.0)), 0.0))
