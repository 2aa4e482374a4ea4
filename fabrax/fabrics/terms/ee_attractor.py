"""End-effector pose attractor on three points of a frame (thesis §3.3.1)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from fabrax.fabrics import energies as E
from fabrax.fabrics.lagrangian import eom, hd2_geometry
from fabrax.fabrics.terms.base import Contribution, Term, TermInputs, _params
from fabrax.robot.robot import Robot


def ee_attractor(name: str = "ee_attractor", frame: str = "panda_hand", offsets=((0, 0, 0.1), (0.1, 0, 0.1), (0, 0.1, 0.1)), **overrides) -> Term:
    """End-effector pose attractor on three non-collinear points of `frame` (thesis §3.3.1).

    Per point: geometry xdd = -|xd|^2 dpsi_g/dx, energy 1/2 m(x)|xd|^2 with the
    tanh-shaped mass, forcing psi = k_force log cosh(alpha_force |x - x_d|). Targets are the
    same points on the goal pose (`target_pos`, `target_quat` wxyz). `point_weights`
    selects points: (1, 0, 0) attracts position only.
    """
    offsets = np.asarray(offsets, np.float32)
    defaults = dict(
        target_pos=np.zeros(3),
        target_quat=np.array([1.0, 0, 0, 0]),
        weight=1.0,
        point_weights=np.ones(len(offsets)),
        m_hi=2.0,
        m_lo=0.2,
        alpha_mass=10.0,
        k_geometry=5.0,
        alpha_geometry=10.0,
        k_force=10.0,
        alpha_force=10.0,
        b_goal=5.0,
        alpha_damping=10.0,
    )
    init = _params(defaults, overrides, name)

    def points(robot: Robot):
        i = robot.frame_index(frame)
        local = jnp.asarray(offsets) @ robot.frame_offset_r[i].T + robot.frame_offset_t[i]
        return f"{name}:{frame}", jnp.full((len(offsets),), robot.frame_parent[i]), local

    def apply(p, inp: TermInputs) -> Contribution:
        kin = inp.points
        target = jaxlie.SO3(p["target_quat"] / jnp.linalg.norm(p["target_quat"])).apply(jnp.asarray(offsets)) + p["target_pos"]
        x, xd, jac, jdqd = kin.x.T, kin.xd.T, kin.jac.transpose(2, 0, 1), kin.jdqd.T  # few points: (K, 3), (K, 3, n)
        r = x - target
        w = p["weight"] * p["point_weights"]
        energy = lambda r_, rd: E.attractor_energy(r_, rd, p["m_hi"], p["m_lo"], p["alpha_mass"])  # noqa: E731
        M, fe, H = jax.vmap(lambda r_, rd: eom(energy, r_, rd))(r, xd)
        h2 = jax.vmap(hd2_geometry(lambda r_: E.attractor_potential(r_, p["k_geometry"], p["alpha_geometry"])))(r, xd)
        psi, dpsi = jax.vmap(jax.value_and_grad(E.attractor_potential), in_axes=(0, None, None))(r, p["k_force"], p["alpha_force"])
        b = p["b_goal"] * (1.0 - jnp.tanh(p["alpha_damping"] * E.safe_norm(r)))  # (K,)
        # contractions as broadcasts and sums over the few (point, axis) rows: XLA fuses them, where
        # einsums became a small matrix product each
        mj = sum(M[:, :, c, None] * jac[:, None, c] for c in range(3))  # (K, 3, n): M J per point
        ma = sum(M[:, :, c] * jdqd[:, c, None] for c in range(3))  # (K, 3)
        rows = jac.reshape(-1, jac.shape[-1])  # (3K, n)

        def pull(v):  # J^T v over all points, v (K, 3)
            return jnp.sum(rows * v.reshape(-1, 1), axis=0)

        return Contribution(
            jnp.sum(rows[:, :, None] * mj.reshape(rows.shape)[:, None, :], axis=0),
            pull(w[:, None] * (sum(M[:, :, c] * h2[:, c, None] for c in range(3)) + ma)),
            pull(fe + ma),
            pull(w[:, None] * dpsi),
            jnp.sum((jnp.repeat(w * b, 3)[:, None] * rows)[:, :, None] * rows[:, None, :], axis=0),
            jnp.sum(H),
            jnp.sum(w * psi),
        )

    return Term(name, init, apply, points)
