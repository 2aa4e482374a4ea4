"""The MπNets-faithful problem set: frames, scene ranges, problem-type mix, valid starts and goals."""

from collections import Counter

import jax.numpy as jnp
import numpy as np
import pytest

from fabrax.check.clearance import state_clearances
from fabrax.problems import mpinets
from fabrax.robot.kinematics import frame_pose


def _pose(robot, q, frame="panda_hand"):
    T = frame_pose(robot, jnp.asarray(q, jnp.float32), frame)
    quat = np.asarray(T.rotation().wxyz, np.float64)
    return np.asarray(T.translation(), np.float64), quat / np.linalg.norm(quat)


def _same_rotation(qa, qb, tol=1e-9):
    return abs(abs(float(np.dot(qa, qb))) - 1.0) < tol


def test_tcp_conversion_is_exact(panda):
    rng = np.random.default_rng(0)
    for q in rng.uniform(panda.lower, panda.upper, (5, panda.dof)):
        hand_p, hand_q = _pose(panda, q)
        tcp_p, tcp_q = mpinets.hand_to_tcp(hand_p, hand_q)
        z = mpinets._matrix(hand_q)[:, 2]
        np.testing.assert_allclose(tcp_p - hand_p, mpinets.TCP_OFFSET * z, atol=1e-12)  # 0.10 m along the hand's z
        np.testing.assert_allclose(mpinets._matrix(tcp_q), mpinets._matrix(hand_q) @ mpinets._rz(np.pi), atol=1e-12)  # turned 180° about z
        back_p, back_q = mpinets.tcp_to_hand(tcp_p, tcp_q)
        np.testing.assert_allclose(back_p, hand_p, atol=1e-12)
        assert _same_rotation(back_q, hand_q)


def test_quaternion_from_matrix_round_trips():
    rng = np.random.default_rng(1)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        assert _same_rotation(mpinets._quat(mpinets._matrix(q)), q, 1e-12)


def test_problem_type_and_family_mix_matches_mpinets():
    n = 3000
    draws = [mpinets.draw(0, k) for k in range(n)]
    fam, typ = Counter(f for f, _ in draws), Counter(t for _, t in draws)
    for names, counts, weights in ((mpinets.FAMILIES, fam, mpinets.FAMILY_WEIGHTS), (mpinets.TYPES, typ, mpinets.TYPE_WEIGHTS)):
        for name, w in zip(names, weights, strict=True):
            sigma = np.sqrt(n * w * (1 - w))
            assert abs(counts[name] - n * w) < 4 * sigma, (name, counts[name], n * w)
    assert mpinets.draw(0, 7) == mpinets.draw(0, 7) and [mpinets.draw(1, k) for k in range(20)] != draws[:20]


def test_cubby_dimensions_and_merging():
    rng = np.random.default_rng(2)
    for _ in range(200):
        merged = bool(rng.random() < 0.5)
        lay = mpinets.cubby(rng, merged)
        p = lay.params
        assert 0.45 <= p["front"] <= 0.65 and 0.15 <= p["back"] - p["front"] <= 0.55
        assert 0.6 <= p["left"] <= 0.8 and -0.8 <= p["right"] <= -0.6 and 1.2 <= p["left"] - p["right"] <= 1.6
        assert 0.1 <= p["bottom"] <= 0.3 and 0.35 <= p["mid_z"] <= 0.55 and 0.6 <= p["top"] <= 0.8
        assert 0.01 <= p["thickness"] <= 0.03 and abs(p["yaw"]) <= np.pi / 18
        i, j = p["pockets"]
        assert i != j
        across_rows, across_columns = (i < 2) != (j < 2), (i % 2) != (j % 2)
        assert p["shelf"] == (not (merged and across_rows)) and p["wall"] == (not (merged and across_columns))
        names = [o["name"] for o in lay.obstacles]
        assert ("shelf" in names) == p["shelf"] and ("wall" in names) == p["wall"]
        for v in lay.volumes:  # pockets lie inside the cubby's outer box
            corners = v.sample(rng, 64)
            local = (corners - np.array([(p["front"] + p["back"]) / 2, (p["left"] + p["right"]) / 2, 0])) @ mpinets._rz(p["yaw"])
            assert np.all(np.abs(local[:, 0]) <= (p["back"] - p["front"]) / 2 + 1e-9)
            assert np.all((corners[:, 2] >= p["bottom"] - 1e-9) & (corners[:, 2] <= p["top"] + 1e-9))
        if merged and across_rows and not across_columns:
            assert np.allclose(lay.volumes[0].center, lay.volumes[1].center)  # one merged column


def test_dresser_dimensions_and_open_drawers():
    rng = np.random.default_rng(3)
    made = 0
    for _ in range(100):
        lay = mpinets.dresser(rng)
        if lay is None:
            continue
        made += 1
        p = lay.params
        assert 0.8 <= p["width"] <= 1.2 and 0.2 <= p["depth"] <= 0.4 and 0.55 <= p["height"] <= 0.85
        assert 0.55 <= p["x"] <= 0.75 and abs(p["y"]) <= 0.1 and abs(p["rotation"] - np.pi / 2) <= np.pi / 3
        assert p["drawers"] >= 2 and p["open"][0] != p["open"][1]
        assert sum(o["name"] == "drawer" for o in lay.obstacles) == 10  # two open drawers of five boards
        assert sum(o["name"] == "front" for o in lay.obstacles) == p["drawers"] - 2  # closed ones: their fronts
        for v in lay.volumes:
            assert np.all(v.size > 0.0) and v.center[2] - v.size[2] / 2 >= -1e-9  # above the floor
            out = np.array([np.cos(p["rotation"] + np.pi / 2), np.sin(p["rotation"] + np.pi / 2)])  # the front's normal
            assert np.dot(v.center[:2] - [p["x"], p["y"]], out) > p["depth"] / 2  # out of the body
    assert made >= 50


def test_tabletop_dimensions():
    rng = np.random.default_rng(4)
    heights = []
    for _ in range(100):
        lay = mpinets.tabletop(rng)
        h = lay.params["height"]
        heights.append(h)
        assert 0.0 <= h <= 0.4 and 3 <= len(lay.objects) <= 14
        for o in lay.objects:
            tall = o["length"] if o["type"] == "cylinder" else o["size"][2]
            assert 0.05 <= tall <= 0.35 and abs(o["center"][2] - (h + tall / 2)) < 1e-9
            on = any(lo[0] <= o["center"][0] <= hi[0] and lo[1] <= o["center"][1] <= hi[1] for lo, hi in lay.tables)
            assert on
        for _ in range(5):
            p, m = mpinets._table_pose(rng, lay)
            assert m[2, 2] < -0.6  # pointing down within roll 135-225° and pitch ±22.5°
            assert h + 0.01 - 1e-9 <= p[2] <= h + 0.35 + 0.12 + 1e-9
    assert 0.2 < np.mean(np.asarray(heights) == 0.0) < 0.5  # 35 % of tables at floor level


@pytest.mark.parametrize("index", [2, 3, 5, 7])  # cubby task-oriented, tabletop neutral goal, dresser neutral start, cubby neutral goal
def test_generated_problems_are_valid(panda, index):
    family, kind = mpinets.draw(0, index)
    p = mpinets.one(panda, 0, index)
    assert p is not None and p.valid, p and p.reason
    assert p.meta["family"] == family == p.kind and p.meta["problem_type"] == kind and p.name == f"{family}/{kind}/{index:05d}"
    goal_q = np.asarray(p.meta["goal_q"])
    qs = np.stack([p.start_q, goal_q])
    env, slf, ok = (np.asarray(a) for a in state_clearances(panda, p.scene, jnp.asarray(qs, jnp.float32)))
    assert np.all(env > 0.0) and np.all(slf > 0.0) and np.all(ok)
    hand_p, hand_q = _pose(panda, goal_q)  # the goal configuration reaches the goal pose, hand and TCP
    np.testing.assert_allclose(hand_p, p.goal_pose[0], atol=2e-3)
    assert _same_rotation(hand_q, p.goal_pose[1], 1e-4)
    tcp_p, _ = mpinets.hand_to_tcp(*p.goal_pose)
    np.testing.assert_allclose(tcp_p, p.meta["tcp_goal"][0], atol=1e-9)
    if kind == "neutral_start":
        assert np.all(p.start_q >= np.minimum(mpinets.NEUTRAL, panda.upper) - 1e-9)
        assert np.all(p.start_q <= mpinets.NEUTRAL + 0.25 + 1e-9)
    if kind == "neutral_goal":
        assert np.all((goal_q >= mpinets.NEUTRAL - 1e-9) & (goal_q <= mpinets.NEUTRAL + 0.25 + 1e-9))


def test_generate_filters_counts_drops_and_caches(panda, tmp_path):
    calls = []

    def every_other(robot, p):
        calls.append(p.name)
        return len(calls) % 2 == 1

    kw = dict(classes=["cubby", "merged_cubby"], types=["task_oriented"], solvable=every_other, solvable_key="test", cache_dir=tmp_path)
    s = mpinets.generate(panda, 2, seed=0, **kw)
    assert len(s.problems) == 2 and len(s.dropped) == 1 and s.solvable == "test"
    assert all(p.kind in ("cubby", "merged_cubby") and p.meta["problem_type"] == "task_oriented" for p in s.problems)
    n_calls = len(calls)
    again = mpinets.generate(panda, 2, seed=0, **kw)  # read back from the cache: no new checks
    assert len(calls) == n_calls and [p.name for p in again.problems] == [p.name for p in s.problems]
    with pytest.raises(ValueError, match="unknown MπNets types"):
        mpinets.generate(panda, 1, types=["sideways"])


def test_bench_checks_types_and_budget_before_any_work():
    from fabrax.bench.cli import check, compose

    with pytest.raises(SystemExit, match="types= selects problem types of problems=mpinets"):
        check(compose(["problems=mbm_like", "types=[task_oriented]"]))
    with pytest.raises(SystemExit, match="solvable_s must be a positive number"):
        check(compose(["problems=mpinets", "solvable_s=-1"]))
    check(compose(["problems=mpinets", "types=[task_oriented,neutral_goal]", "solvable_s=null"]))


def test_summary_has_a_table_per_problem_type():
    from fabrax.bench.runner import METRICS, summary_table

    def row(cls, kind, ok):
        r = {"problem": f"{cls}/{kind}", "class": cls, "problem_type": kind, "method": "m", "valid_problem": True, "success": ok, "collision": not ok}
        return r | {m: 1.0 for m in METRICS} | {f"success_{c}": ok for c in ("joint", "pose", "keypoints")}

    rows = [row("cubby", "task_oriented", False), row("cubby", "neutral_goal", True), row("dresser", "task_oriented", True)]
    text = summary_table(rows)
    assert "| m | task_oriented | 2/2 | 50 | 50 |" in text and "| m | neutral_goal | 1/1 | 100 | 0 |" in text
    assert "| m | all | 3/3 | 67 | 33 |" in text and "| m | cubby | 2/2 | 50 | 50 |" in text
