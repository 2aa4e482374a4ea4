"""Geodesics as energy-minimising cubic splines (paper §4, eq. 29).

The curve energy E(c) = int_0^1 c'(t)^T M(c(t)) c'(t) dt is minimised over the
spline's free parameters w, starting from the straight latent line (or a graph
path, below). Under a Riemannian metric the minimiser of the energy is a
constant-speed length minimiser (a geodesic). Two discretisations
(`GeodesicConfig.rule`):

- "chord" (default): the energy of the decoded polyline, N sum_n |h(z_n+1) - h(z_n)|^2
  over N equal chords of the curve, for a pullback metric M = J_h^T J_h of a decoder h
  (Shao et al. 2018, which the paper cites for direct minimisation). By Cauchy-Schwarz
  each chord's term is at most the energy of the curve between its vertices, and equal
  for a curve that the decoder maps to a constant-speed segment. A thin wall of the
  decoder's variance, or an orientation that flips where the quaternion decoder's raw
  output passes near zero, costs the whole jump of h between two vertices however
  quickly the curve crosses it; a quadrature of v^T M v at points does not see a wall
  between its points, and a minimiser learns to cross walls there.
- "gauss": Gauss-Legendre quadrature of v^T M(z) v at N points, for any metric given
  as speed2 alone.

Every solve also reports the energy of the solved curves at `check` times the points
(`Geodesic.resolved`): near the solved energy where the discretisation resolves the metric.

Two minimisers (`GeodesicConfig.method`):

- "newton" (default): damped Newton steps with the exact Hessian. The energy is a
  sum over sites n of f(x_n) with x_n = (z_n, v_n) (gauss) or (z_n, z_n+1) (chord),
  all linear in w, so the Hessian is assembled from each site's 2d x 2d Hessian of f
  (forward over reverse; under gauss the v-v block by polarisation). A step uses the
  Hessian's absolute eigenvalues (saddle-free) plus a damping lambda times the largest;
  each iteration tries `trials` dampings 10x apart, and steps along the most negative
  curvature, in one energy pass and takes the lowest energy. A step that lowers no
  energy is not taken and lambda grows.
- "adam": optax's Adam at step `lr`.

Both stop when the gradient's largest entry falls below `tol` (1 + E) or after
`iters` steps. Newton also stops when a full step would lower the energy by
less than `tol`^2 (1 + E) (in float32 a stiff obstacle metric can hold the
gradient above `tol` at the minimum), and only where the Hessian has no
eigenvalue below -`tol` times its largest, so it does not stop at a saddle.

A batch of start/goal pairs runs in one loop. Once at most 1/`shrink` of the
pairs still run, those go on alone as a smaller batch (sizes B, B / shrink,
..., down to `fabrax.shrink.SMALLEST` = 16), so a few slow pairs do not make
the batch pay for their iterations.

Gradient descent from the straight line stalls where the line crosses a hole in
the data: the RBF variance is flat far from the codes, so only the walls around
the data cost energy. With `nodes` (latent points on the data, e.g. k-means
centres of the codes) the solver first finds the shortest path in a k-nearest-
neighbour graph over the nodes, start and end, edges weighted by their metric
length (Bellman-Ford relaxation in JAX), fits the spline through it, and starts
from whichever of that curve and the straight line has lower energy.

The metric is a `CurveMetric` (or a bare speed2 for rule "gauss"): speed2(args, z, v)
gives v^T M(z) v, chord2(args, za, zb) the squared decoded length of the chord
za -> zb; args (a pytree: model weights, obstacles) is traced, so moving an obstacle
does not recompile.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from fabrax import sharding
from fabrax.shrink import loop as shrink_loop
from fabrax.skills import spline

Speed2 = Callable[..., jax.Array]
Chord2 = Callable[..., jax.Array]

METHODS = ("newton", "adam")


class CurveMetric(NamedTuple):
    """A latent metric as curve energies need it."""

    speed2: Speed2  # (args, z, v) -> v^T M(z) v
    chord2: Chord2 | None = None  # (args, za, zb) -> |h(zb) - h(za)|^2 for a pullback metric of a decoder h


def as_metric(metric) -> CurveMetric:
    """A `CurveMetric`, or a bare speed2 function as one (for rule "gauss")."""
    return metric if isinstance(metric, CurveMetric) else CurveMetric(metric)


@dataclass(frozen=True)
class GeodesicConfig:
    segments: int = 5  # cubic pieces
    points: int = 20  # energy discretisation: chords (rule chord) or quadrature points (rule gauss)
    rule: str = "chord"  # "chord" (decoded polyline; needs chord2) or "gauss" (quadrature of speed2)
    check: int = 10  # Geodesic.resolved: the solved curves' energy at check x points (0: not computed)
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
        if self.rule not in spline.RULES:
            raise ValueError(f"geodesic.rule: '{self.rule}' is not one of {', '.join(spline.RULES)}")
        for name in ("segments", "points", "iters", "trials", "shrink"):
            if getattr(self, name) < 1:
                raise ValueError(f"geodesic.{name}: must be at least 1, got {getattr(self, name)}")
        if self.check < 0:
            raise ValueError(f"geodesic.check: must be 0 (off) or the factor on the points to check at, got {self.check}")

    def basis(self) -> spline.SplineBasis:
        """The spline family and energy discretisation of this config."""
        return spline.basis(self.segments, self.points, self.rule)


class Geodesic(NamedTuple):
    z: jax.Array  # (N, d) curve at the basis' points
    coeffs: jax.Array  # (4S, d) spline coefficients
    energy: jax.Array  # () final energy
    energy0: jax.Array  # () energy of the initial curve
    trace: jax.Array  # (iters,) energy per step (the last value repeated after the stop)
    iters: jax.Array  # () steps taken
    resolved: jax.Array  # () the final curve's energy at `check` x the points (nan where check = 0)


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


def curve_energy(metric, args, sb: spline.SplineBasis, coeffs):
    """Discretised curve energy of the spline with coefficients (4S, d) under the basis' rule. A basis with
    more points than the solver's checks whether those resolved the metric."""
    m = as_metric(metric)
    z = spline.evaluate(sb, coeffs)
    if sb.rule == "gauss":
        v = spline.evaluate(sb, coeffs, order=1)
        return jnp.sum(sb.weight * jax.vmap(lambda zi, vi: m.speed2(args, zi, vi))(z, v))
    return jnp.sum(sb.weight * jax.vmap(lambda za, zb: _chord2(m)(args, za, zb))(z[:-1], z[1:]))


def _chord2(m: CurveMetric) -> Chord2:
    if m.chord2 is None:
        raise ValueError("geodesic.rule: 'chord' needs a metric with chord2 (a CurveMetric of a decoder, e.g. metric.curve_metric); use rule 'gauss'")
    return m.chord2


def energy(metric, args, sb: spline.SplineBasis, start, end, w):
    """`curve_energy` of the spline with end points start, end and free parameters w."""
    return curve_energy(metric, args, sb, spline.coefficients(sb, start, end, w))


def energy_terms(metric, args, sb: spline.SplineBasis, start, end, w):
    """(E, dE/dw (S + 1, d), d2E/dw2 ((S + 1) d, (S + 1) d)) from each site's value, gradient and Hessian of
    f(x_n), chained through the linear maps w -> x_n = (z_n, v_n) (gauss: f = speed2) or (z_n, z_n+1)
    (chord: f = chord2).

    A site's Hessian columns come from jvps of the gradient (forward over reverse). Under gauss its v-v block
    is 2 M(z), by polarisation of f in v, which is quadratic: M_ab = (f(e_a + e_b) - f(2 e_a) / 4 - f(2 e_b) / 4) / 2,
    from values alone, so only the d columns along z need jvps."""
    m = as_metric(metric)
    d = start.shape[0]
    c = spline.coefficients(sb, start, end, w)
    z = spline.evaluate(sb, c)
    vn = sb.value @ sb.null  # (N, S + 1): dz_n/dw, per dimension
    eye = jnp.eye(d, dtype=z.dtype)
    if sb.rule == "gauss":
        f2 = lambda x: m.speed2(args, x[:d], x[d:])  # noqa: E731
        x = jnp.concatenate([z, spline.evaluate(sb, c, order=1)], -1)  # (N, 2d)
        maps = jnp.stack([vn, sb.speed @ sb.null], 1)  # (N, 2, S + 1)
        tangents = jnp.concatenate([eye, jnp.zeros_like(eye)], 1)  # along z
    else:
        chord2 = _chord2(m)
        f2 = lambda x: chord2(args, x[:d], x[d:])  # noqa: E731
        x = jnp.concatenate([z[:-1], z[1:]], -1)  # (N, 2d)
        maps = jnp.stack([vn[:-1], vn[1:]], 1)
        tangents = jnp.eye(2 * d, dtype=z.dtype)
    value_grad = jax.value_and_grad(f2)
    a, b = np.triu_indices(d)

    def site(x):
        (f, g), (_, cols) = jax.vmap(lambda t: jax.jvp(value_grad, (x,), (t,)), out_axes=(None, 0))(tangents)
        if sb.rule == "chord":
            return f, g, cols
        pol = jax.vmap(lambda u: m.speed2(args, x[:d], u))(eye[a] + eye[b])  # f(e_a + e_b), a <= b
        diag = pol[a == b]  # f(2 e_a) = 4 M_aa
        mm = jnp.zeros((d, d), x.dtype).at[a, b].set((pol - 0.25 * (diag[a] + diag[b])) / 2.0)
        mm = mm + jnp.triu(mm, 1).T
        return f, g, jnp.concatenate([cols, jnp.concatenate([cols[:, d:].T, 2.0 * mm], 1)], 0)  # rows z then v

    f, g, h = jax.vmap(site)(x)
    grad = jnp.einsum("n,nsj,nsa->ja", sb.weight, maps, g.reshape(-1, 2, d))
    hess = jnp.einsum("n,nsj,ntl,nsatb->jalb", sb.weight, maps, maps, h.reshape(-1, 2, d, 2, d))
    return jnp.sum(sb.weight * f), grad, hess.reshape(w.size, w.size)


_CURVATURE_STEPS = (0.01, 0.1, 1.0)  # newton: step lengths along the most negative curvature, in w units


def _newton(metric, args, sb: spline.SplineBasis, cfg: GeodesicConfig):
    factors = 10.0 ** (jnp.arange(cfg.trials, dtype=jnp.float32) - 1.0)  # lambda x 0.1, 1, 10, ...

    def at(start, end, w):  # energy, gradient, the Hessian's eigen-decomposition and the stopping test
        e, g, h = energy_terms(metric, args, sb, start, end, w)
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
        e_trial = jax.vmap(lambda w: energy(metric, args, sb, r.start, r.end, w))(trial)
        e_trial = e_trial.at[cfg.trials :].set(jnp.where(ev[0] < 0, e_trial[cfg.trials :], jnp.inf))
        best = jnp.argmin(e_trial)
        better = e_trial[best] < r.e
        w = jnp.where(better, trial[best], r.w)
        e, g, ev, q, done = at(r.start, r.end, w)
        taken = jnp.where(best < cfg.trials, lams[jnp.minimum(best, cfg.trials - 1)] / 3.0, lam)  # a curvature step keeps lambda
        lam = jnp.where(better, taken, jnp.minimum(lam * 10.0**cfg.trials, 1e8))
        return r._replace(w=w, e=e, g=g, aux=(ev, q, lam), done=done, i=r.i + 1, trace=r.trace.at[r.i].set(e))

    return init, step


def _adam(metric, args, sb: spline.SplineBasis, cfg: GeodesicConfig):
    opt = optax.adam(cfg.lr)

    def at(start, end, w):
        e, g = jax.value_and_grad(lambda w: energy(metric, args, sb, start, end, w))(w)
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


def _loop(step, runs: _Run, cfg: GeodesicConfig) -> _Run:
    """Step every running pair of the batch until none runs, the batch shrinking to its running pairs (`fabrax.shrink`)."""

    def running(r: _Run):
        return (r.i < cfg.iters) & ~r.done

    def advance(r: _Run) -> _Run:
        on = running(r)
        new = jax.vmap(step)(r)
        return jax.tree.map(lambda a, b: jnp.where(on.reshape(on.shape + (1,) * (a.ndim - 1)), a, b), new, r)

    return shrink_loop(advance, running, runs, cfg.shrink)


def minimise(metric, args, sb: spline.SplineBasis, starts, ends, w0, cfg: GeodesicConfig) -> Geodesic:
    """Geodesics between starts and ends (B, d) from free parameters w0 (B, S + 1, d), one loop for the batch."""
    init, step = (_newton if cfg.method == "newton" else _adam)(metric, args, sb, cfg)
    runs = jax.vmap(init)(starts, ends, w0)
    e0 = runs.e
    runs = _loop(step, runs, cfg)
    trace = jnp.where(jnp.arange(cfg.iters) < runs.i[:, None], runs.trace, runs.e[:, None])
    c = jax.vmap(spline.coefficients, in_axes=(None, 0, 0, 0))(sb, starts, ends, runs.w)
    if cfg.check:
        fine = spline.basis(cfg.segments, cfg.check * sb.weight.shape[0], sb.rule)
        resolved = jax.vmap(lambda c: curve_energy(metric, args, fine, c))(c)
    else:
        resolved = jnp.full_like(runs.e, jnp.nan)
    return Geodesic(jax.vmap(lambda c: spline.evaluate(sb, c))(c), c, runs.e, e0, trace, runs.i, resolved)


def shortest(metric, args, sb: spline.SplineBasis, start, end, cfg: GeodesicConfig, w0=None) -> Geodesic:
    """Minimise the curve energy between start and end (d,); w0 (S + 1, d) overrides the straight-line start."""
    w0 = spline.straight(sb, start, end) if w0 is None else w0
    return jax.tree.map(lambda x: x[0], minimise(metric, args, sb, start[None], end[None], w0[None], cfg))


def _edge_length(metric: CurveMetric, args, a, b, samples: int):
    """Metric length of the straight segment a -> b: the decoded length of its `samples` chords where the metric
    has chord2, else sqrt of its mean squared speed at `samples` midpoints."""
    if metric.chord2 is not None:
        s = jnp.arange(samples + 1) / samples
        p = a + s[:, None] * (b - a)
        return jnp.sum(jnp.sqrt(jax.vmap(lambda u, v: metric.chord2(args, u, v))(p[:-1], p[1:])))
    s = (jnp.arange(samples) + 0.5) / samples
    return jnp.sqrt(jnp.mean(jax.vmap(lambda si: metric.speed2(args, a + si * (b - a), b - a))(s)))


def graph(metric, args, nodes, k: int, samples: int):
    """Weights (V, V) of the symmetric k-nearest-neighbour graph over nodes (V, d); inf where no edge."""
    metric = as_metric(metric)
    v = nodes.shape[0]
    d2 = jnp.sum((nodes[:, None] - nodes[None]) ** 2, -1) + jnp.where(jnp.eye(v, dtype=bool), jnp.inf, 0.0)
    nbr = jnp.argsort(d2, axis=1)[:, :k]
    lengths = jax.vmap(lambda a, bs: jax.vmap(lambda b: _edge_length(metric, args, a, b, samples))(nodes[bs]))(nodes, nbr)
    w = jnp.full((v, v), jnp.inf).at[jnp.arange(v)[:, None], nbr].set(lengths)
    return jnp.minimum(w, w.T)


def graph_path(metric, args, nodes, weights, sb: spline.SplineBasis, start, end, k: int, samples: int):
    """Free parameters w of the spline through the graph's shortest path from start to end."""
    metric = as_metric(metric)
    v = nodes.shape[0]
    pts = jnp.concatenate([nodes, start[None], end[None]])
    links = []
    for p in (start, end):  # start (row v) and end (row v + 1) join their k nearest nodes
        nbr = jnp.argsort(jnp.sum((nodes - p) ** 2, -1))[:k]
        links.append(jnp.full(v, jnp.inf).at[nbr].set(jax.vmap(lambda b: _edge_length(metric, args, p, b, samples))(nodes[nbr])))
    w = jnp.full((v + 2, v + 2), jnp.inf).at[:v, :v].set(weights)
    w = w.at[v, :v].set(links[0]).at[:v, v].set(links[0]).at[v + 1, :v].set(links[1]).at[:v, v + 1].set(links[1])
    w = w.at[v, v + 1].set(_edge_length(metric, args, start, end, samples)).at[v + 1, v].set(w[v, v + 1])

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


def solver(metric, cfg: GeodesicConfig = GeodesicConfig(), nodes=None):
    """jitted (args, starts (B, d), ends (B, d)) -> batched `Geodesic`, one loop for all pairs, split over
    the local devices (`fabrax.sharding.batched`). metric: a `CurveMetric` (rule chord needs its chord2),
    or speed2 alone for rule gauss.
    nodes (V, d): latent points on the data for the graph initialisation (None: straight-line start)."""
    metric = as_metric(metric)
    if cfg.rule == "chord":
        _chord2(metric)
    sb = cfg.basis()
    lines = jax.vmap(lambda a, b: spline.straight(sb, a, b))
    if nodes is None:
        return jax.jit(lambda args, starts, ends: sharding.batched(lambda a, b: minimise(metric, args, sb, a, b, lines(a, b), cfg))(starts, ends))
    nodes = jnp.asarray(nodes, jnp.float32)

    def initial(args, weights, a, b):  # the graph path's spline or the straight line, whichever has lower energy
        w_graph = graph_path(metric, args, nodes, weights, sb, a, b, cfg.neighbours, cfg.samples)
        w_line = spline.straight(sb, a, b)
        e = lambda w: energy(metric, args, sb, a, b, w)  # noqa: E731
        return jnp.where(e(w_graph) < e(w_line), w_graph, w_line)

    def run(args, starts, ends):
        weights = graph(metric, args, nodes, cfg.neighbours, cfg.samples)
        w0 = lambda a, b: jax.vmap(lambda a, b: initial(args, weights, a, b))(a, b)  # noqa: E731
        return sharding.batched(lambda a, b: minimise(metric, args, sb, a, b, w0(a, b), cfg))(starts, ends)

    return jax.jit(run)
