"""Hand-fused reductions shared by the distance terms: many sums and minima over one axis in a
single variadic reduction, symmetric metrics packed by their upper triangle, and the pullback of
per-sphere 3-D specs through the spheres' Jacobians (eq. 2.6, the transform tree's per-sphere
reduction of DESIGN.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fabrax.robot.kinematics import PointKinematics
from fabrax.scene import FAR
from fabrax.soa import dot0, matvec0


def _reduce(sums: list[jax.Array], mins: list[jax.Array] = (), axis: int = 0) -> tuple[list, list]:
    """Sums and minima of equally shaped arrays over one axis, in a single variadic reduction.

    One reduce shares the arithmetic that produces its operands (per-pair
    distances and energies) among all outputs; separate reductions would each
    fuse, and so recompute, that arithmetic.
    """
    ops = tuple(sums) + tuple(mins)
    k = len(sums)
    init = tuple(jnp.zeros((), o.dtype) for o in sums) + tuple(jnp.full((), FAR, o.dtype) for o in mins)

    def combine(a, b):
        return tuple(x + y for x, y in zip(a[:k], b[:k])) + tuple(jnp.minimum(x, y) for x, y in zip(a[k:], b[k:]))

    out = jax.lax.reduce(ops, init, combine, (axis % ops[0].ndim,))
    return list(out[:k]), list(out[k:])


def _unpack_metric(d: int, values: list[jax.Array]) -> jax.Array:
    upper = [(a, b) for a in range(d) for b in range(a, d)]
    metric = [[None] * d for _ in range(d)]
    for (a, b), val in zip(upper, values):
        metric[a][b] = metric[b][a] = val
    return jnp.stack([jnp.stack(row) for row in metric])


def _metric_products(u: list[jax.Array], weight: jax.Array) -> list[jax.Array]:
    """weight u_a u_b for the upper triangle (a <= b) of a metric sum_k weight_k u_k u_k^T."""
    wu = [weight * ua for ua in u]
    return [wu[a] * u[b] for a in range(len(u)) for b in range(a, len(u))]


def _pull_spheres(kin: PointKinematics, m3, g3, e3, f3) -> tuple:
    """One pullback per sphere of its reduced 3-D spec (eq. 2.6); m3 (3, 3, N), vectors (3, N)."""
    mj = jnp.stack([sum(m3[c, d][None] * kin.jac[d] for d in range(3)) for c in range(3)])  # (3, n, N): M3 J per sphere
    ma = matvec0(m3, kin.jdqd)  # (3, N)
    n = kin.jac.shape[1]
    upper = [(a, b) for a in range(n) for b in range(a, n)]
    jt_m_j = [dot0(kin.jac[:, a], mj[:, b]) for a, b in upper]  # (N,) each
    pulled = [dot0(kin.jac[:, a], v) for v in (g3 + ma, e3 + ma, f3) for a in range(n)]
    sums, _ = _reduce(jt_m_j + pulled, axis=-1)
    rest = sums[len(upper) :]
    return _unpack_metric(n, sums[: len(upper)]), jnp.stack(rest[:n]), jnp.stack(rest[n : 2 * n]), jnp.stack(rest[2 * n :])
