"""The benchmark harness: exact checker, metrics, retiming, MBM loader, generators and the CLI."""

import dataclasses
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from fabrax import config
from fabrax.bench import check_path, densify, state_clearances
from fabrax.bench.metrics import evaluate, log_dimensionless_jerk
from fabrax.bench.retime import retime
from fabrax.problems import make_problem
from fabrax.problems.mbm import CLASSES, _read_files, data_dir, load_mbm, parse_request, parse_scene
from fabrax.robot.kinematics import frame_pose, sphere_centers
from fabrax.scene import from_dict

READY = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


def _rot(quat):
    w, x, y, z = quat / np.linalg.norm(quat)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _brute_distance(obstacle: dict, p: np.ndarray) -> float:
    """Signed distance of a point to one primitive, written independently of fabrax.scene."""
    c = np.asarray(obstacle["center"])
    if obstacle["type"] == "sphere":
        return float(np.linalg.norm(p - c) - obstacle["radius"])
    local = _rot(np.asarray(obstacle.get("quat_wxyz", [1, 0, 0, 0]), float)).T @ (p - c)
    if obstacle["type"] == "cuboid":
        half = np.asarray(obstacle["size"]) / 2
        q = np.abs(local) - half
        return float(np.linalg.norm(np.maximum(q, 0)) + min(q.max(), 0.0))
    radial = np.hypot(local[0], local[1]) - obstacle["radius"]
    axial = abs(local[2]) - obstacle["length"] / 2
    return float(np.hypot(max(radial, 0), max(axial, 0)) + min(max(radial, axial), 0.0))


def test_checker_matches_brute_force(panda):
    rng = np.random.default_rng(0)
    obstacles = [
        {"type": "cuboid", "center": [0.45, 0.1, 0.4], "quat_wxyz": [0.9, 0.1, 0.3, 0.2], "size": [0.2, 0.3, 0.15]},
        {"type": "cuboid", "center": [0.2, -0.4, 0.2], "size": [0.1, 0.1, 0.5]},
        {"type": "cylinder", "center": [0.3, 0.4, 0.5], "quat_wxyz": [0.8, 0.6, 0, 0], "radius": 0.06, "length": 0.4},
        {"type": "sphere", "center": [0.5, -0.1, 0.7], "radius": 0.1},
    ]
    scene = from_dict({"obstacles": obstacles})
    lo, hi = np.asarray(panda.lower), np.asarray(panda.upper)
    qs = rng.uniform(lo, hi, (64, panda.dof))
    env, slf, lim = (np.asarray(a) for a in state_clearances(panda, scene, jnp.asarray(qs, jnp.float32)))
    radius = np.asarray(panda.collision.radius)
    pi, pj = np.asarray(panda.collision.pair_i), np.asarray(panda.collision.pair_j)
    for k, q in enumerate(qs):
        x = np.asarray(sphere_centers(panda, jnp.asarray(q, jnp.float32)), float)
        brute_env = min(_brute_distance(o, xi) - r for xi, r in zip(x, radius) for o in obstacles)
        brute_self = min(np.linalg.norm(x[i] - x[j]) - radius[i] - radius[j] for i, j in zip(pi, pj))
        assert env[k] == pytest.approx(brute_env, abs=2e-5)
        assert slf[k] == pytest.approx(brute_self, abs=2e-5)
        assert lim[k]
    assert (env < 0).any() and (env > 0).any(), "the random configurations should include both outcomes"
    outside = qs[0].copy()
    outside[3] = hi[3] + 0.1
    assert not check_path(panda, scene, outside[None]).limits_ok


def test_interpolation_catches_a_corner_clip(panda):
    """A cube whose corner pokes into the swept volume between two collision-free waypoints."""
    qa, qb = READY.copy(), READY.copy()
    qa[0], qb[0] = -0.9, 0.9
    x = np.asarray(sphere_centers(panda, jnp.asarray(READY, jnp.float32)), float)
    s = int(np.argmax(np.hypot(x[:, 0], x[:, 1])))  # the sphere farthest from the base axis
    r = float(panda.collision.radius[s])
    half = 0.025
    outward = np.array([x[s, 0], x[s, 1], 0.0]) / np.hypot(x[s, 0], x[s, 1])
    corner_dir = -outward  # the cube sits outside the arm, its (1,1,1) corner rotated to point at the axis
    axis = np.cross([1, 1, 1], corner_dir) / np.linalg.norm(np.cross([1, 1, 1], corner_dir))
    angle = np.arccos(np.dot([1, 1, 1], corner_dir) / np.sqrt(3))
    quat = [np.cos(angle / 2), *(np.sin(angle / 2) * axis)]
    center = x[s] - corner_dir * (0.5 * r + half * np.sqrt(3))
    cube = {"type": "cuboid", "center": center.tolist(), "quat_wxyz": quat, "size": [2 * half] * 3}
    scene = from_dict({"obstacles": [cube]})
    assert _brute_distance(cube, x[s]) == pytest.approx(0.5 * r, abs=1e-6)
    for q in (qa, qb):
        assert not check_path(panda, scene, q[None]).collision
    sparse = check_path(panda, scene, np.stack([qa, qb]), resolution=10.0)  # endpoints only
    dense = check_path(panda, scene, np.stack([qa, qb]))
    assert sparse.checked_states == 2 and not sparse.collision
    assert dense.collision and dense.first_collision == 0 and dense.min_clearance < -0.4 * r
    states, owner = densify(np.stack([qa, qb, qa]))
    assert np.abs(np.diff(states, axis=0)).max() <= 1 / 32 + 1e-12 and owner.max() == 1


def test_ldj_published_reference():
    t = np.arange(-1.0, 1.0, 0.01)
    assert log_dimensionless_jerk(np.exp(-5 * t**2), 0.01) == pytest.approx(-5.81636, abs=1e-5)
    # LDJ is dimensionless: scaling speed or time leaves it unchanged
    assert log_dimensionless_jerk(3.0 * np.exp(-5 * t**2), 0.01) == pytest.approx(-5.81636, abs=1e-5)


def test_metrics_of_a_straight_joint_path(panda):
    """Joint 1 sweeps 0.6 rad at constant speed: C-space length 0.6, the hand an arc of radius rho."""
    problem = make_problem(panda, READY, {"obstacles": []}, goal_q=READY + [0.6, 0, 0, 0, 0, 0, 0])
    s = np.linspace(0, 1, 301)[:, None]
    q = READY + s * (problem.goal_q - READY)
    m = evaluate(panda, problem, q, dt=0.01)
    p = np.asarray(frame_pose(panda, jnp.asarray(READY, jnp.float32), "panda_hand").translation())
    assert m["success"] and m["reached"] and not m["collision"]
    assert m["cspace_length"] == pytest.approx(0.6, rel=1e-9)
    assert m["ee_length"] == pytest.approx(np.hypot(p[0], p[1]) * 0.6, rel=1e-4)
    assert m["duration_s"] == pytest.approx(3.0)
    short = evaluate(panda, problem, q[:150], dt=0.01)
    assert not short["success"] and short["joint_error"] == pytest.approx(0.3, abs=0.003)


def test_retime_respects_limits_and_waypoints(panda):
    rng = np.random.default_rng(1)
    path = READY + rng.uniform(-0.6, 0.6, (5, panda.dof))
    dt = 0.002
    q = retime(panda, path, dt)
    assert np.allclose(q[0], path[0]) and np.allclose(q[-1], path[-1])
    vel = np.diff(q, axis=0) / dt
    acc = np.diff(q, 2, axis=0) / dt**2
    assert (np.abs(vel) <= np.asarray(panda.velocity) * (1 + 1e-6)).all()
    assert (np.abs(acc) <= np.asarray(panda.acceleration) * 1.05).all()
    for w in path:  # it stops at every waypoint
        assert np.min(np.linalg.norm(q - w, axis=1)) < 1e-3


def test_mbm_loader_matches_converted_json(shared_data):
    converted = json.loads((shared_data / "mbm_panda.json").read_text())
    files = _read_files(data_dir(shared_data))
    names = tuple(converted["meta"]["joint_order"])
    assert len(converted["problems"]) == 700
    for ref in converted["problems"]:
        cls, i = ref["class"], ref["index"]
        scene = parse_scene(files[f"{cls}_panda/scene{i:04d}.yaml"])
        start, goal, pose = parse_request(files[f"{cls}_panda/request{i:04d}.yaml"], names)
        assert np.allclose(start, ref["start_q"], atol=1e-9) and np.allclose(goal, ref["goal_q"], atol=1e-9) and pose is None
        assert len(scene["obstacles"]) == len(ref["obstacles"]), ref["name"]
        for ours, theirs in zip(scene["obstacles"], ref["obstacles"], strict=True):
            assert ours["type"] == theirs["type"] and ours["name"] == theirs["name"]
            assert np.allclose(ours["center"], theirs["center"], atol=1e-9)
            if "quat_wxyz" in theirs:
                assert abs(np.dot(ours["quat_wxyz"], theirs["quat_wxyz"])) == pytest.approx(1.0, abs=1e-9)
            for key in ("size", "radius", "length"):
                if key in theirs:
                    assert np.allclose(ours[key], theirs[key], atol=1e-12)


def test_mbm_split_and_flags(shared_data):
    robot = config.load_robot("panda_mbm")
    test = load_mbm(robot, shared_data, ["box"], "test", limit=3)
    train = load_mbm(robot, shared_data, ["box"], "train", limit=2)
    assert [p.name for p in test] == ["box/0051", "box/0052", "box/0053"]
    assert [p.name for p in train] == ["box/0001", "box/0002"]
    assert all(p.valid for p in test + train)
    # a robot whose spheres are far too large flags (never drops) every problem, with a reason
    fat = robot.replace(collision=robot.collision.replace(radius=robot.collision.radius + 0.5))
    flagged = load_mbm(fat, shared_data, ["box"], "test", limit=2)
    assert len(flagged) == 2 and not any(p.valid for p in flagged)
    assert all("collision" in p.reason for p in flagged)
    with pytest.raises(ValueError, match="unknown MBM classes"):
        load_mbm(robot, shared_data, ["boxes"])
    assert set(CLASSES) == set(json.loads((shared_data / "mbm_panda.json").read_text())["meta"]["counts"])


def test_mbm_data_path_error(tmp_path, monkeypatch):
    monkeypatch.delenv("FABRAX_DATA", raising=False)
    with pytest.raises(ValueError, match="FABRAX_DATA"):
        data_dir(None)
    with pytest.raises(ValueError, match="neither"):
        _read_files(tmp_path)
    with pytest.raises(ValueError, match="malformed MoveIt scene"):
        parse_scene("world: [")


@pytest.mark.parametrize("family, cls", [("mbm_like", "box"), ("mpinets_like", "cubby")])
def test_generators_deterministic_and_valid(panda, family, cls):
    from fabrax.problems.procedural import generate

    a = generate(panda, family, [cls], n=1, seed=0)
    b = generate(panda, family, [cls], n=1, seed=0)
    c = generate(panda, family, [cls], n=1, seed=1)
    for pa, pb in zip(a, b, strict=True):
        assert pa.valid and pa.kind == cls
        assert np.array_equal(pa.start_q, pb.start_q)
        assert np.array_equal(np.asarray(pa.scene.cuboids.center), np.asarray(pb.scene.cuboids.center))
        assert not check_path(panda, pa.scene, pa.start_q[None]).collision
    assert not np.array_equal(np.asarray(a[0].scene.cuboids.center), np.asarray(c[0].scene.cuboids.center))
    if family == "mpinets_like":
        assert a[0].goal_pose is not None and a[0].goal_q is None
        from fabrax.problems.load import with_ik_goal

        ik = with_ik_goal(panda, a[0], "panda_hand")  # a joint goal for joint-space methods; the pose stays the goal
        assert ik.valid and ik.goal_pose is a[0].goal_pose
        pose = frame_pose(panda, jnp.asarray(ik.goal_q, jnp.float32), "panda_hand")
        np.testing.assert_allclose(pose.translation(), a[0].goal_pose[0], atol=2e-3)
        assert not check_path(panda, ik.scene, ik.goal_q[None]).collision
        np.testing.assert_array_equal(with_ik_goal(panda, a[0], "panda_hand").goal_q, ik.goal_q)  # seeded by the name
    else:
        assert not check_path(panda, a[0].scene, a[0].goal_q[None]).collision
    with pytest.raises(ValueError, match="unknown"):
        generate(panda, family, ["nope"], n=1)


def test_bench_cli_end_to_end(tmp_path):
    from fabrax.bench.cli import main

    out = tmp_path / "gf"
    args = ["method=gf", "problems=mbm_like", "classes=[box]", "limit=2", "t_max=3.0", f"out={out}", "progress=false"]
    assert main(args) == 0
    data = json.loads((out / "results.json").read_text())
    rows = data["rows"]
    assert len(rows) == 2 and data["meta"]["config"]["method"]["name"] == "gf"
    import fabrax

    assert data["meta"]["source"]["path"] == str(Path(fabrax.__file__).resolve().parent)  # which code ran
    for row in rows:
        assert row["method"] == "gf" and row["class"] == "box" and row["valid_problem"]
        for key in ("success", "collision", "ee_length", "cspace_length", "ee_ldj", "cspace_ldj", "plan_time_s", "duration_s"):
            assert key in row
        assert row["duration_s"] <= 3.0 + 1e-9 and row["plan_time_s"] > 0
    assert "| gf | box | 2/2 |" in (out / "summary.md").read_text()
    assert (out / "success.png").stat().st_size > 0
    with pytest.raises(SystemExit, match="nope"):
        main(["nope=1"])


@pytest.mark.parametrize(
    "arg, message",
    [
        ("limit=0", "limit must be a positive integer"),
        ("limit=-1", "limit must"),
        ("limit=abc", "limit must"),
        ("classes=box", r"classes=\[box,cage\]"),
        ("split=foo", "split must be train, test or all"),
        ("dt=0", "dt must be a positive number"),
        ("t_max=-1", "t_max must"),
    ],
)
def test_bench_cli_rejects_bad_keys_in_one_line(tmp_path, arg, message):
    """Before anything loads: a bad value of the run's own keys is one line naming the key."""
    from fabrax.bench.cli import main

    with pytest.raises(SystemExit, match=message):
        main(["method=gf", "problems=mbm_like", arg, f"out={tmp_path}", "progress=false"])


@pytest.mark.skipif(importlib.util.find_spec("ompl") is None, reason="OMPL is not installed (pip install -e '.[bench]')")
def test_ompl_rrtconnect_through_the_cli(tmp_path):
    out = tmp_path / "rrt"
    cmd = [
        sys.executable,
        "-m",
        "fabrax.bench.cli",
        "method=rrtconnect",
        "problems=mbm_like",
        "classes=[cage]",
        "limit=1",
        f"out={out}",
        "progress=false",
    ]
    subprocess.run(cmd, check=True, timeout=600)
    (row,) = json.loads((out / "results.json").read_text())["rows"]
    assert row["method"] == "rrtconnect" and row["valid_problem"]
    if row["reached"]:  # a found path is retimed and re-checked by the same checker
        assert not row["collision"] and row["duration_s"] > 0


_SEEDED_PLANS = """
import json, os
from fabrax import config
from fabrax.bench.ompl import plan
from fabrax.problems import procedural
from fabrax.problems.load import with_ik_goal
robot = config.load_robot("panda")
p = with_ik_goal(robot, procedural.generate(robot, "mbm_like", ["cage"], 1, 3)[0], robot.ee_frame)
runs = [plan(robot, p, "RRTConnect", 60.0, False, 1 / 32, max_states=budget, seed=5) for budget in (400_000, 400_000, 50)]
print(json.dumps([[None if path is None else path.tolist(), info["states_checked"]] for path, info in runs]))
os._exit(0)  # OMPL 1.7.0's module crashes at interpreter shutdown
"""


@pytest.mark.skipif(importlib.util.find_spec("ompl") is None, reason="OMPL is not installed (pip install -e '.[bench]')")
def test_ompl_seeded_state_budget_is_deterministic():
    """The solvability filter's planner run (seed and a budget of checked states) gives the same
    path in another process, and stops once its budget of states is spent."""
    run = lambda: subprocess.run([sys.executable, "-c", _SEEDED_PLANS], check=True, capture_output=True, text=True, timeout=600)  # noqa: E731
    runs = [json.loads(run().stdout) for _ in range(2)]
    (a, sa), (b, sb), (tiny, st) = runs[0]
    assert a is not None and a == b == runs[1][0][0] and sa == sb == runs[1][0][1]  # same path, same work, both processes
    assert tiny is None and 50 <= st < 50 + 500  # ended at its budget (plus the motion being checked), without a path


def test_solvable_key_names_the_deterministic_budget():
    from fabrax.problems.load import SOLVABLE_STATES_PER_S, solvable_key, solvable_states

    assert solvable_states(10.0) == 10 * SOLVABLE_STATES_PER_S
    assert f"{solvable_states(10.0):,} checked states" in solvable_key(10.0) and solvable_key(10.0) != solvable_key(20.0)


def test_bench_cli_gfcs_reports_batch_variants(tmp_path):
    from fabrax.bench.cli import main

    out = tmp_path / "gfcs"
    args = ["method=gfcs", "method.population=4", "method.batches=2", "method.report=[1]", "problems=mbm_like", "classes=[cage]"]
    assert main(args + ["limit=1", "t_max=1.0", f"out={out}", "progress=false"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert sorted(r["method"] for r in rows) == ["gfcs", "gfcs (1 b)"]
    final, first = sorted(rows, key=lambda r: r["method"])
    assert final["plan_time_s"] >= first["plan_time_s"] > 0  # the final row includes the first batch's time
    assert final["info"]["cost"] <= first["info"]["cost"]  # best-so-far never worsens
    assert len(final["info"]["commands"]) == 1 and len(final["info"]["batch_wall_s"]) == 2


def test_bench_cli_without_data_says_what_to_set(tmp_path, monkeypatch):
    from fabrax.bench.cli import main

    monkeypatch.delenv("FABRAX_DATA", raising=False)
    monkeypatch.chdir(tmp_path)  # no ../shared/data from here
    with pytest.raises(SystemExit, match="set FABRAX_DATA or data_dir="):
        main(["method=gf", "problems=mbm", "classes=[box]", "limit=1", f"out={tmp_path}", "progress=false"])


def test_a_problem_a_method_refuses_fails_alone(panda):
    """One problem a method raises a ValueError on is a failed row with the error; the others stand."""
    from fabrax.bench.methods import Solution
    from fabrax.bench.runner import run
    from fabrax.problems.generators import demo_problem

    base = demo_problem(panda)
    problems = [dataclasses.replace(base, name=f"demo/{k}") for k in range(3)]

    class Straight:
        name, batch_size, dt = "straight", 3, 0.01

        def solve(self, robot, part):
            if any(p.name == "demo/1" for p in part):
                raise ValueError("demo/1: refused")
            return [Solution(np.linspace(p.start_q, p.goal_q, 50), self.dt, 0.1) for p in part]

    rows = {r["problem"]: r for r in run(Straight(), panda, problems, progress=False)}
    assert set(rows) == {"demo/0", "demo/1", "demo/2"}
    assert rows["demo/1"]["info"]["error"] == "demo/1: refused" and not rows["demo/1"]["success"]
    assert rows["demo/0"]["reached"] and rows["demo/2"]["reached"] and "error" not in rows["demo/0"]["info"]


def test_progress_says_the_first_batch_compiles(panda, capsys):
    """The bar cannot move while the first batch compiles: its postfix says what is happening."""
    from fabrax.bench.methods import Solution
    from fabrax.bench.runner import run
    from fabrax.problems.generators import demo_problem

    base = demo_problem(panda)
    problems = [dataclasses.replace(base, name=f"demo/{k}") for k in range(4)]

    class Straight:
        name, batch_size, dt = "straight", 2, 0.01

        def solve(self, robot, part):
            return [Solution(np.linspace(p.start_q, p.goal_q, 50), self.dt, 0.1) for p in part]

    run(Straight(), panda, problems, progress=True)
    assert "compiling and solving the first 2" in capsys.readouterr().err


def test_a_stopped_run_resumes_and_refuses_other_settings(panda, tmp_path):
    """The runner saves solutions after every batch; resume=True solves only what is missing and
    refuses a checkpoint written with other settings."""
    from fabrax.bench.methods import Solution
    from fabrax.bench.runner import CheckpointMismatch, run
    from fabrax.problems.generators import demo_problem

    base = demo_problem(panda)
    problems = [dataclasses.replace(base, name=f"demo/{k}") for k in range(4)]

    class Counting:
        name, batch_size, dt = "straight", 2, 0.01

        def __init__(self, stop_after=None):
            self.solved, self.stop_after = [], stop_after

        def solve(self, robot, part):
            if self.stop_after is not None and len(self.solved) >= self.stop_after:
                raise KeyboardInterrupt  # the run is stopped mid-way
            self.solved += [p.name for p in part]
            return [Solution(np.linspace(p.start_q, p.goal_q, 50), self.dt, 0.1) for p in part]

    ckpt, settings = tmp_path / "solutions.pkl", {"method": "straight", "seed": 0}
    with pytest.raises(KeyboardInterrupt):
        run(Counting(stop_after=2), panda, problems, progress=False, checkpoint=ckpt, settings=settings, save_every_s=0.0)
    again = Counting()
    rows = run(again, panda, problems, progress=False, checkpoint=ckpt, settings=settings, resume=True)
    assert again.solved == ["demo/2", "demo/3"]  # the first batch came from the checkpoint
    assert [r["problem"] for r in rows] == [p.name for p in problems] and all(r["reached"] for r in rows)
    with pytest.raises(CheckpointMismatch, match="seed"):
        run(Counting(), panda, problems, progress=False, checkpoint=ckpt, settings={**settings, "seed": 1}, resume=True)


def test_bench_table_merge_adds_runs_and_replaces_same_named_methods():
    """experiments/bench_table.py --merge: one new run's methods join a table without rerunning the others."""
    spec = importlib.util.spec_from_file_location("bench_table", Path(__file__).parents[1] / "experiments" / "bench_table.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    old = {"runs": {"a": 1}, "classes": {"box": {"gf": {"x": 1}, "gfcs": {"x": 2}}}}
    new = {"runs": {"b": 2}, "classes": {"box": {"gfcs": {"x": 3}, "gfcs_hand": {"x": 4}}, "cage": {"gfcs_hand": {"x": 5}}}}
    out = script.merge(old, new)
    assert out["classes"] == {"box": {"gf": {"x": 1}, "gfcs": {"x": 3}, "gfcs_hand": {"x": 4}}, "cage": {"gfcs_hand": {"x": 5}}}
    assert out["runs"] == {"a": 1, "b": 2} and old["classes"]["box"]["gfcs"] == {"x": 2}  # the old table is not changed
