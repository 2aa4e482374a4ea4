"""Compatibility of the libraries fabrax builds on across the supported JAX range (jax 0.9.2-0.11),
and their import-time noise.

brax 0.14.2 (the newest brax) replicates its training state over devices with
`jax.device_put_replicated`, which jax removed from its public namespace after 0.9 (accessing it
raises AttributeError). `brax_ppo()` returns brax's PPO module with the function available again:
jax's own implementation where jax still ships it, else the same replication by public API (the
value stacked once per device, sharded along the new leading axis). Everything in fabrax that
trains with brax imports PPO through here.

brax's observation normaliser starts with `std_eps` a Python float, which becomes a weakly typed
array in the replicated training state, while every update returns it strongly typed: the
evaluation unroll, compiled first with the initial parameters, was traced and compiled a second
time at the first evaluation after training began. `brax_ppo()` makes the initial `std_eps` a
strongly typed array of the statistics' dtype, the type every update returns. Its evaluator also
starts from an environment state that is not committed to a device, and every later evaluation
from the committed state the unroll returned (replicated like the policy parameters, over every
device of a multi-device run): the same program was lowered and compiled twice. `brax_ppo()`
places the first state as the parameters are placed before the first evaluation.

mujoco-mjx 3.17 prints "Failed to import warp" and "Failed to import mujoco_warp" when it is
imported without the optional NVIDIA Warp backend, which fabrax does not use; `quiet_mjx()` imports
it once with those two lines dropped (anything else it prints is printed).
"""

from __future__ import annotations

import contextlib
import functools
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


def strong_normaliser_init() -> None:
    """brax's `running_statistics.init_state` with `std_eps` an array of the statistics' dtype (see
    the module docstring); idempotent."""
    from brax.training.acme import running_statistics as rs

    if getattr(rs.init_state, "strong_std_eps", False):
        return
    original = rs.init_state

    @functools.wraps(original)
    def init_state(*args, **kwargs):
        state = original(*args, **kwargs)
        dtype = jax.numpy.float64 if jax.config.jax_enable_x64 else jax.numpy.float32
        return state.replace(std_eps=jax.numpy.asarray(state.std_eps, dtype))

    init_state.strong_std_eps = True
    rs.init_state = init_state


def committed_eval_state() -> None:
    """brax's `acting.Evaluator` with its first environment state placed, at the first evaluation,
    where the unroll's outputs will live: replicated like the policy parameters it is given (one
    device, or every device of a multi-device run; see the module docstring). Idempotent, and a
    no-op on a brax whose evaluator keeps no such state."""
    from brax.training import acting

    if getattr(acting.Evaluator.run_evaluation, "commits_state", False):
        return
    original = acting.Evaluator.run_evaluation

    @functools.wraps(original)
    def run_evaluation(self, policy_params, *args, **kwargs):
        state = getattr(self, "_eval_state_to_donate", None)
        leaf = next(iter(jax.tree.leaves(policy_params)), None)
        sharding = getattr(leaf, "sharding", None)
        first = next(iter(jax.tree.leaves(state)), None)
        if sharding is not None and sharding.is_fully_replicated and getattr(leaf, "committed", False) and not getattr(first, "committed", True):
            self._eval_state_to_donate = jax.device_put(state, sharding)
        return original(self, policy_params, *args, **kwargs)

    run_evaluation.commits_state = True
    acting.Evaluator.run_evaluation = run_evaluation


def brax_ppo():
    """brax's PPO training module (`brax.training.agents.ppo.train`), usable on this jax."""
    ensure_device_put_replicated()
    strong_normaliser_init()
    committed_eval_state()
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
