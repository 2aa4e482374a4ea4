"""Batch axes over all local devices with `jax.sharding`: one mesh, one axis name.

Every batched solver (arm rollouts, GFCS populations, geodesic batches, skill
execution) runs its batch axis split over the devices of `mesh()`: `per_device`
runs a batched function on each device's share with `jax.shard_map`, `batched`
also pads the batch to a multiple of the device count, and `constrain` marks a
batch axis for GSPMD where the whole batch takes part (a population's stop
test). Each arm's maths is the one a single device runs. A multi-GPU node or a
TPU slice scales without code changes. On a CPU, XLA shows one device unless
told otherwise: set FABRAX_CPU_DEVICES=<cores> before importing fabrax (it
becomes `--xla_force_host_platform_device_count`) to run one shard per core.
The RL guide's env batch is split over the same local devices by brax's own `pmap`.
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


def per_device(fn, m: Mesh | None = None):
    """`fn` (a batch in, a batch out: every leaf of its arguments and results has the batch as
    leading axis) run by each device on its own share (`jax.shard_map`). Nothing in `fn` crosses
    devices: a batch left to GSPMD got cross-device collectives inside the fabric step (an all-reduce
    for every round of a vmapped `while_loop`'s test, all-gathers around the self-collision search's
    gathers), which synchronised the devices at every step (experiments/bench_fabric_step.py
    measures the rate on one and two devices). A batch whose
    size does not divide by the device count runs whole, left to GSPMD (`batched` pads it)."""

    def run(*args):
        mm = m or mesh()
        n = mm.devices.size
        if n == 1 or not all(_shardable(x, n) for x in jax.tree.leaves(args)):
            return fn(*args)
        return jax.shard_map(fn, mesh=mm, in_specs=PartitionSpec(AXIS), out_specs=PartitionSpec(AXIS), check_vma=False)(*args)

    return run


def batched(fn, sub_batch: int | None = None):
    """`fn` (a batch in, a batch out, along the leading axis) with the batch split over the devices:
    padded to a multiple of their count (`pad`), run on each device's share (`per_device`), cut
    back. With `sub_batch`, a device's share larger than that runs as consecutive sub-batches of
    `sub_batch` arms (`lax.map`).

    Large batches are memory-bound on a CPU: a sub-batch keeps each kernel's working set in cache
    (experiments/bench_fabric_step.py --chunk measures it). Results are `fn`'s;
    a share that does not divide into sub-batches runs whole."""

    def local(*args):  # one device's share; sub-batch i takes its arms [i c, (i + 1) c)
        share = jax.tree.leaves(args)[0].shape[0]
        if sub_batch is None or share <= sub_batch or share % sub_batch:
            return fn(*args)
        k, c = share // sub_batch, sub_batch
        out = jax.lax.map(lambda sub: fn(*sub), jax.tree.map(lambda x: x.reshape((k, c) + x.shape[1:]), args))
        return jax.tree.map(lambda x: x.reshape((k * c,) + x.shape[2:]), out)

    def run(*args):
        args, n = pad(args, jax.local_device_count())
        return unpad(per_device(local)(*args), n)

    return run
