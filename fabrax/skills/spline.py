"""Cubic splines in latent space with fixed end points and C^2 continuity (paper §4, eq. 29).

A curve on t in [0, 1] is S cubic segments on uniform knots t_i = i / S,
c(t) = sum_k a_ik (t - t_i)^k on segment i. The constraints (two end points;
equal value, slope and curvature at the S - 1 interior knots) are linear in the
4S coefficients per latent dimension, A a = B [start; end]. Every admissible
spline is then a = P [start; end] + N w with P = pinv(A) B a particular solution
and N an orthonormal basis of the null space of A (S + 1 free parameters per
dimension), so an optimiser over w can never break continuity or move the end
points. The curvature row is 2 a_(i+1),2 on the right-hand side: the second
derivative of a_k t^k at t = 0 is k (k - 1) a_k.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

RULES = ("chord", "gauss")


@struct.dataclass
class SplineBasis:
    """Static matrices of one spline family and its energy discretisation, built by `basis`."""

    ends: jax.Array  # (4S, 2): coefficients from [start; end]
    null: jax.Array  # (4S, S + 1): orthonormal null-space basis
    value: jax.Array  # (N, 4S): c(t_n) = value @ coefficients
    speed: jax.Array  # (N, 4S): c'(t_n)
    line: jax.Array  # (4S, 2): coefficients of the straight line start -> end
    fit: jax.Array  # (S + 1, N): least-squares free parameters of the spline through N given points
    t: jax.Array  # (N,) evaluation times: Gauss-Legendre nodes, N / S per segment; chord: N + 1 equally spaced vertices
    weight: jax.Array  # (N,) quadrature weights (sum 1): int_0^1 f dt ~ sum weight f(t); chord: 1 / dt per chord
    rule: str = struct.field(pytree_node=False, default="gauss")


def _powers(t, seg, segments: int, order: int) -> np.ndarray:
    """Rows (len(t), 4S) evaluating the `order`-th derivative at times t on segments seg."""
    h = t - seg / segments
    rows = np.zeros((len(t), 4 * segments))
    for k in range(order, 4):
        fac = np.prod(np.arange(k - order + 1, k + 1)) if order else 1.0
        rows[np.arange(len(t)), 4 * seg + k] = fac * h ** (k - order)
    return rows


def constraints(segments: int) -> tuple[np.ndarray, np.ndarray]:
    """(A, B): A a = B [start; end] holds exactly for the admissible coefficients a (4S per dimension)."""
    s, h = segments, 1.0 / segments
    a_rows, b_rows = [], []
    start = np.zeros(4 * s)
    start[0] = 1.0
    a_rows.append(start), b_rows.append([1.0, 0.0])
    a_rows.append(_powers(np.array([1.0]), np.array([s - 1]), s, 0)[0]), b_rows.append([0.0, 1.0])
    for i in range(s - 1):
        for order in range(3):
            row = _powers(np.array([(i + 1) * h]), np.array([i]), s, order)[0]
            row[4 * (i + 1) + order] -= 1.0 if order < 2 else 2.0
            a_rows.append(row), b_rows.append([0.0, 0.0])
    return np.asarray(a_rows), np.asarray(b_rows)


def basis(segments: int = 5, points: int = 20, rule: str = "gauss") -> SplineBasis:
    """Spline family of `segments` cubic pieces with the energy discretised by `rule`:

    - "gauss": `points` Gauss-Legendre nodes (points / segments per piece, at least 3), which integrate
      polynomials of degree 5 exactly on each piece, so under a constant metric the discretised energy is
      the curve energy itself and its minimiser the constant-speed line;
    - "chord": `points` equal chords between points + 1 vertices (t = 0, 1 / N, ..., 1), the energy of
      the decoded polyline (`fabrax.skills.geodesic`)."""
    if rule not in RULES:
        raise ValueError(f"geodesic.rule: '{rule}' is not one of {', '.join(RULES)}")
    a, b = constraints(segments)
    ends = np.linalg.pinv(a) @ b
    _, sv, vt = np.linalg.svd(a)
    rank = int(np.sum(sv > 1e-10 * sv[0]))
    null = vt[rank:].T
    assert null.shape[1] == segments + 1, "the C^2 constraints lost rank"
    if rule == "gauss":
        per = max(3, int(round(points / segments)))
        x, w = np.polynomial.legendre.leggauss(per)
        t = ((np.arange(segments)[:, None] + 0.5 * (x[None] + 1.0)) / segments).reshape(-1)
        weight = np.tile(0.5 * w / segments, segments)
        seg = np.repeat(np.arange(segments), per)
    else:
        t = np.linspace(0.0, 1.0, points + 1)
        weight = np.full(points, float(points))
        seg = np.minimum((t * segments).astype(int), segments - 1)
    line = np.zeros((4 * segments, 2))
    knots = np.arange(segments) / segments
    line[4 * np.arange(segments), 0], line[4 * np.arange(segments), 1] = 1.0 - knots, knots
    line[4 * np.arange(segments) + 1, 0], line[4 * np.arange(segments) + 1, 1] = -1.0, 1.0
    value = _powers(t, seg, segments, 0)
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    speed = _powers(t, seg, segments, 1)
    return SplineBasis(f(ends), f(null), f(value), f(speed), f(line), f(np.linalg.pinv(value @ null)), f(t), f(weight), rule)


def coefficients(sb: SplineBasis, start, end, w):
    """Spline coefficients (4S, d) from end points (d,) and free parameters w (S + 1, d)."""
    return sb.ends @ jnp.stack([start, end]) + sb.null @ w


def straight(sb: SplineBasis, start, end):
    """Free parameters w of the straight line from start to end at constant speed."""
    ab = jnp.stack([start, end])
    return sb.null.T @ (sb.line @ ab - sb.ends @ ab)


def through(sb: SplineBasis, start, end, path):
    """Free parameters w of the admissible spline closest (least squares) to `path` (N, d) at the basis' times."""
    ab = jnp.stack([start, end])
    return sb.fit @ (path - sb.value @ (sb.ends @ ab))


def at(coeffs, t, order: int = 0):
    """Curve (order 0), velocity (1) or acceleration (2) of the spline with coefficients (4S, d) at times t (static)."""
    segments = coeffs.shape[0] // 4
    t = np.asarray(t, np.float64)
    seg = np.minimum((t * segments).astype(int), segments - 1)
    return jnp.asarray(_powers(t, seg, segments, order), coeffs.dtype) @ coeffs


def dense(coeffs, points: int = 100):
    """The curve at `points` equally spaced times, for decoding and drawing."""
    return at(coeffs, np.linspace(0.0, 1.0, points))


def evaluate(sb: SplineBasis, coeffs, t=None, order: int = 0):
    """Curve (order 0), velocity (1) or acceleration (2) at times t (default: the basis' points)."""
    if t is None and order < 2:
        return (sb.value if order == 0 else sb.speed) @ coeffs
    return at(coeffs, np.asarray(sb.t) if t is None else t, order)
