"""Small symmetric positive definite solves, unrolled for SIMD across batches.

A 7x7 Cholesky through LAPACK pays a call per matrix; unrolled at trace time
into elementwise arithmetic it costs ~150 flops and vectorises across arms,
candidates and time. Used for every fabric solve.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

UNROLL_MAX = 16  # larger systems go to LAPACK


def cholesky_solve(M: jax.Array, b: jax.Array) -> jax.Array:
    """x with M x = b for symmetric positive definite M (..., n, n), b (..., n)."""
    n = M.shape[-1]
    if n > UNROLL_MAX:
        chol = jax.scipy.linalg.cho_factor(M, lower=True)
        return jax.scipy.linalg.cho_solve(chol, b)
    L = [[None] * n for _ in range(n)]
    inv_diag = [None] * n
    for j in range(n):
        s = M[..., j, j]
        for k in range(j):
            s = s - L[j][k] * L[j][k]
        d = jnp.sqrt(jnp.maximum(s, 1e-12))
        inv_diag[j] = 1.0 / d
        L[j][j] = d
        for i in range(j + 1, n):
            t = M[..., i, j]
            for k in range(j):
                t = t - L[i][k] * L[j][k]
            L[i][j] = t * inv_diag[j]
    y = [None] * n
    for i in range(n):  # L y = b
        t = b[..., i]
        for k in range(i):
            t = t - L[i][k] * y[k]
        y[i] = t * inv_diag[i]
    x = [None] * n
    for i in reversed(range(n)):  # L^T x = y
        t = y[i]
        for k in range(i + 1, n):
            t = t - L[k][i] * x[k]
        x[i] = t * inv_diag[i]
    return jnp.stack(x, -1)
