"""Exact signed distances from points to scene primitives, with derivatives.

Distances are positive outside, negative inside (point clouds are unsigned).
Everything is vectorised over points (N) and primitive slots (K, in the order
cuboids, cylinders, spheres, cloud points); masked slots read as `FAR`.
`distance_kinematics` also returns the gradient n = dd/dp, the rate n.pd and
the curvature term pd^T (d^2 d/dp^2) pd that a distance task map needs for
its Jdot qd, all in closed form: the fabric evaluates them for every
(sphere, primitive) pair at every step. Arrays are component-first
((3, K, N) for vectors) so that the work vectorises over points.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie

from fabrax.scene.primitives import Scene
from fabrax.soa import dot0, sum0, written

FAR = 1e3  # distance reported for masked (empty) slots
UNROLL_MAX = 32  # longest axis `min_packed` unrolls (each entry is an op in the program)
LANES = 8  # float32 lanes of a 256-bit vector register (see `nearest_distance`)
_EPS2 = 1e-18  # keeps norms differentiable at zero


class PairDistances(NamedTuple):
    d: jax.Array  # (K, N) signed distance
    n: jax.Array  # (3, K, N) gradient (unit outward normal)
    rate: jax.Array  # (K, N) n . pd
    curv: jax.Array  # (K, N) pd^T H pd
    mask: jax.Array  # (K,) slot in use


def _local(center, rot, x, xd):
    """Point positions and velocities in each primitive's frame: (3, K, N) each; x, xd are (3, K or 1, N)."""
    dp = x - center.T[:, :, None]
    rt = jnp.moveaxis(rot, 0, -1)  # (3, 3, K): rt[c, i, k] = R_k[c, i]
    pl = jnp.stack([sum(rt[c, i][:, None] * dp[c] for c in range(3)) for i in range(3)])
    vl = jnp.stack([sum(rt[c, i][:, None] * xd[c] for c in range(3)) for i in range(3)])
    return pl, vl, rt


def _world(rt, gl):
    return jnp.stack([sum(rt[c, i][:, None] * gl[i] for i in range(3)) for c in range(3)])


def _boxes(center, rot, half, x, xd):
    """Box |p_l| - h: outside d = |max(q, 0)|, inside d = max_i q_i."""
    pl, vl, rt = _local(center, rot, x, xd)
    q = jnp.abs(pl) - half.T[:, :, None]
    m = jnp.maximum(q, 0.0)
    dout = jnp.sqrt(dot0(m, m) + _EPS2)
    qmax = jnp.maximum(jnp.maximum(q[0], q[1]), q[2])
    outside = qmax > 0.0
    sign = jnp.where(pl >= 0.0, 1.0, -1.0)
    top = q >= qmax[None]
    first = jnp.stack([top[0], top[1] & ~top[0], ~top[0] & ~top[1]])  # the face of the largest q_i (ties: the first)
    gl = jnp.where(outside[None], sign * m / dout[None], jnp.where(first, sign, 0.0))
    rate = dot0(gl, vl)
    active = sum0(jnp.where(q > 0.0, vl * vl, 0.0))
    curv = jnp.where(outside, (active - rate * rate) / dout, 0.0)  # (diag(active) - g g^T)/|m| on the outside
    return dout + jnp.minimum(qmax, 0.0), _world(rt, gl), rate, curv


def _cylinders(center, rot, radius, half_length, x, xd):
    """Solid cylinder along local z: d from (rho - r, |z| - h) like a 2-D box."""
    pl, vl, rt = _local(center, rot, x, xd)
    rho = jnp.sqrt(pl[0] ** 2 + pl[1] ** 2 + _EPS2)
    a = rho - radius[:, None]
    b = jnp.abs(pl[2]) - half_length[:, None]
    ma, mb = jnp.maximum(a, 0.0), jnp.maximum(b, 0.0)
    dout = jnp.sqrt(ma * ma + mb * mb + _EPS2)
    outside = jnp.maximum(a, b) > 0.0
    ga = jnp.stack([pl[0] / rho, pl[1] / rho, jnp.zeros_like(rho)])  # d rho / d p_l
    gb = jnp.stack([jnp.zeros_like(rho), jnp.zeros_like(rho), jnp.where(pl[2] >= 0.0, 1.0, -1.0)])
    gl = jnp.where(outside[None], (ma * ga + mb * gb) / dout[None], jnp.where((a >= b)[None], ga, gb))
    rate = dot0(gl, vl)
    ra, rb = dot0(ga, vl), dot0(gb, vl)
    radial = (vl[0] ** 2 + vl[1] ** 2 - ra * ra) / rho  # v^T (d^2 rho) v
    out_curv = (ma * radial + jnp.where(a > 0.0, ra * ra, 0.0) + jnp.where(b > 0.0, rb * rb, 0.0) - rate * rate) / dout
    curv = jnp.where(outside, out_curv, jnp.where(a >= b, radial, 0.0))
    return dout + jnp.minimum(jnp.maximum(a, b), 0.0), _world(rt, gl), rate, curv


def _balls(center, radius, x, xd):
    """Spheres (and cloud points, radius 0): |p - c| - r."""
    dp = x - center.T[:, :, None]
    dist = jnp.sqrt(dot0(dp, dp) + _EPS2)
    n = dp / dist[None]
    rate = dot0(n, xd)
    curv = (dot0(xd, xd) - rate * rate) / dist
    return dist - radius[:, None], n, rate, curv


def _rot(quat):
    return jaxlie.SO3(quat).as_matrix()


def distance_kinematics(scene: Scene, x: jax.Array, xd: jax.Array) -> PairDistances:
    """Distance task maps x = sd(p) of (primitive slot, point) pairs.

    x, xd are (3, N): every point against every slot; or (3, K, M): slot k
    against its own M points (e.g. the closest sphere of each link).
    """
    if x.ndim == 2:
        x, xd = x[:, None, :], xd[:, None, :]
    c, y, s, pc = scene.cuboids, scene.cylinders, scene.spheres, scene.cloud
    sizes = [c.mask.shape[0], y.mask.shape[0], s.mask.shape[0], pc.mask.shape[0]]
    starts = [sum(sizes[:i]) for i in range(4)]

    def pts(i):  # the points that kind i is measured against
        if x.shape[1] == 1:
            return x, xd
        return x[:, starts[i] : starts[i] + sizes[i]], xd[:, starts[i] : starts[i] + sizes[i]]

    parts = []
    if sizes[0]:
        parts.append((_boxes(c.center, _rot(c.quat), c.half_extents, *pts(0)), c.mask))
    if sizes[1]:
        parts.append((_cylinders(y.center, _rot(y.quat), y.radius, y.half_length, *pts(1)), y.mask))
    if sizes[2]:
        parts.append((_balls(s.center, s.radius, *pts(2)), s.mask))
    if sizes[3]:
        parts.append((_balls(pc.points, jnp.zeros(pc.mask.shape, x.dtype), *pts(3)), pc.mask))
    if not parts:
        n = x.shape[2]
        z = jnp.zeros((0, n), x.dtype)
        return PairDistances(z, jnp.zeros((3, 0, n), x.dtype), z, z, jnp.zeros((0,), bool))
    mask = jnp.concatenate([m for _, m in parts])
    d, n, rate, curv = (jnp.concatenate([p[i] for p, _ in parts], axis=1 if i == 1 else 0) for i in range(4))
    live = mask[:, None]
    return PairDistances(jnp.where(live, d, FAR), n * live[None], rate * live, curv * live, mask)


def argmin_packed(values: jax.Array, offset: float = 2.0, axis: int = -1) -> jax.Array:
    """Index of the smallest value along `axis`, for values > -offset (ties: the first).

    The bits of the positive floats `values + offset` order like integers; their
    lowest bits are replaced by the index and one integer min-reduction finds
    both (XLA vectorises a plain min but runs an argmin's (value, index)
    reduction as scalar code). Values closer than ~2^-(23 - index bits)
    relative are ties.
    """
    return min_packed(values, offset, axis)[0]


def min_packed(values: jax.Array, offset: float = 2.0, axis: int = -1, unroll: bool = False) -> tuple[jax.Array, jax.Array]:
    """`argmin_packed` and the smallest value itself, read back from the same packed key: exact up
    to the index bits it lost (within ~2^-(23 - index bits) relative of values + offset), without a
    gather of the values at the index (XLA fused such a gather with the arithmetic that made the
    values, and recomputed it per gathered entry).

    unroll: the minimum as a chain of elementwise minima of the slices along `axis`, written to
    memory once, for axes of at most UNROLL_MAX entries (longer ones, e.g. point clouds, reduce as
    usual). For a short axis that is not the minor one (the self-collision chunks with the arms
    minor) this is one loop vectorised over the other axes; a reduction there ran over the short
    axis innermost, and its consumers recomputed it. The keys are written before the chain: XLA
    fused the slots' distances and keys into it and ran that as scalar code."""
    axis = axis % values.ndim
    bits = _index_bits(values.shape[axis])
    key = _min_key(values, offset, axis, unroll, bits, 0)
    low = (1 << bits) - 1
    return key & low, jax.lax.bitcast_convert_type(key & ~low, jnp.float32).astype(values.dtype) - offset


def _index_bits(width: int) -> int:
    bits = max(1, int(width - 1).bit_length())
    if bits > 12:
        raise ValueError(f"too many entries ({width}) to pack an index into a float32 mantissa")
    return bits


def _min_key(values: jax.Array, offset: float, axis: int, unroll: bool, bits: int, start: int) -> jax.Array:
    """The smallest packed key along `axis`: the bits of values + offset with the lowest `bits`
    replaced by the entry's index plus `start` (see `min_packed`)."""
    width = values.shape[axis]
    raw = jax.lax.bitcast_convert_type(jnp.maximum(values + offset, 1e-30).astype(jnp.float32), jnp.int32)
    index = start + jnp.arange(width, dtype=jnp.int32).reshape((width,) + (1,) * (values.ndim - 1 - axis))
    keys = (raw & ~((1 << bits) - 1)) | index
    if unroll and width <= UNROLL_MAX:
        keys = written(keys)  # fused into the chain, the keys of 8 slots ran as scalar code
        return written(functools.reduce(jnp.minimum, [jax.lax.index_in_dim(keys, k, axis, keepdims=False) for k in range(width)]))
    return jnp.min(keys, axis=axis)


class NearestDistance(NamedTuple):
    d: jax.Array  # (N,) signed distance to the scene (the union of its primitives)
    n: jax.Array  # (3, N) gradient
    rate: jax.Array  # (N,)
    curv: jax.Array  # (N,)
    slot: jax.Array  # (N,) primitive slot that is nearest


def _lanes(params: tuple, mask: jax.Array) -> tuple[tuple, jax.Array]:
    """A kind's slots padded to a multiple of LANES with masked copies of its first slot."""
    extra = -mask.shape[0] % LANES
    if mask.shape[0] <= 1 or not extra:
        return params, mask
    pad = lambda a: jnp.concatenate([a, jnp.broadcast_to(a[:1], (extra,) + a.shape[1:])])  # noqa: E731
    return tuple(pad(a) for a in params), jnp.concatenate([mask, jnp.zeros(extra, bool)])


def nearest_distance(scene: Scene, x: jax.Array, xd: jax.Array, skip_empty: bool = False) -> NearestDistance:
    """Distance from each point (3, N) to the whole scene, min over primitives, with its derivatives.

    Every (point, slot) distance is computed (values only); the derivatives are
    then evaluated once per point, against its nearest slot of each kind. The
    nearest slot is a chain of elementwise minima over the slots' rows
    (`min_packed(unroll=True)`), vectorised along the points. A reduction over
    the slots vectorised only when the slot count was a multiple of the vector
    width (other counts ran as scalar code), so the
    slots are padded to a multiple of LANES here (masked); with the chain the
    padding measured neutral on a 20-cuboid scene and stays.

    skip_empty: each block of LANES slots, and each kind's derivative pass, runs under a
    `lax.cond` on whether it holds an obstacle, so a scene padded far past its obstacles (a
    benchmark's common capacity) costs what its obstacles cost. For many points against one
    scene (a basis point set); under `vmap` over scenes the conds become selects that run both
    branches, and for a few points their overhead outweighs the slots they skip.
    """
    c, y, s, pc = scene.cuboids, scene.cylinders, scene.spheres, scene.cloud
    kinds = [
        (_boxes, (c.center, _rot(c.quat), c.half_extents), c.mask),
        (_cylinders, (y.center, _rot(y.quat), y.radius, y.half_length), y.mask),
        (_balls, (s.center, s.radius), s.mask),
        (_balls, (pc.points, jnp.zeros(pc.mask.shape, x.dtype)), pc.mask),
    ]
    best, start = None, 0
    for fn, params, mask in kinds:
        k = mask.shape[0]
        if k:
            params, mask = _lanes(params, mask)
            idx = _nearest_slots(fn, params, mask, x, xd, skip_empty)

            def near(idx=idx, fn=fn, params=params, mask=mask, start=start):
                d, n, rate, curv = fn(*(a[idx] for a in params), x[:, :, None], xd[:, :, None])
                return NearestDistance(jnp.where(mask[idx], d[:, 0], FAR), n[:, :, 0], rate[:, 0], curv[:, 0], idx + start)

            if skip_empty:

                def far(idx=idx, start=start):
                    z = jnp.zeros(idx.shape, x.dtype)
                    return NearestDistance(z + FAR, jnp.zeros_like(x), z, z, idx + start)

                cand = jax.lax.cond(jnp.any(mask), near, far)
            else:
                cand = near()
            best = cand if best is None else jax.tree.map(lambda a, b: jnp.where(cand.d < best.d, a, b), cand, best)
        start += k
    if best is None:
        z = jnp.zeros(x.shape[1], x.dtype)
        return NearestDistance(z + FAR, jnp.zeros_like(x), z, z, jnp.zeros(x.shape[1], jnp.int32))
    return best


def _nearest_slots(fn, params: tuple, mask: jax.Array, x: jax.Array, xd: jax.Array, skip_empty: bool) -> jax.Array:
    """(N,) index of each point's nearest slot of one kind (values only; `nearest_distance`)."""
    k = mask.shape[0]
    if not skip_empty:
        d_all = jnp.where(mask[:, None], fn(*params, x[:, None, :], xd[:, None, :])[0], FAR)  # (K, N)
        return min_packed(d_all, axis=0, unroll=True)[0]  # minima of the slots' rows, along the points
    bits = _index_bits(k)
    none = jnp.full(x.shape[1:], jnp.iinfo(jnp.int32).max, jnp.int32)  # larger than any packed key

    def block(lo: int) -> jax.Array:
        hi = min(k, lo + LANES)
        sub, live = tuple(a[lo:hi] for a in params), mask[lo:hi]

        def keys():
            d = jnp.where(live[:, None], fn(*sub, x[:, None, :], xd[:, None, :])[0], FAR)
            return _min_key(d, 2.0, 0, True, bits, lo)

        return jax.lax.cond(jnp.any(live), keys, lambda: none)

    key = functools.reduce(jnp.minimum, [block(lo) for lo in range(0, k, LANES)])
    return jnp.minimum(key & ((1 << bits) - 1), k - 1)  # no block live: any slot, masked


def primitive_mask(scene: Scene) -> jax.Array:
    """(K,) which primitive slots are in use."""
    return jnp.concatenate([scene.cuboids.mask, scene.cylinders.mask, scene.spheres.mask, scene.cloud.mask])


def signed_distances(scene: Scene, points: jax.Array) -> jax.Array:
    """(N, K) signed distance from every point (N, 3) to every primitive slot."""
    return distance_kinematics(scene, points.T, jnp.zeros_like(points.T)).d.T


def distance(scene: Scene, points: jax.Array) -> jax.Array:
    """(N,) signed distance from every point (N, 3) to the nearest obstacle (FAR if none)."""
    return jnp.min(signed_distances(scene, points), axis=1, initial=FAR)
