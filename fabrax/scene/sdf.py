"""Exact signed distances from points to scene primitives, with derivatives.

Distances are positive outside, negative inside (point clouds are unsigned).
Everything is vectorised over points (N) and primitives (K, in the order
cuboids, cylinders, spheres, cloud points); masked slots read as `FAR`.
`distance_kinematics` also returns the gradient n = dd/dp and the curvature
term pd^T (d^2 d/dp^2) pd that a distance task map needs for its Jdot qd.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie

from fabrax.scene.primitives import Scene

FAR = 1e3  # distance reported for masked (empty) slots
_EPS2 = 1e-18  # keeps norms differentiable at zero


def _norm(v):
    return jnp.sqrt(jnp.sum(v * v, -1) + _EPS2)


def _rot(quat):
    return jaxlie.SO3(quat).as_matrix()


def sdf_cuboid(p, center, rot, half):
    """Signed distance from p (3,) to a box with half extents `half`."""
    q = jnp.abs(rot.T @ (p - center)) - half
    return _norm(jnp.maximum(q, 0.0)) + jnp.minimum(jnp.max(q), 0.0)


def sdf_cylinder(p, center, rot, radius, half_length):
    """Signed distance to a solid cylinder along its local z axis."""
    local = rot.T @ (p - center)
    q = jnp.stack([_norm(local[:2]) - radius, jnp.abs(local[2]) - half_length])
    return _norm(jnp.maximum(q, 0.0)) + jnp.minimum(jnp.max(q), 0.0)


def sdf_sphere(p, center, radius):
    return _norm(p - center) - radius


def _primitive_fns(scene: Scene):
    """Per-kind (fn(p, *params), params, mask) with rotations precomputed."""
    c, y, s, pc = scene.cuboids, scene.cylinders, scene.spheres, scene.cloud
    return (
        (sdf_cuboid, (c.center, _rot(c.quat), c.half_extents), c.mask),
        (sdf_cylinder, (y.center, _rot(y.quat), y.radius, y.half_length), y.mask),
        (sdf_sphere, (s.center, s.radius), s.mask),
        (lambda p, x: _norm(p - x), (pc.points,), pc.mask),
    )


def primitive_mask(scene: Scene) -> jax.Array:
    """(K,) which primitive slots are in use."""
    return jnp.concatenate([m for _, _, m in _primitive_fns(scene)])


def signed_distances(scene: Scene, points: jax.Array) -> jax.Array:
    """(N, K) signed distance from every point to every primitive slot."""
    cols = []
    for fn, params, mask in _primitive_fns(scene):
        if mask.shape[0] == 0:
            continue
        d = jax.vmap(lambda p: jax.vmap(lambda *a: fn(p, *a))(*params))(points)
        cols.append(jnp.where(mask, d, FAR))
    if not cols:
        return jnp.full((points.shape[0], 0), FAR, points.dtype)
    return jnp.concatenate(cols, 1)


def distance(scene: Scene, points: jax.Array) -> jax.Array:
    """(N,) signed distance from every point to the nearest obstacle (FAR if none)."""
    d = signed_distances(scene, points)
    return jnp.min(d, axis=1, initial=FAR)


def distance_kinematics(scene: Scene, points: jax.Array, velocities: jax.Array):
    """Distance task maps x = sd(p) for every (point, primitive) pair.

    Returns d (N, K), gradient n (N, K, 3), rate n.pd (N, K), curvature
    pd^T H pd (N, K) and the slot mask (K,). The curvature term is a jvp of
    the gradient along pd (forward over reverse), never finite differences.
    """
    outs = []
    for fn, params, mask in _primitive_fns(scene):
        if mask.shape[0] == 0:
            continue

        def pair(p, pd, *a, fn=fn):
            value_grad = lambda x: jax.value_and_grad(fn)(x, *a)  # noqa: E731
            (d, n), (dd, hpd) = jax.jvp(value_grad, (p,), (pd,))
            return d, n, dd, hpd @ pd

        d, n, dd, curv = jax.vmap(lambda p, pd: jax.vmap(lambda *a: pair(p, pd, *a))(*params))(points, velocities)
        outs.append((jnp.where(mask, d, FAR), n * mask[:, None], dd * mask, curv * mask, mask))
    if not outs:
        n = points.shape[0]
        z = jnp.zeros((n, 0), points.dtype)
        return z + FAR, jnp.zeros((n, 0, 3), points.dtype), z, z, jnp.zeros((0,), bool)
    return tuple(jnp.concatenate(x, 1 if i < 4 else 0) for i, x in enumerate(zip(*outs)))
