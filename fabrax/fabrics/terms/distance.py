"""Distance-space specs (thesis §3.3.3): the gated barrier energy, barrier geometry and forcing
of 1-D distances, elementwise, and their pullback through one row per distance; shared by the
obstacle, self-collision and joint-limit terms.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fabrax.fabrics import energies as E
from fabrax.fabrics.lagrangian import eom_elementwise
from fabrax.fabrics.terms.base import Contribution
from fabrax.fabrics.terms.kernels import _metric_products, _reduce, _unpack_metric


def _distance_terms(p, x, xd, vt2=None):
    """Elementwise over distances x with rates xd and squared tangential speeds vt2: metric m, energy
    force f_e, energy H, geometry h2, forcing dpsi_f/dx and psi_f (thesis §3.3.3).

    The geometry is xdd = -(xd^2 + k_slide vt2) dpsi/dx: the thesis' xd^2 dpsi/dx plus a push
    by the speed along the surface, so that a body point sliding past an obstacle is pushed
    off it too (vt2 = |v|^2 - xd^2 of the body point, HD2 in qd like xd^2; None for 1-D distances)."""
    energy = lambda x_, xd_: E.gated_barrier_energy(x_, xd_, p["k_metric"], p["sigma"], p["reach"], p["floor"])  # noqa: E731
    m, fe, h = eom_elementwise(energy, x, xd)
    geometry = lambda x_: E.barrier_potential(x_, p["k_barrier"], p["k_soft"], p["soft_width"], p["x0"], p["reach"], p["floor"])  # noqa: E731
    dpsi_g = jax.grad(lambda x_: jnp.sum(geometry(x_)))(x)
    # the forcing copy of the barrier (thesis: "weighted significantly less") is also shorter-ranged,
    # so that it only acts where the geometry alone would let the arm touch
    forcing = lambda x_: p["k_force"] * E.barrier_potential(x_, p["k_barrier"], 0.0, p["soft_width"], p["x0"], p["force_reach"], p["floor"])  # noqa: E731
    psi, dpsi = forcing(x), jax.grad(lambda x_: jnp.sum(forcing(x_)))(x)
    speed2 = xd * xd if vt2 is None else xd * xd + p["k_slide"] * vt2
    return m, fe, h, speed2 * dpsi_g, dpsi, psi


def _distance_defaults():
    return dict(
        margin=0.0,
        k_metric=0.5,
        sigma=0.02,
        reach=0.25,
        k_barrier=0.2,
        k_soft=0.5,
        soft_width=0.025,
        x0=0.03,
        floor=2e-3,
        k_force=0.1,
        force_reach=0.05,
        k_slide=0.0,
    )


def _pulled_pairs(p, x, rate, curv, u: list[jax.Array], vt2: jax.Array) -> Contribution:
    """1-D distance specs x with rate, curvature term and squared tangential speed, pulled back through
    u_k = J_x^T (one vector per distance, as rows u[a] over the pairs): M = sum m u u^T,
    f = sum u (m (h2 + curv)), ...  (eqs. 2.55, 2.60)."""
    m, fe, h, h2, dpsi, psi = _distance_terms(p, x, rate, vt2)
    vectors = [m * (h2 + curv), fe + m * curv, dpsi]
    sums, (clear,) = _reduce(_metric_products(u, m) + [ua * v for v in vectors for ua in u] + [h, psi], [x + p["margin"]])
    d = len(u)
    nm = d * (d + 1) // 2
    M = _unpack_metric(d, sums[:nm])
    fg, fen, ff = (jnp.stack(sums[nm + k * d : nm + (k + 1) * d]) for k in range(3))
    return Contribution(M, fg, fen, ff, jnp.zeros_like(M), sums[-2], sums[-1], clear)


RESOLUTIONS = ("link", "sphere")


def _check_resolution(resolution: str, name: str) -> None:
    if resolution not in RESOLUTIONS:
        raise ValueError(f"fabric term '{name}': resolution must be one of {RESOLUTIONS}, got '{resolution}'")
