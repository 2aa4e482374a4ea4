"""Antipodally symmetric von Mises-Fisher mixture on the unit quaternions S^3.

Eq. 15-16 of the motion-skills paper (riemannian_motion_skills_paper §3.1.2):
vMF(q | mu, kappa) = C_p(kappa) exp(kappa mu^T q) with
C_p(kappa) = kappa^(p/2-1) / ((2 pi)^(p/2) I_(p/2-1)(kappa)); on S^3 p = 4, so the
Bessel function is I_1. Eq. 17 mixes the components at mu and -mu with equal
weights, so that q and -q (the same rotation) are equally likely.
The normaliser is computed from the exponentially scaled Bessel function
(log I_1(k) = log i1e(k) + k), finite from kappa -> 0 (the uniform density
1 / (2 pi^2)) to kappa in the thousands.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax.scipy.special import i1e

KAPPA_MIN = 1e-6


def log_normalizer(kappa):
    """log C_4(kappa), eq. 16 on S^3."""
    k = jnp.maximum(kappa, KAPPA_MIN)
    return jnp.log(k) - 2.0 * jnp.log(2.0 * jnp.pi) - (jnp.log(i1e(k)) + k)


def log_vmf(q, mu, kappa):
    """log vMF(q | mu, kappa), eq. 15; q, mu unit 4-vectors (..., 4)."""
    return log_normalizer(kappa) + kappa * jnp.sum(mu * q, axis=-1)


def log_antipodal(q, mu, kappa):
    """log of eq. 17: 0.5 vMF(q | mu, kappa) + 0.5 vMF(q | -mu, kappa)."""
    m = kappa * jnp.sum(mu * q, axis=-1)
    return log_normalizer(kappa) + jnp.logaddexp(m, -m) - jnp.log(2.0)
