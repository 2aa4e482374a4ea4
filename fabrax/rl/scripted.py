"""Scripted policies for the guide's environment: baselines and the viewer's episodes.

random: uniform actions in [-1, 1] in curriculum stage 1; switch: stage 2 with the fabric switch
on from the first step, i.e. the pure fabric aimed at the goal (the baseline a guide must beat);
hold: zero actions with the switch off, the hand holding its pose.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

POLICIES = ("random", "switch", "hold")


def episode(env, policy: str, key: jax.Array, act=None):
    """One episode of `policy` from a reset: substep configurations (T, S, n), hand targets (T, 7),
    visit counts (T, cells^3), metrics (T,) per policy step, alive (T,) (False after the episode ended).
    `act` (a trained guide's deterministic policy, `fabrax.rl.policy.Guide.act`) replaces the
    scripted actions, in stage 2."""
    stage = jnp.asarray(2 if policy == "switch" or act is not None else 1, jnp.int32)
    k_reset, k_act = jax.random.split(key)
    state = env.reset(k_reset)
    state = state.replace(info={**state.info, "stage": stage})

    def body(carry, k):
        s, alive = carry
        if act is not None:
            a = act(s.obs)
        elif policy == "random":
            a = jax.random.uniform(k, (env.action_size,), minval=-1.0, maxval=1.0)
        else:
            a = jnp.zeros(env.action_size).at[-1].set(1.0 if policy == "switch" else -1.0)
        nxt, qs, params = env.step_with_path(s, a)
        qs = jnp.where(alive, qs, s.pipeline_state.q)
        nxt = jax.tree.map(lambda x, y: jnp.where(alive, x, y), nxt, s)
        target = jnp.concatenate([params["ee"]["target_pos"], params["ee"]["target_quat"]])
        out = (qs, target, nxt.pipeline_state.counts, nxt.metrics, alive)
        return (nxt, alive & (nxt.done == 0.0)), out

    keys = jax.random.split(k_act, env.cfg.episode_steps)
    _, out = jax.lax.scan(body, (state, jnp.ones((), bool)), keys)
    return state, out
