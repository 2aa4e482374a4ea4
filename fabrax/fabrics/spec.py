"""Spectral semi-sprays and their algebra (thesis §2.1.1, §2.1.5, §2.1.9).

A spec (M, f) stands for M xdd + f = 0. Everything here is a small pure
function on arrays; batch with `jax.vmap`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from fabrax.fabrics.linalg import cholesky_solve
from fabrax.soa import matvec


@struct.dataclass
class Spec:
    M: jax.Array  # (..., d, d)
    f: jax.Array  # (..., d)

    def __add__(self, other: "Spec") -> "Spec":
        return combine(self, other)


def pullback(spec: Spec, jac: jax.Array, jdqd: jax.Array) -> Spec:
    """pull_phi (M, f)_X = (J^T M J, J^T (f + M Jdot qd))_Q  (eq. 2.6)."""
    mj = spec.M @ jac
    return Spec(jac.T @ mj, jac.T @ (spec.f + spec.M @ jdqd))


def combine(*specs: Spec) -> Spec:
    """sum_i (M_i, f_i) = (sum M_i, sum f_i)  (eq. 2.8)."""
    return Spec(sum(s.M for s in specs), sum(s.f for s in specs))


def solve(spec: Spec) -> jax.Array:
    """The acceleration xdd = -M^-1 f of a spec with positive definite M (Cholesky)."""
    return -cholesky_solve(spec.M, spec.f)


def energize_alpha(M: jax.Array, f_geom: jax.Array, f_energy: jax.Array, xd: jax.Array, eps: float = 1e-8) -> jax.Array:
    """alpha = -(xd^T M xd)^-1 xd^T [M h - f_e]  (eq. 2.26), with M h given as f_geom.

    xd^T (M h - f_e) is HD3 and xd^T M xd HD2 in xd, so alpha xd -> 0 as xd -> 0;
    `eps` guards the division there.
    """
    return -jnp.sum(xd * (f_geom - f_energy), -1) / (jnp.sum(xd * matvec(M, xd), -1) + eps)


def energize(M: jax.Array, f_geom: jax.Array, f_energy: jax.Array, xd: jax.Array, eps: float = 1e-8) -> Spec:
    """energize_Le{(I, h)} = (M_e, f_e + P_e[M_e h - f_e]) = (M_e, M_e h + alpha M_e xd)  (eqs. 2.27, 2.33).

    The added term is zero-work (xd^T P_e g = 0, eq. 2.28), so the result conserves
    the energy of L_e while tracing the paths of xdd + h = 0.
    """
    alpha = energize_alpha(M, f_geom, f_energy, xd, eps)
    return Spec(M, f_geom + alpha[..., None] * matvec(M, xd))
