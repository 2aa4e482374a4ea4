"""Pullback metrics of a skill VAE, reshaped by an obstacle-aware ambient metric (paper eqs. 10-12, 21-32).

A model's `rows(z, v)` returns (anchors (K, 3), attached (K, r), free (f,)):
velocities of decoded quantities along the latent velocity v, linear in v.
With the ambient metric of eq. 30, a(x) = 1 + eta sum_o exp(-|x - o|^2 / r_o^2),
evaluated at each anchor (the decoded end-effector position in task space, eq.
31; every FK point in joint space, the block-diagonal multi-limb metric of eq.
32), the squared speed is

    v^T M(z) v = sum_k a(anchor_k) |attached_k|^2 + |free|^2,

and M(z) itself is J^T W J with J = d rows / dv (`jax.jacfwd`). A model's
`chord(za, zb)` returns the same triple for the chord za -> zb (differences of
the decoded quantities, anchored at midpoints): its `chord2` is the squared
decoded length of the chord, which the geodesic's "chord" rule sums
(`fabrax.skills.geodesic`). Orientation rows
see a flat ambient metric, as in §4.4.1. Obstacles are an argument, not a
constant: moving one reshapes the metric without retraining or recompiling.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import nnx

from fabrax.skills.geodesic import CurveMetric


class Obstacles(NamedTuple):
    """Spherical obstacles for the ambient metric; rows with active False are padding."""

    centers: jax.Array  # (O, 3)
    radii: jax.Array  # (O,) length scale r of eq. 30
    active: jax.Array  # (O,) bool
    eta: jax.Array  # () cost scale of eq. 30


def obstacles(centers=(), radii=(), eta: float = 0.0, capacity: int | None = None) -> Obstacles:
    """Obstacles padded to `capacity` rows (default: as many as given, at least one)."""
    c = jnp.asarray(centers, jnp.float32).reshape(-1, 3)
    r = jnp.asarray(radii, jnp.float32).reshape(-1)
    if c.shape[0] != r.shape[0]:
        raise ValueError(f"obstacles: {c.shape[0]} centres but {r.shape[0]} radii")
    if r.shape[0] and not bool(jnp.all(r > 0)):
        raise ValueError("obstacles: radii must be positive")
    n = max(capacity or 0, c.shape[0], 1)
    pad = n - c.shape[0]
    return Obstacles(
        jnp.concatenate([c, jnp.zeros((pad, 3))]), jnp.concatenate([r, jnp.ones(pad)]), jnp.arange(n) < c.shape[0], jnp.asarray(eta, jnp.float32)
    )


NONE = obstacles()


def embedding_rows(embed, z, v):
    """`rows` of a model whose metric is the pullback of embed(z) -> (anchors, attached, free): its velocities along v."""
    (anchors, _, _), (_, attached, free) = jax.jvp(embed, (z,), (v,))
    return anchors, attached, free


def embedding_chord(embed, za, zb):
    """`chord` of such a model: the differences of embed over za -> zb, anchored at the anchors' midpoints."""
    (xa, aa, fa), (xb, ab, fb) = embed(za), embed(zb)
    return 0.5 * (xa + xb), ab - aa, fb - fa


def ambient(obs: Obstacles, x):
    """Eq. 30's scalar factor a(x) at points x (..., 3): 1 + eta sum_o exp(-|x - o|^2 / r_o^2)."""
    d2 = jnp.sum((x[..., None, :] - obs.centers) ** 2, -1)
    return 1.0 + obs.eta * jnp.sum(jnp.where(obs.active, jnp.exp(-d2 / obs.radii**2), 0.0), -1)


def speed2(model, obs: Obstacles, z, v):
    """v^T M(z) v under the model's pullback metric reshaped by the obstacles' ambient metric."""
    anchors, attached, free = model.rows(z, v)
    return jnp.sum(ambient(obs, anchors) * jnp.sum(attached**2, -1)) + jnp.sum(free**2)


def chord2(model, obs: Obstacles, za, zb):
    """Squared decoded length of the chord za -> zb under the same ambient metric (-> speed2 dt^2 as zb -> za)."""
    anchors, attached, free = model.chord(za, zb)
    return jnp.sum(ambient(obs, anchors) * jnp.sum(attached**2, -1)) + jnp.sum(free**2)


def metric(model, obs: Obstacles, z):
    """M(z) (d, d): J^T W J with J the Jacobian of the rows in v (forward mode)."""
    zero = jnp.zeros_like(z)
    anchors, _, _ = model.rows(z, zero)
    ja, jf = jax.jacfwd(lambda v: model.rows(z, v)[1:])(zero)  # (K, r, d), (f, d)
    w = ambient(obs, anchors)
    return jnp.einsum("k,krd,kre->de", w, ja, ja) + jf.T @ jf


def magnification(model, obs: Obstacles, z):
    """Magnification factor log sqrt(det M(z)) (Bishop et al. 1997; paper Fig. 3)."""
    return 0.5 * jnp.linalg.slogdet(metric(model, obs, z))[1]


def speed2_fn(graphdef):
    """speed2(args, z, v) with args = (model state, obstacles), the model rebuilt from its graph."""

    def f(args, z, v):
        state, obs = args
        return speed2(nnx.merge(graphdef, state), obs, z, v)

    return f


def chord2_fn(graphdef):
    """chord2(args, za, zb) with args = (model state, obstacles), the model rebuilt from its graph."""

    def f(args, za, zb):
        state, obs = args
        return chord2(nnx.merge(graphdef, state), obs, za, zb)

    return f


def curve_metric(graphdef) -> CurveMetric:
    """The model's metric for `geodesic.solver` (both rules), args = (model state, obstacles)."""
    return CurveMetric(speed2_fn(graphdef), chord2_fn(graphdef))
