"""Geodesics as energy-minimising cubic splines (paper §4, eq. 29).

The curve energy E(c) = int_0^1 c'(t)^T M(c(t)) c'(t) dt is discretised at the
spline basis' N Gauss-Legendre points and minimised over the spline's free parameters with
optax's Adam, starting from the straight latent line. Under a Riemannian metric
the minimiser of the energy is a constant-speed length minimiser (a geodesic).
The loop is a `lax.while_loop` over Adam steps that ends when the gradient's
largest entry falls below `tol` (1 + E) or after `iters` steps; `vmap` runs many
start/goal pairs in one loop.

Gradient descent from the straight line stalls where the line crosses a hole in
the data: the RBF variance is flat far from the codes, so only the walls around
the data cost energy. With `nodes` (latent points on the data, e.g. k-means
centres of the codes) the solver first finds the shortest path in a k-nearest-
neighbour graph over the nodes, start and end, edges weighted by their metric
length (Bellman-Ford relaxation in JAX), fits the spline through it, and starts
Adam from whichever of that curve and the straight line has lower energy.

`speed2(args, z, v)` gives v^T M(z) v for latent point z and velocity v; args
(a pytree: model weights, obstacles) is traced, so moving an obstacle does not
recompile.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import optax

from fabrax import sharding
from fabrax.skills import spline

Speed2 = Callable[..., jax.Array]


@dataclass(frozen=True)
class GeodesicConfig:
    segments: int = 5  # cubic pieces
    points: int = 20  # energy discretisation points
    lr: float = 0.02  # Adam step (latent units)
    iters: int = 300  # most Adam steps
    tol: float = 1e-3  # stop when max |dE/dw| is below tol (1 + E)
    neighbours: int = 8  # graph initialisation: edges per node
    samples: int = 3  # points per edge for its metric length


class Geodesic(NamedTuple):
    z: jax.Array  # (N, d) curve at the basis' points
    coeffs: jax.Array  # (4S, d) spline coefficients
    energy: jax.Array  # () final energy
    energy0: jax.Array  # () energy of the initial curve
    trace: jax.Array  # (iters,) energy per Adam step (the last value repeated after the stop)
    iters: jax.Array  # () Adam steps taken


def energy(speed2: Speed2, args, sb: spline.SplineBasis, start, end, w):
    """Discretised curve energy: Gauss-Legendre quadrature of c'^T M(c) c' over the basis' N points."""
    c = spline.coefficients(sb, start, end, w)
    z, v = spline.evaluate(sb, c), spline.evaluate(sb, c, order=1)
    return jnp.sum(sb.weight * jax.vmap(lambda zi, vi: speed2(args, zi, vi))(z, v))


def shortest(speed2: Speed2, args, sb: spline.SplineBasis, start, end, cfg: GeodesicConfig, w0=None) -> Geodesic:
    """Minimise the curve energy between start and end (d,); w0 (S + 1, d) overrides the straight-line start."""
    opt = optax.adam(cfg.lr)
    w0 = spline.straight(sb, start, end) if w0 is None else w0
    value_grad = jax.value_and_grad(lambda w: energy(speed2, args, sb, start, end, w))
    e0, g0 = value_grad(w0)

    def cond(s):
        i, _, _, _, g, _ = s
        return (i < cfg.iters) & (jnp.max(jnp.abs(g)) > cfg.tol * (1.0 + s[3]))

    def body(s):
        i, w, st, e, g, trace = s
        upd, st = opt.update(g, st, w)
        w = optax.apply_updates(w, upd)
        e, g = value_grad(w)
        return i + 1, w, st, e, g, trace.at[i].set(e)

    trace = jnp.full((cfg.iters,), e0)
    i, w, _, e, _, trace = jax.lax.while_loop(cond, body, (jnp.int32(0), w0, opt.init(w0), e0, g0, trace))
    trace = jnp.where(jnp.arange(cfg.iters) < i, trace, e)
    c = spline.coefficients(sb, start, end, w)
    return Geodesic(spline.evaluate(sb, c), c, e, e0, trace, i)


def _edge_length(speed2: Speed2, args, a, b, samples: int):
    """Metric length of the straight segment a -> b: sqrt of its mean squared speed at `samples` midpoints."""
    s = (jnp.arange(samples) + 0.5) / samples
    return jnp.sqrt(jnp.mean(jax.vmap(lambda si: speed2(args, a + si * (b - a), b - a))(s)))


def graph(speed2: Speed2, args, nodes, k: int, samples: int):
    """Weights (V, V) of the symmetric k-nearest-neighbour graph over nodes (V, d); inf where no edge."""
    v = nodes.shape[0]
    d2 = jnp.sum((nodes[:, None] - nodes[None]) ** 2, -1) + jnp.where(jnp.eye(v, dtype=bool), jnp.inf, 0.0)
    nbr = jnp.argsort(d2, axis=1)[:, :k]
    lengths = jax.vmap(lambda a, bs: jax.vmap(lambda b: _edge_length(speed2, args, a, b, samples))(nodes[bs]))(nodes, nbr)
    w = jnp.full((v, v), jnp.inf).at[jnp.arange(v)[:, None], nbr].set(lengths)
    return jnp.minimum(w, w.T)


def graph_path(speed2: Speed2, args, nodes, weights, sb: spline.SplineBasis, start, end, k: int, samples: int):
    """Free parameters w of the spline through the graph's shortest path from start to end."""
    v = nodes.shape[0]
    pts = jnp.concatenate([nodes, start[None], end[None]])
    links = []
    for p in (start, end):  # start (row v) and end (row v + 1) join their k nearest nodes
        nbr = jnp.argsort(jnp.sum((nodes - p) ** 2, -1))[:k]
        links.append(jnp.full(v, jnp.inf).at[nbr].set(jax.vmap(lambda b: _edge_length(speed2, args, p, b, samples))(nodes[nbr])))
    w = jnp.full((v + 2, v + 2), jnp.inf).at[:v, :v].set(weights)
    w = w.at[v, :v].set(links[0]).at[:v, v].set(links[0]).at[v + 1, :v].set(links[1]).at[:v, v + 1].set(links[1])
    w = w.at[v, v + 1].set(_edge_length(speed2, args, start, end, samples)).at[v + 1, v].set(w[v, v + 1])

    def relax(s):  # Bellman-Ford: distance from start through one more edge
        dist, _, _, i = s
        via = dist[:, None] + w
        new = jnp.minimum(dist, jnp.min(via, 0))
        return new, jnp.where(new < dist, jnp.argmin(via, 0), s[1]), jnp.any(new < dist), i + 1

    dist0 = jnp.full(v + 2, jnp.inf).at[v].set(0.0)
    _, parent, _, _ = jax.lax.while_loop(lambda s: s[2] & (s[3] < v + 2), relax, (dist0, jnp.full(v + 2, v), True, 0))
    hops = jax.lax.scan(lambda n, _: (parent[n], n), v + 1, None, length=v + 2)[1]  # end, ..., start, start, ...
    poly = pts[hops[::-1]]  # start repeated, ..., end
    seg = jnp.linalg.norm(jnp.diff(poly, axis=0), axis=-1)
    s = jnp.concatenate([jnp.zeros(1), jnp.cumsum(seg)])
    u = sb.t * s[-1]
    path = jax.vmap(lambda col: jnp.interp(u, s, col), in_axes=1, out_axes=1)(poly)
    return spline.through(sb, start, end, path)


def solver(speed2: Speed2, cfg: GeodesicConfig = GeodesicConfig(), nodes=None):
    """jitted (args, starts (B, d), ends (B, d)) -> batched `Geodesic`, one loop for all pairs, split over
    the local devices (`fabrax.sharding.batched`).
    nodes (V, d): latent points on the data for the graph initialisation (None: straight-line start)."""
    sb = spline.basis(cfg.segments, cfg.points)
    if nodes is None:
        pairs = jax.vmap(lambda args, a, b: shortest(speed2, args, sb, a, b, cfg), in_axes=(None, 0, 0))
        return jax.jit(lambda args, starts, ends: sharding.batched(lambda a, b: pairs(args, a, b))(starts, ends))
    nodes = jnp.asarray(nodes, jnp.float32)

    def one(args, weights, a, b):
        w_graph = graph_path(speed2, args, nodes, weights, sb, a, b, cfg.neighbours, cfg.samples)
        w_line = spline.straight(sb, a, b)
        e = lambda w: energy(speed2, args, sb, a, b, w)  # noqa: E731
        return shortest(speed2, args, sb, a, b, cfg, jnp.where(e(w_graph) < e(w_line), w_graph, w_line))

    def run(args, starts, ends):
        weights = graph(speed2, args, nodes, cfg.neighbours, cfg.samples)
        return sharding.batched(jax.vmap(lambda a, b: one(args, weights, a, b)))(starts, ends)

    return jax.jit(run)
