"""Checks of array arguments at the public boundary: shapes always (they are static under `jit`),
values when the array is concrete (a traced value cannot be inspected without a host round trip)."""

import jax
import numpy as np


def vector(name: str, x, n: int):
    """`x` as given, after checking that it holds `n` numbers and, when concrete, that all are finite.

    Raises a one-line ValueError naming `name`.
    """
    shape = np.shape(x)
    if shape != (n,):
        raise ValueError(f"{name}: expected {n} values, got shape {shape}")
    if not isinstance(x, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(x))):
        raise ValueError(f"{name}: NaN or infinite value {np.asarray(x).tolist()}")
    return x
