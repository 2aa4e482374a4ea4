"""Component-first (structure-of-arrays) vector arithmetic: vectors are arrays (3, ...).

Hot paths keep the small axis (xyz, joints) first and unroll it in Python, so
XLA sees only elementwise arithmetic over the large axes (points, pairs) and
fuses it into a few vectorised loops; a `sum` over a size-3 axis would be a
separate reduction kernel each time.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def sum0(a: jax.Array) -> jax.Array:
    """Sum over the leading (small) axis, unrolled."""
    out = a[0]
    for i in range(1, a.shape[0]):
        out = out + a[i]
    return out


def dot0(a: jax.Array, b: jax.Array) -> jax.Array:
    """Dot product over the leading axis."""
    return sum0(a * b)


def cross0(a: jax.Array, b: jax.Array) -> jax.Array:
    """Cross product over the leading axis of size 3."""
    return jnp.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def matvec(m: jax.Array, v: jax.Array) -> jax.Array:
    """m v for small matrices m (..., n, k) and v (..., k), axes last, as a multiply and a sum that
    XLA fuses with its neighbours (a `@` on a 7x7 or 3x3 is a matrix-product kernel call of its own)."""
    return jnp.sum(m * v[..., None, :], axis=-1)


def matvec0(m: jax.Array, v: jax.Array) -> jax.Array:
    """(m v)_i = sum_j m[i, j] v[j] for m (d, e, ...) and v (e, ...)."""
    return jnp.stack([dot0(m[i], v) for i in range(m.shape[0])])


def written(x: jax.Array) -> jax.Array:
    """x, computed once into memory rather than fused into (and recomputed, or read with strides, by)
    each consumer. XLA's CPU fusion does not fuse a reduction into the loops that consume it, so x
    goes through one: the sum of x and zeros over a leading axis of two (exact: x + 0 = x). A
    heuristic of XLA's, not a guarantee: a gather consumer took such a sum into its own fusion,
    and a large one ran as a separate library fusion that cost more than it saved. Measure
    (experiments/ab_fabric_step.py)."""
    x = jnp.asarray(x)
    return jnp.sum(jnp.stack([x, jnp.zeros_like(x)]), axis=0, dtype=x.dtype)  # dtype: ints stay int32 under x64


def batch_minor(x: jax.Array) -> jax.Array:
    """x (B, ...) as (..., B), `written`: the batch becomes the minor axis, along which XLA on CPU
    vectorises (e.g. gathers of whole rows of arms, minima across rows). A plain transpose is fused
    into its consumers, which then read every element with a stride."""
    return written(jnp.moveaxis(x, 0, -1))
