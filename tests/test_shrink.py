"""fabrax.shrink: a batched loop that goes on with its running elements alone gives the plain loop's results."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fabrax import shrink


def _toy(lifetimes):
    """Elements that each run `lifetime` steps; a step adds a value that depends on the element and its step."""
    n = len(lifetimes)
    return {"i": jnp.zeros(n, jnp.int32), "life": jnp.asarray(lifetimes, jnp.int32), "x": jnp.zeros(n), "id": jnp.arange(n, dtype=jnp.float32)}


def _running(s):
    return s["i"] < s["life"]


def _advance(s):
    on = _running(s)
    x = s["x"] + jnp.sin(s["id"] * 0.37 + s["i"].astype(jnp.float32))
    return {**s, "i": jnp.where(on, s["i"] + 1, s["i"]), "x": jnp.where(on, x, s["x"])}


def _plain(state, count=None, limit=None):
    def cond(s):
        on = jnp.any(_running(s))
        return on if count is None else on & (jnp.sum(count(s)) < limit)

    return jax.lax.while_loop(cond, _advance, state)


@pytest.mark.parametrize("shrink_by", [1, 2, 4])
def test_shrinking_loop_equals_the_plain_loop(shrink_by):
    rng = np.random.default_rng(0)
    state = _toy(rng.integers(1, 200, size=70))
    got = jax.jit(lambda s: shrink.loop(_advance, _running, s, shrink_by))(state)
    want = jax.jit(_plain)(state)
    assert shrink.sizes(70, 4) == [70, 18]
    for k in ("i", "x"):
        assert np.array_equal(np.asarray(got[k]), np.asarray(want[k])), k
    assert np.array_equal(np.asarray(got["i"]), np.asarray(state["life"]))


def test_shrinking_loop_stops_at_the_count_limit_with_finished_elements_counted():
    """count: finished elements and those past step 200; the loop stops once 60 exist. 56 finish within 80
    steps, before the sub-batch of the 8 others starts, and still count there: it stops at step 201."""
    rng = np.random.default_rng(1)
    state = _toy(np.concatenate([rng.integers(60, 80, size=56), rng.integers(220, 300, size=8)]))
    count = lambda s: (~_running(s) | (s["i"] > 200)).astype(jnp.int32)  # noqa: E731
    got = jax.jit(lambda s: shrink.loop(_advance, _running, s, 4, count=count, limit=60))(state)
    want = jax.jit(lambda s: _plain(s, count, 60))(state)
    assert int(jnp.max(want["i"])) == 201 and int(jnp.sum(_running(want))) == 8
    for k in ("i", "x"):
        assert np.array_equal(np.asarray(got[k]), np.asarray(want[k])), k
