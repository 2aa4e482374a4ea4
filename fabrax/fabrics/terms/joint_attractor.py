"""Joint-space attractor (thesis §3.3.2): postures, joint goals and GFCS's commands."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fabrax.fabrics import energies as E
from fabrax.fabrics.lagrangian import eom, hd2_geometry
from fabrax.fabrics.terms.base import Contribution, Term, TermInputs, _params
from fabrax.soa import matvec


def joint_attractor(name: str = "joint_attractor", n: int = 7, **overrides) -> Term:
    """Joint-space attractor (thesis §3.3.2): geometry qdd = -|qd|^2 dpsi_g/dq, energy m(q)/2 |qd|^2,
    forcing psi = k_force log cosh(alpha_force |q - q_d|) and extra damping near the target.

    The isotropic mass is `mass` at the target and `mass_far` far from it (the tanh profile of the
    end-effector attractor's energy, §3.3.1; default mass_far = mass, the thesis' constant m). A
    posture with mass_far > mass leads the arm's shape from afar and hands over near its target.
    `weight` (0 or 1) switches the attraction (geometry, forcing, damping) while the mass stays,
    so the fabric's metric keeps full rank. `target` is the goal or command q_d (GFCS) or a posture.
    """
    overrides.setdefault("mass_far", overrides.get("mass", 1.0))
    defaults = dict(
        target=np.zeros(n),
        weight=1.0,
        mass=1.0,
        mass_far=1.0,
        alpha_mass=1.0,
        k_geometry=2.0,
        alpha_geometry=5.0,
        k_force=10.0,
        alpha_force=5.0,
        b_goal=5.0,
        alpha_damping=5.0,
    )
    init = _params(defaults, overrides, name)

    def apply(p, inp: TermInputs) -> Contribution:
        r = inp.q - p["target"]
        energy = lambda r_, rd: E.attractor_energy(r_, rd, p["mass"], p["mass_far"], p["alpha_mass"])  # noqa: E731
        M, fe, H = eom(energy, r, inp.qd)
        h2 = hd2_geometry(lambda r_: E.attractor_potential(r_, p["k_geometry"], p["alpha_geometry"]))(r, inp.qd)
        psi, dpsi = jax.value_and_grad(E.attractor_potential)(r, p["k_force"], p["alpha_force"])
        b = p["b_goal"] * (1.0 - jnp.tanh(p["alpha_damping"] * E.safe_norm(r)))
        w = p["weight"]
        return Contribution(M, w * matvec(M, h2), fe, w * dpsi, w * b * jnp.eye(r.shape[0], dtype=r.dtype), H, w * psi)

    return Term(name, init, apply)
