"""Training wrappers for the guide's environment under brax's PPO (thesis §3.4.5).

`wrap_for_training(env, episode_length, ...)` is the `wrap_env_fn` given to `ppo.train`:

    CurriculumReset(EpisodeWrapper(VmapWrapper(EpisodeSums(env)), episode_length))

- `EpisodeSums` names the grid observations "pixels/<name>" (`networks.ppo_observation`) and
  reports `unique_cells` and `keypoint_distance` as per-step increments, so that brax's episode
  sums (`EpisodeWrapper`, the evaluator) are the episode's final visit count and final keypoint
  distance rather than sums over its steps.
- `CurriculumReset` replaces brax's `AutoResetWrapper`, which restores each env's *first*
  episode: here a finished env starts a freshly sampled episode (new scene, start and goal), and
  the curriculum stage is kept across resets. The stage moves from 1 to 2 once the running mean
  of the unique cells visited per finished episode reaches `cells` (the thesis' trigger; the mean
  is over this device's envs), or at the latest after `max_steps` env steps in stage 1 (a
  training budget's safeguard, not the thesis'); it never moves back. `cells <= 0` trains in
  stage 2 from the start (the no-curriculum ablation); `start_stage` resumes a run in its stage.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs.base import State, Wrapper
from brax.envs.wrappers.training import EpisodeWrapper, VmapWrapper

from fabrax.rl.networks import env_observation, ppo_observation

KEPT = ("steps", "truncation", "episode_done", "episode_metrics", "stage", "cells_mean", "stage1_steps", "reset_key")  # survive an auto-reset


class EpisodeSums(Wrapper):
    """Per-step increments of the cumulative metrics (see the module docstring); metrics an outer
    wrapper added (brax's evaluator adds `reward`) are kept."""

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        info = {**state.info, "last_cells": jnp.zeros(()), "last_distance": jnp.zeros(())}
        return state.replace(obs=ppo_observation(state.obs), info=info, metrics={**state.metrics, "stage_per_step": jnp.zeros(())})

    def step(self, state: State, action: jax.Array) -> State:
        nxt = self.env.step(state.replace(obs=env_observation(state.obs)), action)
        cells, dist = nxt.metrics["unique_cells"], nxt.metrics["keypoint_distance"]
        metrics = {
            **state.metrics,
            **nxt.metrics,
            "unique_cells": cells - state.info["last_cells"],
            "keypoint_distance": dist - state.info["last_distance"],
        }
        metrics["stage_per_step"] = state.info["stage"].astype(jnp.float32)  # brax divides *_per_step sums by the length
        info = {**nxt.info, "last_cells": cells, "last_distance": dist}
        return nxt.replace(obs=ppo_observation(nxt.obs), metrics=metrics, info=info)

    @property
    def observation_size(self):
        return ppo_observation(self.env.observation_size)


class CurriculumReset(Wrapper):
    """Resampling auto-reset that keeps the curriculum stage (see the module docstring). Acts on a
    batch of envs (outside `VmapWrapper`)."""

    def __init__(self, env, cells: float, start_stage: int = 1, max_steps: float | None = None, momentum: float = 0.05):
        super().__init__(env)
        self.cells, self.start_stage, self.momentum = float(cells), int(start_stage), float(momentum)
        self.max_steps = float("inf") if max_steps is None else float(max_steps)

    def _stage0(self, shape) -> jax.Array:
        return jnp.full(shape, 2 if self.cells <= 0 else self.start_stage, jnp.int32)

    def reset(self, rng: jax.Array) -> State:
        keys = jax.vmap(lambda k: jax.random.split(k, 2))(rng)
        state = self.env.reset(keys[:, 0])
        b = rng.shape[:-1]
        stage = jnp.maximum(state.info["stage"], self._stage0(b))  # a `FixedStage` env (evaluation) starts higher
        info = {**state.info, "stage": stage, "cells_mean": jnp.zeros(b), "stage1_steps": jnp.zeros(b), "reset_key": keys[:, 1]}
        return state.replace(info=info)

    def step(self, state: State, action: jax.Array) -> State:
        steps = jnp.where(state.done > 0, 0.0, state.info["steps"])
        state = state.replace(done=jnp.zeros_like(state.done), info={**state.info, "steps": steps})
        state = self.env.step(state, action)
        done = state.done > 0

        # the curriculum: running mean of the finished episodes' unique cells, over this device's envs
        n_done = jnp.sum(done)
        finished = jnp.sum(jnp.where(done, state.info["episode_metrics"]["unique_cells"], 0.0)) / jnp.maximum(n_done, 1)
        m = state.info["cells_mean"]
        m = jnp.where(n_done > 0, jnp.where(m == 0.0, finished, (1.0 - self.momentum) * m + self.momentum * finished), m)
        ran = state.info["stage1_steps"] + jnp.where(state.info["stage"] < 2, done.size, 0)  # this device's env steps in stage 1
        stage = jnp.where((m >= self.cells) | (ran >= self.max_steps), jnp.maximum(state.info["stage"], 2), state.info["stage"])

        # finished envs start a freshly sampled episode
        split = jax.vmap(lambda k: jax.random.split(k, 2))(state.info["reset_key"])
        fresh = self.env.reset(split[:, 0])

        def pick(new, old):
            return jnp.where(done.reshape(done.shape + (1,) * (old.ndim - 1)), new, old)

        info = {k: (v if k in KEPT else jax.tree.map(pick, fresh.info[k], v)) for k, v in state.info.items()}
        info.update(stage=stage, cells_mean=m, stage1_steps=ran, reset_key=split[:, 1])
        return state.replace(
            pipeline_state=jax.tree.map(pick, fresh.pipeline_state, state.pipeline_state),
            obs=jax.tree.map(pick, fresh.obs, state.obs),
            info=info,
        )


class FixedStage(Wrapper):
    """Episodes in a given curriculum stage from their reset (evaluation runs the task: stage 2)."""

    def __init__(self, env, stage: int = 2):
        super().__init__(env)
        self.stage = int(stage)

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        return state.replace(info={**state.info, "stage": jnp.asarray(self.stage, jnp.int32)})


def wrap_for_training(
    env, episode_length: int, action_repeat: int = 1, randomization_fn=None, cells: float = 0.0, start_stage: int = 1, max_steps: float | None = None
):
    """brax's `wrap_env_fn` signature; the curriculum's settings are bound with functools.partial."""
    if randomization_fn is not None:
        raise ValueError("the guide's environment has no domain randomisation (randomization_fn)")
    return CurriculumReset(EpisodeWrapper(VmapWrapper(EpisodeSums(env)), episode_length, action_repeat), cells, start_stage, max_steps)
