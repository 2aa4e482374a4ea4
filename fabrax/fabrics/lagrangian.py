"""Equations of motion of Lagrangians by autodiff (thesis §2.1.4, §2.1.7).

For L(x, xd): M = d^2L/dxd^2, f = (d/dx dL/dxd) xd - dL/dx, and the energy
(Hamiltonian) H = dL/dxd . xd - L (eq. 2.11), which equals L for a Finsler
energy (HD2 in xd, eq. 2.46). Works for scalar and vector task spaces.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

Lagrangian = Callable[[jax.Array, jax.Array], jax.Array]


def eom(lagrangian: Lagrangian, x: jax.Array, xd: jax.Array):
    """(M, f, H) of the Euler-Lagrange equation M xdd + f = 0 of `lagrangian` at (x, xd)."""
    dl_dxd = jax.grad(lagrangian, argnums=1)
    p, dp_dx_xd = jax.jvp(lambda x_: dl_dxd(x_, xd), (x,), (xd,))
    M = jax.jacfwd(dl_dxd, argnums=1)(x, xd)
    f = dp_dx_xd - jax.grad(lagrangian, argnums=0)(x, xd)
    H = jnp.sum(p * xd) - lagrangian(x, xd)
    return M, f, H


def eom_elementwise(lagrangian: Lagrangian, x: jax.Array, xd: jax.Array):
    """`eom` for a separable Lagrangian sum_k L(x_k, xd_k) of scalar coordinates, all at once.

    Each scalar term's M, f and H are the elementwise results; differentiating
    the sum once with `grad` and `jvp` gives all of them without per-term
    Jacobians (the same numbers as `jax.vmap(eom)`, far cheaper).
    """
    total = lambda a, b: jnp.sum(lagrangian(a, b))  # noqa: E731
    dl_dxd = jax.grad(total, argnums=1)
    p, dp_dx_xd = jax.jvp(lambda a: dl_dxd(a, xd), (x,), (xd,))
    M = jax.jvp(lambda b: dl_dxd(x, b), (xd,), (jnp.ones_like(xd),))[1]
    f = dp_dx_xd - jax.grad(total, argnums=0)(x, xd)
    H = p * xd - lagrangian(x, xd)
    return M, f, H


def hd2_geometry(potential: Callable[[jax.Array], jax.Array]) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """h2(x, xd) = |xd|^2 dpsi/dx: the geometry xdd = -|xd|^2 dpsi/dx of thesis §3.3 (HD2 in xd)."""

    def h2(x, xd):
        return jnp.sum(xd * xd) * jax.grad(potential)(x)

    return h2
