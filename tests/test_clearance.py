"""`clearances`, the host callers' form of the exact checker's state test."""

import jax.monitoring as monitoring
import jax.numpy as jnp
import numpy as np

from fabrax.check import clearances, state_clearances
from fabrax.scene import from_dict


def _scene(rng, cuboids: int, cylinders: int):
    obstacles = [{"type": "cuboid", "center": rng.uniform(0.2, 0.7, 3).tolist(), "size": [0.2, 0.1, 0.3]} for _ in range(cuboids)]
    obstacles += [{"type": "cylinder", "center": rng.uniform(0.2, 0.7, 3).tolist(), "radius": 0.05, "length": 0.3} for _ in range(cylinders)]
    return from_dict({"obstacles": obstacles})


def test_host_clearances_equal_the_checker_and_share_one_program(panda):
    """Padded to 8 slots per kind and the rows to a power of two, `clearances` gives
    `state_clearances`' values row for row, and a scene of another obstacle count in the same
    bucket, with another number of rows, lowers no new program."""
    rng = np.random.default_rng(3)
    cases = [(_scene(rng, 3, 2), 5), (_scene(rng, 6, 1), 7), (_scene(rng, 1, 0), 1)]
    cases = [(s, rng.uniform(panda.lower, panda.upper, (m, panda.dof)).astype(np.float32)) for s, m in cases]
    lowered, new = [], []

    def listen(event, secs, **kw):
        if event.endswith("jaxpr_to_mlir_module_duration"):
            lowered.append(event)

    monitoring.register_event_duration_secs_listener(listen)
    try:
        got = []
        for s, qs in cases:
            before = len(lowered)
            got.append(clearances(panda, s, qs))
            new.append(len(lowered) - before)
    finally:
        monitoring.unregister_event_duration_listener(listen)
    assert new[1] == new[2] == 0, new
    for (s, qs), values in zip(cases, got, strict=True):
        for a, b in zip(values, state_clearances(panda, s, jnp.asarray(qs)), strict=True):
            assert a.shape == qs.shape[:1]
            np.testing.assert_allclose(a, np.asarray(b), rtol=0, atol=1e-6)
    assert any(np.min(v[0]) < 0.0 for v in got) and any(np.max(v[0]) > 0.0 for v in got)  # both verdicts occur
    empty = clearances(panda, cases[0][0], np.zeros((0, panda.dof)))
    assert [len(a) for a in empty] == [0, 0, 0]
