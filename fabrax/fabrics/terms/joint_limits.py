"""Joint-limit repulsion in distance space (thesis §3.3.3)."""

from __future__ import annotations

import jax.numpy as jnp

from fabrax.fabrics.terms.base import Contribution, Term, TermInputs, _params
from fabrax.fabrics.terms.distance import _distance_terms


def joint_limits(name: str = "joint_limits", **overrides) -> Term:
    """Distance-space repulsion from both limits of every joint (thesis §3.3.3, x = q - lower, upper - q)."""
    defaults = dict(
        k_metric=0.2, sigma=0.05, reach=0.3, k_barrier=0.5, k_soft=0.5, soft_width=0.03, x0=0.05, floor=1e-3, k_force=0.05, force_reach=0.1
    )
    init = _params(defaults, overrides, name)

    def apply(p, inp: TermInputs) -> Contribution:
        lo, hi = inp.robot.lower, inp.robot.upper
        finite = jnp.isfinite(lo) & jnp.isfinite(hi)
        x = jnp.stack([inp.q - jnp.where(finite, lo, -1e3), jnp.where(finite, hi, 1e3) - inp.q])  # (2, n)
        sign = jnp.array([1.0, -1.0], inp.q.dtype)[:, None]
        xd = sign * inp.qd
        m, fe, h, h2, dpsi, psi = _distance_terms(p, x, xd)
        m, fe, h2 = m * finite, fe * finite, h2 * finite
        diag = jnp.sum(m, 0)
        return Contribution(
            jnp.diag(diag),
            jnp.sum(sign * m * h2, 0),
            jnp.sum(sign * fe, 0),
            jnp.sum(sign * dpsi * finite, 0),
            jnp.zeros((inp.q.shape[0],) * 2, inp.q.dtype),
            jnp.sum(h * finite),
            jnp.sum(psi * finite),
        )

    return Term(name, init, apply)
