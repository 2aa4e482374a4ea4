"""`Fabric`: a robot plus a tuple of terms, evaluated in one pass (thesis eqs. 2.54-2.60, 3.1-3.3).

    M_e qdd + f_h + alpha M_e qd = -dpsi/dq - B qd

with M_e = sum J^T M_i J, f_h = sum J^T M_i (h2_i + Jdot qd) the combined
geometry, alpha from energizing it with the summed pulled-back energies (eq.
2.26), forcing potentials and damping on the right. Parameters are a dict
{term name: params}; pass them (and the scene) as arrays so that goals,
gains and obstacles batch under `jax.vmap`.

Energization. "conservative" is eq. 2.26 exactly: the unforced fabric keeps
H_e constant, so energy that a barrier takes out of one direction is given
back along the whole velocity, also along the directions that approach other
obstacles (a joint braking hard at its limit, alpha -> -1e3, drove the arm
into a box at full acceleration). "dissipative" (the default) uses
max(alpha, 0): the energizing correction only ever removes energy, so the
unforced fabric's H_e never increases. max(alpha, 0) is HD1 in qd like alpha
itself, so the system stays HD2 and keeps the geometry's paths at any speed.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from fabrax.fabrics.spec import Spec, energize_alpha, solve
from fabrax.fabrics.terms import Contribution, Term, TermInputs
from fabrax.robot.kinematics import point_kinematics
from fabrax.robot.robot import Robot
from fabrax.scene import Scene
from fabrax.soa import matvec, written

Params = dict[str, Any]
FORCING_KEYS = ("k_force", "b", "b_goal", "k_speed", "k_drag")  # parameters that inject or drain energy
ENERGIZATIONS = ("dissipative", "conservative")
SMALL_SET = 16  # point sets up to this size get their Jacobians written apart (`Fabric.evaluate`)


@struct.dataclass
class FabricEval:
    spec: Spec  # the forced, damped fabric (M_e, f): qdd = -M_e^-1 f
    metric: jax.Array  # M_e, the energy metric
    alpha: jax.Array  # energization coefficient
    energy: jax.Array  # H_e, conserved when unforced and undamped
    potential: jax.Array  # sum of forcing potentials
    terms: Contribution  # summed raw contributions


@dataclasses.dataclass(frozen=True, eq=False)
class Fabric:
    """A geometric fabric for one robot. Hashable by identity, so it can be a static jit argument."""

    robot: Robot
    terms: tuple[Term, ...]
    energization: str = "dissipative"  # or "conservative" (see the module docstring)

    def __post_init__(self):
        names = [t.name for t in self.terms]
        if len(set(names)) != len(names):
            raise ValueError(f"fabric term names must be unique, got {names}")
        if self.energization not in ENERGIZATIONS:
            raise ValueError(f"fabric energization must be one of {ENERGIZATIONS}, got '{self.energization}'")

    def init(self) -> Params:
        """Default parameters of every term."""
        return {t.name: t.init() for t in self.terms}

    def term(self, name: str) -> Term:
        for t in self.terms:
            if t.name == name:
                return t
        raise ValueError(f"fabric has no term '{name}' (terms: {', '.join(t.name for t in self.terms)})")

    def _point_sets(self):
        """Unique task-point sets requested by the terms, concatenated for one kinematics pass."""
        sets: dict[str, tuple] = {}
        for t in self.terms:
            if t.points is not None:
                key, frame, local = t.points(self.robot)
                sets.setdefault(key, (frame, local))
        return sets

    def evaluate(self, params: Params, scene: Scene, q: jax.Array, qd: jax.Array) -> FabricEval:
        sets = self._point_sets()
        kin = {}
        if sets:
            frame = jnp.concatenate([f for f, _ in sets.values()])
            local = jnp.concatenate([loc for _, loc in sets.values()]).astype(q.dtype)
            with jax.named_scope("kinematics"):  # scopes name the kernels in profiles
                allk = point_kinematics(self.robot, q, qd, frame, local)
            start = 0
            for key, (f, _) in sets.items():
                sl = slice(start, start + f.shape[0])
                # each set's share written once: sliced views were fused into every consumer, which
                # recomputed the points' kinematics there with strided reads (e.g. the end-effector's
                # 3 points in the energization's fusion). The Jacobians of a large set (the spheres)
                # stay a view: written, they went through a library fusion that cost more than it
                # saved (experiments/ab_fabric_step.py compares such variants).
                jac = allk.jac[..., sl]
                kin[key] = allk._replace(
                    x=written(allk.x[:, sl]),
                    jac=written(jac) if f.shape[0] <= SMALL_SET else jac,
                    xd=written(allk.xd[:, sl]),
                    jdqd=written(allk.jdqd[:, sl]),
                )
                start += f.shape[0]
        total = Contribution.zeros(q.shape[0], q.dtype)
        for t in self.terms:
            pts = kin[t.points(self.robot)[0]] if t.points is not None else None
            with jax.named_scope(t.name):
                total = total + t.apply(params[t.name], TermInputs(q, qd, pts, scene, self.robot))
        alpha = energize_alpha(total.M, total.f_geom, total.f_energy, qd)
        if self.energization == "dissipative":
            alpha = jnp.maximum(alpha, 0.0)
        f = total.f_geom + alpha * matvec(total.M, qd) + total.f_force + matvec(total.damping, qd)
        return FabricEval(Spec(total.M, f), total.M, alpha, total.energy, total.potential, total)

    def accel(self, params: Params, scene: Scene, q: jax.Array, qd: jax.Array) -> jax.Array:
        """Unconstrained fabric acceleration qdd = -M_e^-1 f."""
        return solve(self.evaluate(params, scene, q, qd).spec)


def unforced(params: Params, fabric: Fabric) -> Params:
    """The same parameters with every forcing potential and damping switched off (for checks of the geometry)."""
    out = {}
    for t in fabric.terms:
        p = dict(params[t.name])
        for key in FORCING_KEYS:
            if key in p:
                p[key] = jnp.zeros_like(p[key])
        out[t.name] = p
    return out
