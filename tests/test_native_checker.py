"""The numba checker of the OMPL baselines equals the exact checker."""

import jax.numpy as jnp
import numpy as np
import pytest

from fabrax.check.clearance import state_clearances
from fabrax.problems import procedural
from fabrax.scene import COMMON_CAPACITY, from_dict

pytest.importorskip("numba", reason="numba is not installed (pip install -e '.[bench]')")


def _scenes(panda):
    yield procedural.generate(panda, "mpinets_like", ["tabletop"], 1, 3)[0].scene  # cuboids and cylinders
    yield procedural.generate(panda, "mbm_like", ["cage"], 1, 3)[0].scene
    q = [0.96, 0.1, -0.2, 0.15]
    yield from_dict(
        {
            "obstacles": [
                {"type": "sphere", "center": [0.45, 0.0, 0.5], "radius": 0.12},
                {"type": "cylinder", "center": [0.3, 0.3, 0.4], "quat_wxyz": q, "radius": 0.06, "length": 0.5},
                {"type": "cuboid", "center": [0.4, -0.3, 0.3], "quat_wxyz": q, "size": [0.2, 0.1, 0.6]},
            ],
            "points": [[0.5, 0.2, 0.7], [0.3, -0.1, 0.9]],
        }
    )


def test_native_clearances_equal_the_exact_checker(panda):
    from fabrax.check.native import NativeChecker

    rng = np.random.default_rng(0)
    q = rng.uniform(np.asarray(panda.lower) - 0.05, np.asarray(panda.upper) + 0.05, (1500, panda.dof))  # some outside the limits
    for scene in _scenes(panda):
        check = NativeChecker(panda, scene)
        env, slf, ok = check.clearances(q)
        exact = [np.asarray(a) for a in state_clearances(panda, scene.pad(**COMMON_CAPACITY), jnp.asarray(q, jnp.float32))]
        np.testing.assert_allclose(env, exact[0], atol=2e-5)
        np.testing.assert_allclose(slf, exact[1], atol=2e-5)
        np.testing.assert_array_equal(ok, exact[2])
        valid = (exact[0] >= 0) & (exact[1] >= 0) & exact[2]
        assert 0.05 < valid.mean() < 0.95  # both kinds of states are exercised
        clear = np.minimum(np.abs(exact[0]), np.abs(exact[1])) > 1e-4  # away from float32's rounding of contact
        np.testing.assert_array_equal(check.valid(q)[clear], valid[clear])
        # a motion is valid when all its states are, however early the bounding-sphere culling stops it
        for k in range(0, 60, 6):
            chunk = q[k : k + 6]
            assert check.all_valid(chunk) == bool(check.valid(chunk).all())
        assert check.all_valid(q[valid & clear][:20])
