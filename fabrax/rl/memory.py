"""Whether one PPO training step's rollout fits the accelerator, checked before training starts.

brax's PPO collects `batch_size x num_minibatches` unrolls of `unroll_length` env steps per
training step and keeps every transition's observation and next observation on the device (then
a shuffled copy for the minibatches). The guide's observation is large (thesis Table 3.2: a
16^3 x 3 basis point set and a 20^3 exploration map, ~20k floats), so a preset sized for one GPU
can need more memory than the GPU has; XLA would fail deep inside the first compile. This module
estimates the floor (observations twice per transition, float32) and refuses a run that cannot
fit, naming the settings to lower.
"""

from __future__ import annotations

import math
import os

import jax


def observation_floats(observation_size: dict[str, tuple[int, ...]]) -> int:
    """Floats in one observation (every entry of the env's observation dict)."""
    return int(sum(math.prod(shape) for shape in observation_size.values()))


def rollout_bytes(batch_size: int, num_minibatches: int, unroll_length: int, observation_size: dict[str, tuple[int, ...]]) -> int:
    """A floor on one training step's rollout memory: its transitions' observations and next
    observations in float32 (actions, rewards and the shuffled copy come on top)."""
    transitions = batch_size * num_minibatches * unroll_length
    return 2 * transitions * observation_floats(observation_size) * 4


def device_bytes(device=None) -> int | None:
    """Memory of one local device: the accelerator's `bytes_limit`, or the host's physical memory
    for a CPU device (None where neither is known)."""
    device = device or jax.local_devices()[0]
    stats = device.memory_stats() if hasattr(device, "memory_stats") else None
    if stats and stats.get("bytes_limit"):
        return int(stats["bytes_limit"])
    if device.platform == "cpu":
        try:
            return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
        except (ValueError, OSError, AttributeError):
            return None
    return None


def check_rollout_fits(ppo, observation_size: dict[str, tuple[int, ...]], devices: int | None = None, limit: int | None = None) -> int:
    """Raise a one-line ValueError when the rollout floor, split over `devices` (brax's pmap), exceeds
    one device's memory (`limit`, default `device_bytes()`); returns the floor in bytes."""
    need = rollout_bytes(ppo.batch_size, ppo.num_minibatches, ppo.unroll_length, observation_size)
    devices = devices or jax.local_device_count()
    limit = device_bytes() if limit is None else limit
    if limit is not None and need / devices > limit:
        gib = 1024**3
        raise ValueError(
            f"ppo: one training step keeps at least {need / devices / gib:.1f} GiB of observations per device "
            f"(batch_size x num_minibatches x unroll_length = {ppo.batch_size * ppo.num_minibatches * ppo.unroll_length} "
            f"transitions x {observation_floats(observation_size)} floats x 2), more than the device's {limit / gib:.1f} GiB; "
            "lower ppo.num_minibatches, ppo.batch_size or ppo.unroll_length"
        )
    return need
