"""GFCS: the command-sequence cost and the CMA-ES solver (gfcs_paper eqs. 4-8, Algorithm 1)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fabrax import config
from fabrax.planners.gfcs import GFCOP, GFCSConfig, sequence_cost, solve, to_commands, to_unconstrained, uniform_sampler
from fabrax.scene import from_dict

READY = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785], np.float32)


@pytest.fixture(scope="module")
def fabric_params(panda):
    return config.load_fabric(panda, "panda")


def _problem(goal, obstacles=()):
    return GFCOP(jnp.asarray(READY), jnp.zeros(7), jnp.asarray(goal, jnp.float32), from_dict({"obstacles": list(obstacles)}, {"cuboids": 2}))


def test_commands_stay_inside_limits_and_round_trip(panda):
    z = jnp.asarray(np.random.default_rng(0).normal(0, 20, (100, 2, 7)), jnp.float32)
    q = to_commands(z, panda.lower, panda.upper)
    assert bool(jnp.all((q >= panda.lower) & (q <= panda.upper)))
    q0 = jnp.asarray(READY)
    assert np.allclose(to_commands(to_unconstrained(q0, panda.lower, panda.upper), panda.lower, panda.upper), q0, atol=1e-5)
    samples = uniform_sampler(jax.random.PRNGKey(0), panda, 512, 1)
    u = (to_commands(samples, panda.lower, panda.upper) - panda.lower) / (panda.upper - panda.lower)
    assert abs(float(u.mean()) - 0.5) < 0.02 and float(u.std()) == pytest.approx(np.sqrt(1 / 12), abs=0.02)


def test_cost_of_a_reaching_sequence_is_lower(fabric_params, panda):
    fabric, params = fabric_params
    goal = READY + np.array([0.5, 0.2, 0, 0.2, 0, 0, 0], np.float32)
    problem = _problem(goal)
    z_good = to_unconstrained(jnp.asarray((READY + goal) / 2)[None], panda.lower, panda.upper)  # a command on the way
    z_far = to_unconstrained(jnp.asarray(panda.lower + 0.02 * (panda.upper - panda.lower))[None], panda.lower, panda.upper)
    kw = dict(steps=150)  # 1.5 s per command: the far command cannot be reached and eats the budget
    cost_good, tr_good = jax.jit(lambda z: sequence_cost(fabric, params, problem, z, **kw))(z_good)
    cost_far, tr_far = jax.jit(lambda z: sequence_cost(fabric, params, problem, z, **kw))(z_far)
    assert bool(tr_good.reached) and float(cost_good) == pytest.approx(float(jnp.sum(tr_good.segment_times)))
    assert float(cost_far) > float(cost_good)
    assert float(cost_good) < 2 * 1.5  # within the two segments' budgets, no penalty


def test_cma_es_best_so_far_improves(fabric_params):
    """A wall between start and goal: the best-so-far cost never rises and improves on batch 1."""
    fabric, params = fabric_params
    goal = np.array([1.2, 0.3, 0.2, -1.6, 0.1, 1.9, 0.8], np.float32)
    wall = {"type": "cuboid", "center": [0.45, 0.3, 0.45], "size": [0.12, 0.12, 0.3]}
    cfg = GFCSConfig(population=12, batches=4, t_max=2.0)
    r = solve(fabric, params, _problem(goal, [wall]), jax.random.PRNGKey(1), cfg)
    best = [b["best_cost"] for b in r.per_batch]
    assert all(b <= a for a, b in zip(best, best[1:]))
    assert r.best_cost == best[-1] == float(r.top_cost[0]) and len(r.top_cost) == cfg.top_m
    assert np.all(np.diff(r.top_cost) >= 0)
    cost, _ = sequence_cost(fabric, params, _problem(goal, [wall]), jnp.asarray(r.best_z), steps=cfg.steps)
    assert float(cost) == pytest.approx(r.best_cost, rel=1e-5)  # the reported cost is the candidate's cost
    with pytest.raises(ValueError, match="samples"):
        solve(fabric, params, _problem(goal), jax.random.PRNGKey(0), cfg, samples=jnp.zeros((3, 1, 7)))
