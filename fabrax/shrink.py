"""Batched loops whose batch shrinks to the elements still running.

Under `jax.vmap` a `lax.while_loop` runs until its last element is done, and
every finished element is still computed at each step. `loop` runs the whole
batch until at most 1/`shrink` of it runs, gathers the running elements into a
sub-batch of that size and goes on with it alone (sizes B, B / shrink, ... down
to `SMALLEST`), then scatters the sub-batches back. Each size is one more
`while_loop` in the same program. Every element's steps are those of the
unshrunk loop, so the results are the same (float rounding aside). Used by the
population rollouts (`fabrax.rollout.rollout_population`) and the geodesic
solver (`fabrax.skills.geodesic`).
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

SMALLEST = 16  # smaller sub-batches save less than their compilation costs (a GFCS population's 8 saved nothing measurable)


def sizes(batch: int, shrink: int) -> list[int]:
    """The batch sizes a loop of `batch` elements runs through: batch, ceil(batch / shrink), ... >= SMALLEST."""
    out = [batch]
    while shrink > 1 and -(-out[-1] // shrink) >= SMALLEST:
        out.append(-(-out[-1] // shrink))
    return out


def loop(advance: Callable, running: Callable, state, shrink: int = 4, count: Callable | None = None, limit=None):
    """Repeat `advance` on a batched `state` (leading axis the batch) while any element runs.

    advance(state) -> state: one step of the whole (sub-)batch; it must leave the
    outputs of elements that no longer run as they were (or change only what the
    caller ignores). running(state) -> (B,) bool. count(state) -> (B,) int and
    `limit`: also stop once the batch's total count, finished elements included,
    reaches limit (e.g. enough arms have arrived).
    """
    steps = sizes(jax.tree.leaves(state)[0].shape[0], shrink)
    fixed = 0  # the count of the elements outside the current sub-batch

    def go_on(after, fixed):
        def cond(s):
            on = jnp.sum(running(s)) > after
            return on if count is None else on & (fixed + jnp.sum(count(s)) < limit)

        return cond

    for k, size in enumerate(steps):
        after = steps[k + 1] if k + 1 < len(steps) else 0
        if k == 0:
            state = jax.lax.while_loop(go_on(after, fixed), advance, state)
            continue
        idx = jnp.argsort(jnp.where(running(state), 0, 1), stable=True)[:size]  # the running elements first
        sub = jax.tree.map(lambda x: x[idx], state)
        if count is not None:
            fixed = jnp.sum(count(state)) - jnp.sum(count(sub))
        sub = jax.lax.while_loop(go_on(after, fixed), advance, sub)
        state = jax.tree.map(lambda x, y: x.at[idx].set(y), state, sub)
    return state
