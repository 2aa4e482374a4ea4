"""Damping and speed control (thesis eq. 2.60's B)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fabrax.fabrics.terms.base import Contribution, Term, TermInputs, _params


def damping(name: str = "damping", **overrides) -> Term:
    """Damping B qd with speed control: B = (b + k_drag |qd|^2) I plus a brake on every joint above eta of its velocity limit.

    The quadratic drag bounds the cruise speed (terminal speed ~ (force / k_drag)^(1/3))
    without slowing the final approach, where the attractors' own near-goal
    damping settles the arm; a large constant b would make convergence crawl
    along directions the task barely moves.
    """
    defaults = dict(b=0.5, k_drag=4.0, k_speed=20.0, eta=0.8, sharpness=20.0)
    init = _params(defaults, overrides, name)

    def apply(p, inp: TermInputs) -> Contribution:
        ratio = jnp.abs(inp.qd) / inp.robot.velocity
        brake = p["k_speed"] * jax.nn.softplus(p["sharpness"] * (ratio - p["eta"])) / p["sharpness"]
        c = Contribution.zeros(inp.q.shape[0], inp.q.dtype)
        return c.replace(damping=jnp.diag(p["b"] + p["k_drag"] * jnp.sum(inp.qd * inp.qd) + brake))

    return Term(name, init, apply)
