"""Geodesics as energy-minimising cubic splines (paper §4, eq. 29).

The curve energy E(c) = int_0^1 c'(t)^T M(c(t)) c'(t) dt is discretised at the
spline basis' N Gauss-Legendre points and minimised over the spline's free
parameters w, starting from the straight latent line. Under a Riemannian metric
the minimiser of the energy is a constant-speed length minimiser (a geodesic).

Two minimisers (`GeodesicConfig.method`):

- "newton" (default): damped Newton steps with the exact Hessian. The points
  z_n = c(t_n) and velocities v_n = c'(t_n) are linear in w, so the Hessian of
  E = sum_n omega_n f(z_n, v_n), f = v^T M(z) v, is assembled from each point's
  2d x 2d Hessian of f (one forward-over-reverse pass gives value, gradient and
  Hessian). A step uses the Hessian's absolute eigenvalues (saddle-free) plus a
  damping lambda times the largest; each iteration tries `trials` dampings
  10x apart, and steps along the most negative curvature, in one energy pass
  and takes the lowest energy. A step that lowers no energy is not taken and
  lambda grows.
- "adam": optax's Adam at step `lr`.

Both stop when the gradient's largest entry falls below `tol` (1 + E) or after
`iters` steps. Newton also stops when a full step would lower the energy by
less than `tol`^2 (1 + E) (in float32 a stiff obstacle metric can hold the
gradient above `tol` at the minimum), and only where the Hessian has no
eigenvalue below -`tol` times its largest, so it does not stop at a saddle.

A batch of start/goal pairs runs in one loop. Once at most 1/`shrink` of the
pairs still run, those go on alone as a smaller batch (sizes B, B / shrink,
..., down to 8), so a few slow pairs do not make the batch pay for their
iterations.

The quadrature must resolve the metric: an RBF variance whose walls are
narrower than the points' spacing lets a minimiser slip a curve between the
points (`curve_energy` on a finer basis shows it).

Gradient descent from the straight line stalls where the line crosses a hole in
the data: the RBF variance is flat far from the codes, so only the walls around
the data cost energy. With `nodes` (latent points on the data, e.g. k-means
centres of the codes) the solver first finds the shortest path in a k-nearest-
neighbour graph over the nodes, start and end, edges weighted by their metric
length (Bellman-Ford relaxation in JAX), fits the spline through it, and starts
from whichever of that curve and the straight line has lower energy.

`speed2(args, z, v)` gives v^T M(z) v for latent point z and velocity v; args
(a pytree: model weights, obstacles) is traced, so moving an obstacle does not
recompile.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from fabrax import sharding
from fabrax.skills import spline

Speed2 = Callable[..., jax.Array]

METHODS = ("newton", "adam")


@dataclass(frozen=True)
class GeodesicConfig:
    segments: int = 5  # cubic pieces
    points: int = 20  # energy discretisation points
    method: str = "newton"  # "newton" (exact Hessian, damped) or "adam" (optax)
    iters: int = 300  # most steps
    tol: float = 1e-3  # stop when max |dE/dw| is below tol (1 + E)
    lr: float = 0.02  # adam: step (latent units)
    damping: float = 1e-3  # newton: first lambda, relative to the Hessian's largest |eigenvalue|
    trials: int = 6  # newton: dampings tried per step, 10x apart
    shrink: int = 4  # go on with the running pairs alone once at most 1/shrink of a batch runs (1: never)
    neighbours: int = 8  # graph initialisation: edges per node
    samples: int = 3  # points per edge for its metric length

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"geodesic.method: '{self.method}' is not one of {', '.join(METHODS)}")
        for name in ("segments", "points", "iters", "trials", "shrink"):
            if getattr(self, name) < 1:
                raise ValueError(f"geodesic.{name}: must be at least 1, got {getattr(self, name)}")


class Geodesic(NamedTuple):
    z: jax.Array  # (N, d) curve at the basis' points
    coeffs: jax.Array  # (4S, d) spline coefficients
    energy: jax.Array  # () final energy
    energy0: jax.Array  # () energy of the initial curve
    trace: jax.Array  # (iters,) energy per step (the last value repeated after the stop)
    iters: jax.Array  # () steps taken


class _Run(NamedTuple):
    """One pair's minimisation state."""

    start: jax.Array
    end: jax.Array
    w: jax.Array  # (S + 1, d) free parameters
    e: jax.Array  # () energy at w
    g: jax.Array  # (S + 1, d) its gradient
    aux: Any  # newton: (Hessian eigenvalues, eigenvectors, lambda); adam: optax state
    done: jax.Array  # () the stopping test holds at w
    i: jax.Array  # () steps taken
    trace: jax.Array  # (iters,)


def curve_energy(speed2: Speed2, args, sb: spline.SplineBasis, coeffs):
    """Discretised curve energy of the spline with coefficients (4S, d): Gauss-Legendre quadrature of
    c'^T M(c) c' over the basis' N points. A basis with more points than the solver's checks whether
    those resolved the metric (a metric with walls narrower than the points' spacing lets a curve pass
    between them)."""
    z, v = spline.evaluate(sb, coeffs), spline.evaluate(sb, coeffs, order=1)
    return jnp.sum(sb.weight * jax.vmap(lambda zi, vi: speed2(args, zi, vi))(z, v))


def energy(speed2: Speed2, args, sb: spline.SplineBasis, start, end, w):
    """`curve_energy` of the spline with end points start, end and free parameters w."""
    return curve_energy(speed2, args, sb, spline.coefficients(sb, start, end, w))


def energy_terms(speed2: Speed2, args, sb: spline.SplineBasis, start, end, w):
    """(E, dE/dw (S + 1, d), d2E/dw2 ((S + 1) d, (S + 1) d)) from each point's value, gradient and Hessian
    of f(z, v) = speed2(args, z, v) = v^T M(z) v, chained through the linear maps w -> (z_n, v_n).

    A point's Hessian columns along z come from jvps of the gradient (forward over reverse); its v-v
    block is 2 M(z), by polarisation of f in v, which is quadratic: M_ab = (f(e_a + e_b) - f(2 e_a) / 4
    - f(2 e_b) / 4) / 2, from values alone."""
    d = start.shape[0]
    c = spline.coefficients(sb, start, end, w)
    x = jnp.concatenate([spline.evaluate(sb, c), spline.evaluate(sb, c, order=1)], -1)  # (N, 2d)
    value_grad = jax.value_and_grad(lambda x: speed2(args, x[:d], x[d:]))
    eye = jnp.eye(d, dtype=x.dtype)
    a, b = np.triu_indices(d)

    def point(x):
        tangents = jnp.concatenate([eye, jnp.zeros_like(eye)], 1)  # along z
        (f, g), (_, cols) = jax.vmap(lambda t: jax.jvp(value_grad, (x,), (t,)), out_axes=(None, 0))(tangents)  # (d, 2d)
        pol = jax.vmap(lambda u: speed2(args, x[:d], u))(eye[a] + eye[b])  # f(e_a + e_b), a <= b
        diag = pol[a == b]  # f(2 e_a) = 4 M_aa
        m = jnp.zeros((d, d), x.dtype).at[a, b].set((pol - 0.25 * (diag[a] + diag[b])) / 2.0)
        m = m + jnp.triu(m, 1).T
        h = jnp.concatenate([cols, jnp.concatenate([cols[:, d:].T, 2.0 * m], 1)], 0)  # rows z then v
        return f, g, h

    f, g, h = jax.vmap(point)(x)
    maps = jnp.stack([sb.value @ sb.null, sb.speed @ sb.null], 1)  # (N, 2, S + 1): dz_n/dw and dv_n/dw, per dimension
    grad = jnp.einsum("n,nsj,nsa->ja", sb.weight, maps, g.reshape(-1, 2, d))
    hess = jnp.einsum("n,nsj,ntl,nsatb->jalb", sb.weight, maps, maps, h.reshape(-1, 2, d, 2, d))
    return jnp.sum(sb.weight * f), grad, hess.reshape(w.size, w.size)


_CURVATURE_STEPS = (0.01, 0.1, 1.0)  # newton: step lengths along the most negative curvature, in w units


def _newton(speed2: Speed2, args, sb: spline.SplineBasis, cfg: GeodesicConfig):
    factors = 10.0 ** (jnp.arange(cfg.trials, dtype=jnp.float32) - 1.0)  # lambda x 0.1, 1, 10, ...

    def at(start, end, w):  # energy, gradient, the Hessian's eigen-decomposition and the stopping test
        e, g, h = energy_terms(speed2, args, sb, start, end, w)
        ev, q = jnp.linalg.eigh(h)
        qg = q.T @ g.reshape(-1)
        decrease = 0.5 * jnp.sum(qg**2 / (jnp.abs(ev) + 1e-30))  # what a full step would gain (the Newton decrement)
        flat = (jnp.max(jnp.abs(g)) <= cfg.tol * (1.0 + e)) | (decrease <= cfg.tol**2 * (1.0 + e))
        # a stationary point with negative curvature (a saddle, e.g. a straight line through an obstacle) is no stop
        done = flat & (ev[0] >= -cfg.tol * jnp.max(jnp.abs(ev)))
        return e, g, ev, q, done

    def init(start, end, w):
        e, g, ev, q, done = at(start, end, w)
        return _Run(start, end, w, e, g, (ev, q, jnp.float32(cfg.damping)), done, jnp.int32(0), jnp.full((cfg.iters,), e))

    def step(r: _Run) -> _Run:
        ev, q, lam = r.aux
        qg = q.T @ r.g.reshape(-1)
        lams = lam * factors
        newton = jax.vmap(lambda lm: -(q @ (qg / (jnp.abs(ev) + lm * jnp.max(jnp.abs(ev)) + 1e-30))))(lams)
        down = jnp.where(qg[0] > 0, -1.0, 1.0) * q[:, 0]  # the most negative curvature, downhill
        curvature = jnp.asarray(_CURVATURE_STEPS)[:, None] * down
        trial = r.w[None] + jnp.concatenate([newton, curvature]).reshape((-1,) + r.w.shape)
        e_trial = jax.vmap(lambda w: energy(speed2, args, sb, r.start, r.end, w))(trial)
        e_trial = e_trial.at[cfg.trials :].set(jnp.where(ev[0] < 0, e_trial[cfg.trials :], jnp.inf))
        best = jnp.argmin(e_trial)
        better = e_trial[best] < r.e
        w = jnp.where(better, trial[best], r.w)
        e, g, ev, q, done = at(r.start, r.end, w)
        taken = jnp.where(best < cfg.trials, lams[jnp.minimum(best, cfg.trials - 1)] / 3.0, lam)  # a curvature step keeps lambda
        lam = jnp.where(better, taken, jnp.minimum(lam * 10.0**cfg.trials, 1e8))
        return r._replace(w=w, e=e, g=g, aux=(ev, q, lam), done=done, i=r.i + 1, trace=r.trace.at[r.i].set(e))

    return init, step


def _adam(speed2: Speed2, args, sb: spline.SplineBasis, cfg: GeodesicConfig):
    opt = optax.adam(cfg.lr)

    def at(start, end, w):
        e, g = jax.value_and_grad(lambda w: energy(speed2, args, sb, start, end, w))(w)
        return e, g, jnp.max(jnp.abs(g)) <= cfg.tol * (1.0 + e)

    def init(start, end, w):
        e, g, done = at(start, end, w)
        return _Run(start, end, w, e, g, opt.init(w), done, jnp.int32(0), jnp.full((cfg.iters,), e))

    def step(r: _Run) -> _Run:
        upd, st = opt.update(r.g, r.aux, r.w)
        w = optax.apply_updates(r.w, upd)
        e, g, done = at(r.start, r.end, w)
        return r._replace(w=w, e=e, g=g, aux=st, done=done, i=r.i + 1, trace=r.trace.at[r.i].set(e))

    return init, step


_SMALLEST = 8  # smaller sub-batches save less than their compilation costs


def _loop(step, runs: _Run, cfg: GeodesicConfig) -> _Run:
    """Step every running pair of the batch until none runs; once at most 1/shrink of the current
    (sub-)batch runs, go on with a sub-batch that size, gathered from the running pairs."""

    def running(r: _Run):
        return (r.i < cfg.iters) & ~r.done

    def advance(r: _Run) -> _Run:
        on = running(r)
        new = jax.vmap(step)(r)
        return jax.tree.map(lambda a, b: jnp.where(on.reshape(on.shape + (1,) * (a.ndim - 1)), a, b), new, r)

    sizes = [runs.i.shape[0]]
    while cfg.shrink > 1 and -(-sizes[-1] // cfg.shrink) >= _SMALLEST:
        sizes.append(-(-sizes[-1] // cfg.shrink))
    for k, size in enumerate(sizes):
        after = sizes[k + 1] if k + 1 < len(sizes) else 0
        if k == 0:
            runs = jax.lax.while_loop(lambda r: jnp.sum(running(r)) > after, advance, runs)
            continue
        idx = jnp.argsort(jnp.where(running(runs), 0, 1), stable=True)[:size]  # the running pairs first
        sub = jax.lax.while_loop(lambda r: jnp.sum(running(r)) > after, advance, jax.tree.map(lambda x: x[idx], runs))
        runs = jax.tree.map(lambda x, y: x.at[idx].set(y), runs, sub)
    return runs


def minimise(speed2: Speed2, args, sb: spline.SplineBasis, starts, ends, w0, cfg: GeodesicConfig) -> Geodesic:
    """Geodesics between starts and ends (B, d) from free parameters w0 (B, S + 1, d), one loop for the batch."""
    init, step = (_newton if cfg.method == "newton" else _adam)(speed2, args, sb, cfg)
    runs = jax.vmap(init)(starts, ends, w0)
    e0 = runs.e
    runs = _loop(step, runs, cfg)
    trace = jnp.where(jnp.arange(cfg.iters) < runs.i[:, None], runs.trace, runs.e[:, None])
    c = jax.vmap(spline.coefficients, in_axes=(None, 0, 0, 0))(sb, starts, ends, runs.w)
    return Geodesic(jax.vmap(lambda c: spline.evaluate(sb, c))(c), c, runs.e, e0, trace, runs.i)


def shortest(speed2: Speed2, args, sb: spline.SplineBasis, start, end, cfg: GeodesicConfig, w0=None) -> Geodesic:
    """Minimise the curve energy between start and end (d,); w0 (S + 1, d) overrides the straight-line start."""
    w0 = spline.straight(sb, start, end) if w0 is None else w0
    return jax.tree.map(lambda x: x[0], minimise(speed2, args, sb, start[None], end[None], w0[None], cfg))


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
    lines = jax.vmap(lambda a, b: spline.straight(sb, a, b))
    if nodes is None:
        return jax.jit(lambda args, starts, ends: sharding.batched(lambda a, b: minimise(speed2, args, sb, a, b, lines(a, b), cfg))(starts, ends))
    nodes = jnp.asarray(nodes, jnp.float32)

    def initial(args, weights, a, b):  # the graph path's spline or the straight line, whichever has lower energy
        w_graph = graph_path(speed2, args, nodes, weights, sb, a, b, cfg.neighbours, cfg.samples)
        w_line = spline.straight(sb, a, b)
        e = lambda w: energy(speed2, args, sb, a, b, w)  # noqa: E731
        return jnp.where(e(w_graph) < e(w_line), w_graph, w_line)

    def run(args, starts, ends):
        weights = graph(speed2, args, nodes, cfg.neighbours, cfg.samples)
        w0 = lambda a, b: jax.vmap(lambda a, b: initial(args, weights, a, b))(a, b)  # noqa: E731
        return sharding.batched(lambda a, b: minimise(speed2, args, sb, a, b, w0(a, b), cfg))(starts, ends)

    return jax.jit(run)
