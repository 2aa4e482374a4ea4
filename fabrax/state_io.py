"""Flax NNX state as flat, string-keyed numpy dicts for msgpack files."""

from __future__ import annotations

import numpy as np
from flax import traverse_util


def to_flat(tree: dict) -> dict:
    """String keys for msgpack (nnx pure dicts index list layers by int)."""
    return {"/".join(map(str, k)): np.asarray(v) for k, v in traverse_util.flatten_dict(tree).items()}


def from_flat(flat: dict) -> dict:
    """The inverse of `to_flat`."""

    def ints(d):
        return {int(k) if k.isdigit() else k: ints(v) if isinstance(v, dict) else v for k, v in d.items()}

    return ints(traverse_util.unflatten_dict(flat, sep="/"))
