"""Potentials psi(x) and Finsler energies L_e(x, xd) of the arm term library (thesis §3.3).

Potentials are functions of a displacement or a distance; energies are
Lagrangians whose metric and force come from `lagrangian.eom`. Gates are
smooth (tanh, C1 ramps) so autodiff stays well defined everywhere. Distance
terms use rational functions only: they run for every (sphere, obstacle) and
sphere pair at every step, where a transcendental costs ~30 multiplies.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

_EPS2 = 1e-12


def safe_norm(v: jax.Array) -> jax.Array:
    """|v| that is differentiable at v = 0 (gradient 0 there)."""
    return jnp.sqrt(jnp.sum(v * v, -1) + _EPS2)


def log_cosh(z: jax.Array) -> jax.Array:
    """log cosh z without overflow."""
    a = jnp.abs(z)
    return a + jnp.log1p(jnp.exp(-2.0 * a)) - jnp.log(2.0)


def attractor_potential(r: jax.Array, k: float, alpha: float) -> jax.Array:
    """psi = k log cosh(alpha |r|) for the displacement r = x - x_d (thesis §3.3.1-3.3.2).

    Quadratic near the goal, linear (force magnitude k alpha) far from it.
    """
    return k * log_cosh(alpha * safe_norm(r))


def attractor_mass(r: jax.Array, m_hi: float, m_lo: float, alpha: float) -> jax.Array:
    """Isotropic mass m_lo + (m_hi - m_lo)(1 + tanh(-alpha |r|)): m_hi at the goal, m_lo far away (§3.3.1)."""
    return m_lo + (m_hi - m_lo) * (1.0 - jnp.tanh(alpha * safe_norm(r)))


def attractor_energy(r: jax.Array, rd: jax.Array, m_hi: float, m_lo: float, alpha: float) -> jax.Array:
    """L_e = 1/2 m(r) |rd|^2, the attractor's Finsler energy (priority grows near the goal)."""
    return 0.5 * attractor_mass(r, m_hi, m_lo, alpha) * jnp.sum(rd * rd)


def smooth_relu(u: jax.Array, width: float) -> jax.Array:
    """C1 ramp: 0 below -width, u above +width, (u + width)^2 / (4 width) between. Convex; no transcendentals."""
    mid = jnp.square(u + width) / (4.0 * width)
    return jnp.where(u >= width, u, jnp.where(u <= -width, 0.0, mid))


def clamp_floor(x: jax.Array, floor: float) -> jax.Array:
    """Smooth max(x, floor): x above 2 floor, floor below 0, increasing in between."""
    return floor + smooth_relu(x - floor, floor)


def reach_window(x: jax.Array, reach: float) -> jax.Array:
    """(1 - x/reach)^2 below `reach`, 0 beyond: a C1 activation window."""
    c = jnp.maximum(1.0 - x / reach, 0.0)
    return c * c


def barrier_potential(x: jax.Array, k_barrier: float, k_soft: float, soft_width: float, x0: float, reach: float, floor: float) -> jax.Array:
    """Distance-space barrier of thesis §3.3.3, psi = kb/x + kr/alpha log(1 + e^{-alpha (x - x0)}), made local and cheap:

    kb (reach - x)^2 / (x reach^2) is the C1 cut-off of kb/x (= kb/x - 2 kb/reach +
    kb x/reach^2, vanishing with its slope at `reach`), and the softplus push below
    x0 becomes the C1 ramp k_soft smooth_relu(x0 - x, soft_width) (width 1/alpha).
    Rational arithmetic only: distance terms are evaluated for every
    (sphere, obstacle) pair at every step.
    """
    xc = clamp_floor(x, floor)
    cut = jnp.maximum(reach - x, 0.0)
    return k_barrier * cut * cut / (xc * reach * reach) + k_soft * smooth_relu(x0 - x, soft_width)


def gated_barrier_energy(x: jax.Array, xd: jax.Array, k: float, sigma: float, reach: float, floor: float) -> jax.Array:
    """L_e = k/(2x) s(xd) xd^2 with a smooth velocity gate (thesis §3.3.3).

    The switch s(xd) = [xd < 0] becomes smooth_relu(-xd, sigma)^2, equal to xd^2
    when approaching faster than sigma and 0 when receding faster than sigma;
    it is convex in xd, so the metric stays positive semidefinite, and HD2 in
    xd outside |xd| < sigma. The reach window turns the term off far away.
    """
    gate = jnp.square(smooth_relu(-xd, sigma))
    return 0.5 * k * reach_window(x, reach) / clamp_floor(x, floor) * gate
