"""The term interface (thesis §3.3; gfcs_paper §III), in the spirit of an optax transform.

A `Term` is a pair of pure functions: `init()` gives its default parameters (a pytree of arrays)
and `apply(params, inputs)` its `Contribution` in configuration space. A term may ask for task
points (collision spheres, end-effector keypoints); the fabric computes the kinematics of all
requested points in one pass (the transform tree, eqs. 2.55-2.59).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fabrax.gains import check_value
from fabrax.robot.kinematics import PointKinematics
from fabrax.robot.robot import Robot
from fabrax.scene import FAR, Scene
from fabrax.settings import check_keys


@struct.dataclass
class Contribution:
    """A term's share of the configuration-space fabric."""

    M: jax.Array  # (n, n) pulled-back metric of the term's Finsler energy
    f_geom: jax.Array  # (n,) J^T M_e (h2 + Jdot qd)           eq. 2.55
    f_energy: jax.Array  # (n,) J^T (f_e + M_e Jdot qd)        eq. 2.51
    f_force: jax.Array  # (n,) J^T dpsi/dx of forcing potentials  eq. 2.60
    damping: jax.Array  # (n, n) B
    energy: jax.Array  # () Hamiltonian of L_e (eq. 2.11)
    potential: jax.Array  # () forcing potential psi
    clearance: jax.Array = FAR  # () smallest distance a repulsion term saw (m)

    @staticmethod
    def zeros(n: int, dtype=jnp.float32) -> "Contribution":
        z = jnp.zeros((), dtype)
        return Contribution(
            jnp.zeros((n, n), dtype), jnp.zeros(n, dtype), jnp.zeros(n, dtype), jnp.zeros(n, dtype), jnp.zeros((n, n), dtype), z, z, z + FAR
        )

    def __add__(self, other: "Contribution") -> "Contribution":
        total = jax.tree.map(jnp.add, self, other)
        return total.replace(clearance=jnp.minimum(self.clearance, other.clearance))


class TermInputs(NamedTuple):
    q: jax.Array
    qd: jax.Array
    points: PointKinematics | None  # kinematics of the points the term asked for
    scene: Scene
    robot: Robot


class Term(NamedTuple):
    name: str
    init: Callable[[], dict[str, Any]]
    apply: Callable[[dict[str, Any], TermInputs], Contribution]
    points: Callable[[Robot], tuple[str, jax.Array, jax.Array]] | None = None  # (key, frame (N,), local (N, 3))


def _params(defaults: dict[str, Any], overrides: dict[str, Any], name: str) -> Callable[[], dict[str, Any]]:
    check_keys(overrides, defaults, f"fabric term '{name}' parameter")
    for key, value in overrides.items():
        check_value(name, key, value, scalar=np.ndim(defaults[key]) == 0)
    merged = {**defaults, **overrides}
    return lambda: {k: jnp.asarray(v, jnp.float32) for k, v in merged.items()}


SPHERE_LANES = 16  # the spheres' point set is padded to a multiple of this many points (`_spheres`)


def _spheres(robot: Robot):
    """The collision spheres as a point set, padded to a multiple of SPHERE_LANES with copies of
    sphere 0 that the obstacle term masks (`_sphere_gaps`). XLA on CPU vectorises the per-sphere
    arithmetic (the scene search, the pullbacks) along the spheres, 16 float32 lanes at a time, and
    runs a remainder as scalar code, which the padding avoids."""
    extra = -robot.n_spheres % SPHERE_LANES if robot.n_spheres else 0
    pad = lambda a: jnp.concatenate([a, jnp.broadcast_to(a[:1], (extra,) + a.shape[1:])])  # noqa: E731
    return "spheres", pad(robot.collision.frame), pad(robot.collision.local)


def _sphere_gaps(robot: Robot, d: jax.Array, margin: jax.Array) -> jax.Array:
    """d - r - margin for distances d (..., N) of the padded sphere set (`_spheres`); FAR for the
    padding, beyond every term's reach, so that its metric, forces and energies are exactly 0."""
    n = robot.n_spheres
    radius = jnp.concatenate([robot.collision.radius, jnp.zeros(d.shape[-1] - n, d.dtype)])
    return jnp.where(jnp.arange(d.shape[-1]) < n, d - radius - margin, FAR)
