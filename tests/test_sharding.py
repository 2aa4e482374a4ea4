"""Batches split over devices give the numbers of one device (`fabrax.sharding`).

The same script runs in two fresh processes, with one and with two XLA host
devices (FABRAX_CPU_DEVICES), on a rollout batch (also run as sub-batches of one
arm), a GFCS-style population, a GFCS solve, a geodesic batch and a batch of 5 padded to 6;
the two-device run must actually split them, and its rollout must run without cross-device
collectives (`sharding.per_device`).
"""

import json
import os
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

from fabrax import sharding

SCRIPT = textwrap.dedent(
    """
    import json
    import jax, jax.numpy as jnp, numpy as np
    import fabrax
    from fabrax import config, sharding
    from fabrax.problems import batch
    from fabrax.problems.generators import flying_cuboids, random_problems
    from fabrax.rollout import reach, rollout_population
    from fabrax.skills import geodesic
    from fabrax.planners.gfcs import GFCSConfig, solve
    from fabrax.problems import ProblemBatch

    robot = config.load_robot()
    fab, params = config.load_fabric(robot)
    rng = np.random.default_rng(3)
    problems = random_problems(robot, [flying_cuboids(rng) for _ in range(4)], seed=3)
    reach_fn = jax.jit(lambda b: reach(fab, params, b, "joint", dt=0.01, steps=60))
    tr = reach_fn(batch(problems))
    hlo = reach_fn.lower(batch(problems)).compile().as_text()
    collectives = sum(hlo.count(op + "(") for op in ("all-reduce", "all-gather", "all-to-all", "collective-permute"))
    sub = jax.jit(lambda b: reach(fab, params, b, "joint", dt=0.01, steps=60, sub_batch=1))(batch(problems))  # sub-batches of one

    goals = jnp.asarray(np.random.default_rng(4).uniform(-0.5, 0.5, (4, 7)) + np.asarray(problems[0].start_q), jnp.float32)
    seqs = jax.vmap(lambda g: jax.tree.map(lambda a: a[None], fab.with_joint_goal(params, g)))(goals)
    pop = jax.jit(lambda s: rollout_population(fab, s, problems[0].scene, problems[0].start_q, jnp.zeros(7), fab.reached, dt=0.01, steps=60))(seqs)

    h = lambda args, z: jnp.concatenate([z, args * jnp.exp(-jnp.sum(z * z))[None]])  # a bump over the plane
    bump = geodesic.CurveMetric(
        lambda args, z, v: jnp.sum(jax.jvp(lambda z: h(args, z), (z,), (v,))[1] ** 2), lambda args, a, b: jnp.sum((h(args, b) - h(args, a)) ** 2)
    )
    starts = jnp.asarray([[-1.0, 0.1], [-1.0, -0.2], [-0.8, 0.3], [-1.2, 0.0]])
    geo = geodesic.solver(bump, geodesic.GeodesicConfig(iters=50))(jnp.float32(2.0), starts, -starts[:, ::-1])
    odd = jax.jit(sharding.batched(jax.vmap(lambda z: jnp.sin(z) * jnp.sum(z * z))))(jnp.arange(15.0).reshape(5, 3))  # padded to 6
    gfcs = solve(fab, params, ProblemBatch.of(problems[0]), jax.random.PRNGKey(0), GFCSConfig(population=4, batches=2, t_max=0.6))

    print(json.dumps({
        "devices": jax.local_device_count(), "collectives": collectives,
        "split": [not x.sharding.is_fully_replicated for x in (tr.q, sub.q, pop.q, geo.energy)],
        "odd": np.asarray(odd).tolist(),
        "reach_q": np.asarray(tr.q).tolist(), "reach_len": np.asarray(tr.length).tolist(), "sub_q": np.asarray(sub.q).tolist(),
        "pop_q": np.asarray(pop.q).tolist(), "geo_energy": np.asarray(geo.energy).tolist(),
        "gfcs_first": [float(b["best_cost"]) for b in gfcs.per_batch][0],
    }))
    """
)


def _run(devices: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["FABRAX_CPU_DEVICES"] = str(devices)
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_two_devices_split_the_batches_and_match_one_device():
    one, two = _run(1), _run(2)
    assert one["devices"] == 1 and two["devices"] == 2
    assert one["split"] == [False] * 4 and two["split"] == [True] * 4
    assert two["collectives"] == 0  # each device steps its own arms: nothing crosses devices inside the rollout
    assert one["reach_len"] == two["reach_len"]
    for key in ("reach_q", "pop_q", "geo_energy", "sub_q", "odd", "gfcs_first"):  # GFCS: its first batch's best cost
        assert np.allclose(np.asarray(one[key]), np.asarray(two[key]), atol=1e-5), key
    for run in (one, two):  # sub-batched rollouts are the whole batch's
        assert np.allclose(np.asarray(run["sub_q"]), np.asarray(run["reach_q"]), atol=1e-5)


def test_pad_repeats_the_last_entry_and_unpad_cuts_back():
    tree = {"a": jnp.arange(5.0), "b": jnp.ones((5, 2))}
    padded, n = sharding.pad(tree, 4)
    assert n == 5 and padded["a"].shape == (8,) and padded["b"].shape == (8, 2)
    assert np.all(np.asarray(padded["a"][5:]) == 4.0)
    assert np.array_equal(np.asarray(sharding.unpad(padded, n)["a"]), np.arange(5.0))
    with pytest.raises(ValueError, match="same leading"):
        sharding.pad({"a": jnp.ones(3), "b": jnp.ones(4)}, 2)


def test_bad_cpu_device_count_is_refused():
    env = {**os.environ, "FABRAX_CPU_DEVICES": "two"}
    env.pop("XLA_FLAGS", None)
    out = subprocess.run([sys.executable, "-c", "import fabrax"], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode != 0 and "FABRAX_CPU_DEVICES must be a positive integer" in out.stderr
