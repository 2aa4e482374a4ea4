"""Repulsion of the collision spheres from the scene (thesis §3.3.3)."""

from __future__ import annotations

import jax.numpy as jnp

from fabrax.fabrics.terms.base import Contribution, Term, TermInputs, _params, _sphere_gaps, _spheres
from fabrax.fabrics.terms.distance import _distance_defaults, _distance_terms, _pulled_pairs
from fabrax.fabrics.terms.kernels import _metric_products, _pull_spheres, _reduce, _unpack_metric
from fabrax.scene import distance_kinematics
from fabrax.scene.sdf import nearest_distance
from fabrax.soa import dot0


def obstacle_repulsion(name: str = "obstacles", resolution: str = "scene", **overrides) -> Term:
    """Repulsion of every collision sphere from the scene (thesis §3.3.3).

    resolution="scene": one distance per sphere, to the scene as a whole (the
    signed distance of the union of primitives = the min over them); every
    (sphere, primitive) distance is evaluated, the energy and one pullback run
    per sphere through its Jacobian from the one kinematics pass.
    resolution="primitive": one distance per (sphere, primitive); the 1-D specs
    are reduced per sphere to a 3x3 metric and 3-vectors (sum n m n^T,
    sum n m (h2 + pd^T H pd), ...), then pulled back once per sphere. Several
    obstacles near one sphere all push, and nothing switches where two are
    equidistant, at several times the cost.
    """
    if resolution not in ("scene", "primitive"):
        raise ValueError(f"fabric term '{name}': resolution must be 'scene' or 'primitive', got '{resolution}'")
    init = _params(_distance_defaults(), overrides, name)

    def apply_sphere(p, inp: TermInputs) -> Contribution:
        kin = inp.points
        pd = distance_kinematics(inp.scene, kin.x, kin.xd)
        x = _sphere_gaps(inp.robot, pd.d, p["margin"])  # (K, N)
        m, fe, h, h2, dpsi, psi = _distance_terms(p, x, pd.rate, jnp.maximum(dot0(kin.xd, kin.xd)[None] - pd.rate * pd.rate, 0.0))
        n = pd.n
        wg, we = m * (h2 + pd.curv), fe + m * pd.curv
        per_pair = _metric_products([n[0], n[1], n[2]], m) + [n[c] * w for w in (wg, we, dpsi) for c in range(3)]
        sums, (clear,) = _reduce(per_pair + [h, psi], [x + p["margin"]])
        m3 = _unpack_metric(3, sums[:6])  # (3, 3, N)
        g3, e3, f3 = jnp.stack(sums[6:9]), jnp.stack(sums[9:12]), jnp.stack(sums[12:15])
        M, fg, fen, ff = _pull_spheres(kin, m3, g3, e3, f3)
        return Contribution(M, fg, fen, ff, jnp.zeros_like(M), jnp.sum(sums[15]), jnp.sum(sums[16]), jnp.min(clear))

    def apply_scene(p, inp: TermInputs) -> Contribution:
        kin, robot = inp.points, inp.robot
        near = nearest_distance(inp.scene, kin.x, kin.xd)
        x = _sphere_gaps(robot, near.d, p["margin"])
        curv = near.curv + dot0(near.n, kin.jdqd)  # Jdot qd of x: pd^T H pd + n . (Jdot qd)_sphere
        u = [dot0(kin.jac[:, a], near.n) for a in range(kin.jac.shape[1])]
        return _pulled_pairs(p, x, near.rate, curv, u, jnp.maximum(dot0(kin.xd, kin.xd) - near.rate * near.rate, 0.0))

    return Term(name, init, apply_scene if resolution == "scene" else apply_sphere, _spheres)
