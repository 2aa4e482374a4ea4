"""Batch axes over all local devices with `jax.sharding`: one mesh, one axis name.

Every batched solver (arm rollouts, GFCS populations, geodesic batches, skill
execution) marks its batch axis inside its jitted function, with `constrain` or
with `batched` (which also pads the batch to a multiple of the device count);
GSPMD then splits the vmapped computation over the devices of `mesh()`, and
nothing else changes: each arm's maths is the one a single device runs. A multi-GPU node or a TPU
slice scales without code changes. On a CPU, XLA shows one device unless told
otherwise: set FABRAX_CPU_DEVICES=<cores> before importing fabrax (it becomes
`--xla_force_host_platform_device_count`) to run one shard per core. The RL guide's
env batch is split over the same local devices by brax's own `pmap`.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "batch"


@functools.cache
def _mesh(devices: tuple) -> Mesh:
    return Mesh(np.asarray(devices), (AXIS,))


def mesh(devices=None) -> Mesh:
    """A 1-D mesh named `AXIS` over `devices` (default: all local devices)."""
    return _mesh(tuple(jax.local_devices() if devices is None else devices))


def batch_sharding(m: Mesh | None = None) -> NamedSharding:
    """Leading axis split over the mesh, the rest replicated."""
    return NamedSharding(m or mesh(), PartitionSpec(AXIS))


def _shardable(x, n: int) -> bool:
    return hasattr(x, "shape") and len(x.shape) > 0 and x.shape[0] % n == 0


def constrain(tree, m: Mesh | None = None):
    """Inside `jit`: split the leading (batch) axis of every array leaf over the mesh.

    A no-op on one device; a leaf whose leading axis does not divide evenly stays
    replicated (`batched` pads the batch to use every device)."""
    m = m or mesh()
    n = m.devices.size
    if n == 1:
        return tree
    sharding = batch_sharding(m)
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, sharding) if _shardable(x, n) else x, tree)


def pad(tree, multiple: int | None = None):
    """(tree, n): the leading axis of every leaf padded to a multiple of `multiple` (default: the
    local device count) by repeating its last entry; n is the original size. Cut results back with
    `unpad(out, n)`."""
    multiple = multiple or jax.local_device_count()
    sizes = {x.shape[0] for x in jax.tree.leaves(tree)}
    if len(sizes) != 1:
        raise ValueError(f"pad: every leaf needs the same leading (batch) size, got {sorted(sizes)}")
    (n,) = sizes
    extra = -n % multiple
    if extra == 0:
        return tree, n
    return jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)]), tree), n


def unpad(tree, n: int):
    """The first n entries of every leaf's leading axis."""
    return jax.tree.map(lambda x: x[:n], tree)


def batched(fn, sub_batch: int | None = None):
    """`fn` (a batch in, a batch out, along the leading axis) with the batch split over the devices:
    padded to a multiple of their count (`pad`), constrained, cut back. With `sub_batch`, a device's
    share larger than that runs as consecutive sub-batches of `sub_batch` arms (`lax.map`), with no
    data moving between devices.

    Large batches are memory-bound on a CPU: a sub-batch keeps each kernel's working set in cache
    (1024 fabric arms: 1.36x the arm-steps/s, experiments/bench_fabric_step.py). Results are `fn`'s;
    a share that does not divide into sub-batches runs whole."""

    def run(*args):
        d = jax.local_device_count()
        args, n = pad(args, d)
        share = jax.tree.leaves(args)[0].shape[0] // d
        if sub_batch is None or share <= sub_batch or share % sub_batch:
            return unpad(fn(*constrain(args)), n)
        k, c = share // sub_batch, sub_batch
        # sub-batch i takes arms [i c, (i + 1) c) of every device's share
        split = lambda x: x.reshape((d, k, c) + x.shape[1:]).swapaxes(0, 1).reshape((k, d * c) + x.shape[1:])  # noqa: E731
        join = lambda x: x.reshape((k, d, c) + x.shape[2:]).swapaxes(0, 1).reshape((d * k * c,) + x.shape[2:])  # noqa: E731
        out = jax.lax.map(lambda sub: fn(*constrain(sub)), jax.tree.map(split, constrain(args)))
        return unpad(jax.tree.map(join, out), n)

    return run
