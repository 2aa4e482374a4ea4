"""The robot's collision bodies as their own pytree: its collision spheres, the checked
self-collision sphere pairs and the tables of the closest-pair search (the closest checked sphere
pair of every checked pair of links: the thesis' link-to-link distance, §3.3.3), per arm and with
a batch of arms as the minor axis. `fabrax.robot.robot.build_robot` fills it from the robot's
sphere set and self-collision sampling; `Robot.collision` carries it, and a sphere set is swapped
with `robot.replace(collision=...)`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from fabrax.scene.sdf import FAR, argmin_packed, min_packed
from fabrax.soa import dot0


@struct.dataclass
class RobotCollision:
    """Collision spheres on the robot's joint frames and the self-collision search tables."""

    link_names: tuple = struct.field(pytree_node=False)  # the links that carry spheres
    frame: jax.Array  # (S,) joint frame of each sphere (0 = base)
    local: jax.Array  # (S, 3) its centre in that frame
    radius: jax.Array  # (S,)
    link: jax.Array  # (S,) index into link_names
    pair_i: jax.Array  # (P,) checked self-collision sphere pairs
    pair_j: jax.Array
    pair_groups: jax.Array  # (G, Q) indices into pair_i/pair_j: pairs of one pair of links, at most Q per row, padded
    pair_groups_mask: jax.Array  # (G, Q)
    link_pair_groups: jax.Array  # (LP, C) rows of pair_groups that belong to one pair of links, padded
    link_pair_groups_mask: jax.Array  # (LP, C)

    @property
    def n_spheres(self) -> int:
        return int(self.radius.shape[-1])


def closest_link_pairs(bodies: RobotCollision, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The closest checked sphere pair (i, j) of every checked pair of links, for sphere centres x (3, S).

    The checked pairs' gaps, grouped into chunks of at most 16 pairs of one link pair
    (`bodies.pair_groups`): the closest pair of each chunk, then the closest chunk of each link pair,
    both by packed argmins (`scene.sdf.min_packed`, whose keys also give each chunk's minimum: a
    gather of it made XLA recompute the gaps). The gaps are computed in the chunks' layout
    (sphere indices composed at trace time): gathering per-pair gaps into chunks made XLA recompute
    each gap through two levels of indices. The work grows with the checked pairs alone: a dense
    search over all spheres of both links was slower, as XLA fused its minima into a gather that
    recomputed them per link pair. The self-collision term runs the same search arms-minor under
    `jax.vmap` (`closest_minor`).
    """
    if bodies.pair_i.shape[0] == 0:
        return bodies.pair_i, bodies.pair_j
    return closest_one(jax.lax.stop_gradient(x), *search_tables(bodies))


def search_tables(bodies: RobotCollision) -> tuple:
    """The arrays `closest_one` and `closest_minor` take, in their order."""
    return (
        bodies.radius,
        bodies.pair_i,
        bodies.pair_j,
        bodies.pair_groups,
        bodies.pair_groups_mask,
        bodies.link_pair_groups,
        bodies.link_pair_groups_mask,
    )


def closest_one(x, radius, i, j, groups, groups_mask, link_groups, link_groups_mask):
    gi, gj = i[groups], j[groups]  # (G, Q): the chunks' spheres, constants
    rel = x[:, gi] - x[:, gj]
    gap = jnp.sqrt(dot0(rel, rel)) - radius[gi] - radius[gj]
    grouped = jnp.where(groups_mask, gap, FAR)
    slot, smallest = min_packed(grouped)
    best = jnp.take_along_axis(groups, slot[:, None], -1)[:, 0]
    chunk_gap = jnp.where(link_groups_mask, smallest[link_groups], FAR)
    best = best[jnp.take_along_axis(link_groups, argmin_packed(chunk_gap)[:, None], -1)[:, 0]]
    return i[best], j[best]


def closest_minor(xt, radius, i, j, groups, groups_mask, link_groups, link_groups_mask):
    """`closest_one` of arms xt (3, S, B), the arms minor: the same operations and values, so the same
    pairs, as (LP, B) indices."""
    gi, gj = i[groups], j[groups]
    rel = xt[:, gi] - xt[:, gj]  # (3, G, Q, B): rows of arms
    gap = jnp.sqrt(dot0(rel, rel)) - (radius[gi] + radius[gj])[..., None]
    grouped = jnp.where(groups_mask[..., None], gap, FAR)
    slot, smallest = min_packed(grouped, axis=1, unroll=True)  # (G, B) each: rows of arms, minima of slices
    best = jnp.take_along_axis(jnp.broadcast_to(groups[..., None], grouped.shape), slot[:, None], 1)[:, 0]  # (G, B)
    chunk_gap = jnp.where(link_groups_mask[..., None], smallest[link_groups], FAR)  # (LP, C, B)
    rows = min_packed(chunk_gap, axis=1, unroll=True)[0][:, None]
    rows = jnp.take_along_axis(jnp.broadcast_to(link_groups[..., None], chunk_gap.shape), rows, 1)[:, 0]  # (LP, B)
    best = jnp.take_along_axis(best, rows, 0)
    return i[best], j[best]
