"""Compatibility of the libraries fabrax builds on across the supported JAX range (jax 0.9.2-0.11),
and their import-time noise.

brax 0.14.2 (the newest brax) replicates its training state over devices with
`jax.device_put_replicated`, which jax removed from its public namespace after 0.9 (accessing it
raises AttributeError). `brax_ppo()` returns brax's PPO module with the function available again:
jax's own implementation where jax still ships it, else the same replication by public API (the
value stacked once per device, sharded along the new leading axis). Everything in fabrax that
trains with brax imports PPO through here.

mujoco-mjx 3.17 prints "Failed to import warp" and "Failed to import mujoco_warp" when it is
imported without the optional NVIDIA Warp backend, which fabrax does not use; `quiet_mjx()` imports
it once with those two lines dropped (anything else it prints is printed).
"""

from __future__ import annotations

import contextlib
import io
import sys
from typing import Sequence

import jax
import numpy as np


def device_put_replicated(x, devices: Sequence):
    """`x` (a pytree) broadcast along a new leading axis, one slice on each of `devices`
    (jax 0.9's `jax.device_put_replicated`)."""
    if not devices:
        raise ValueError("device_put_replicated: devices must be a non-empty sequence")
    devices = list(devices)
    mesh = jax.sharding.Mesh(np.asarray(devices), ("replica",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("replica"))
    return jax.tree.map(lambda a: jax.device_put(np.stack([np.asarray(a)] * len(devices)), sharding), x)


def _jax_device_put_replicated():
    """jax's own `device_put_replicated`, or None where jax no longer has it."""
    try:  # jax's implementation, without the deprecation warning of its public name
        from jax._src.api import device_put_replicated as internal

        return internal
    except ImportError:
        return getattr(jax, "device_put_replicated", None) if "device_put_replicated" in vars(jax) else None


def ensure_device_put_replicated() -> None:
    """Make `jax.device_put_replicated` callable (as brax 0.14 calls it) on every supported jax."""
    fn = _jax_device_put_replicated()
    if fn is None:
        fn = device_put_replicated
    if "device_put_replicated" not in vars(jax):
        jax.device_put_replicated = fn


def brax_ppo():
    """brax's PPO training module (`brax.training.agents.ppo.train`), usable on this jax."""
    ensure_device_put_replicated()
    from brax.training.agents.ppo import train as ppo

    return ppo


WARP_NOISE = ("Failed to import warp:", "Failed to import mujoco_warp:")


def quiet_mjx():
    """`mujoco.mjx`, imported without its optional-backend notices (see the module docstring)."""
    if "mujoco.mjx" in sys.modules:
        return sys.modules["mujoco.mjx"]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        from mujoco import mjx
    rest = [line for line in buf.getvalue().splitlines() if not line.startswith(WARP_NOISE)]
    if rest:
        print("\n".join(rest))
    return mjx
