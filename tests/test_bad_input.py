"""Bad input fails before any work with one line naming the key or path; errors and invalid problems
are counted in summaries; results.json is standard JSON; a run's output folder is its own."""

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fabrax import config
from fabrax.bench.outdir import LOCK, OutDirError, claim
from fabrax.bench.runner import errors, strict_json, summary_table, write
from fabrax.gains import check_config
from fabrax.problems.mbm import parse_request

PANDA_FABRIC = config.load("fabric", "panda")
GAINS = sorted(
    (term, key) for term, spec in PANDA_FABRIC["terms"].items() for key, v in spec.items() if key != "type" and not isinstance(v, (list, str))
)
SETTINGS = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
bad_gain = st.one_of(
    st.floats(max_value=-1e-9, allow_nan=False, allow_infinity=True),
    st.just(math.nan),
    st.just(math.inf),
    st.text(max_size=4),
    st.booleans(),
    st.none(),
    st.lists(st.floats(0, 1), min_size=1, max_size=2),
)


def _with(term: str, key: str, value) -> dict:
    cfg = json.loads(json.dumps(PANDA_FABRIC))
    cfg["terms"][term][key] = value
    return cfg


@SETTINGS
@given(st.sampled_from(GAINS), bad_gain)
def test_a_bad_fabric_gain_is_refused_naming_its_key(gain, value):
    term, key = gain
    with pytest.raises(ValueError, match=rf"fabric\.terms\.{term}\.{key} must be"):
        check_config(_with(term, key, value))


@SETTINGS
@given(st.sampled_from(GAINS), st.floats(0.0, 1e3, allow_nan=False))
def test_a_finite_non_negative_gain_is_accepted(gain, value):
    check_config(_with(*gain, value))


@pytest.mark.parametrize(
    "override, message",
    [
        ("fabric.terms.obstacles.k_barrier=-0.5", r"fabric\.terms\.obstacles\.k_barrier must be a finite number >= 0, got -0.5"),
        ("fabric.terms.ee.k_force=-1", r"fabric\.terms\.ee\.k_force must be"),
        ("fabric.terms.damping.b=-1", r"fabric\.terms\.damping\.b must be"),
        ("fabric.terms.obstacles.k_barrier=nan", r"fabric\.terms\.obstacles\.k_barrier must be a finite number"),
        ("fabric.terms.obstacles.k_barrier=inf", r"fabric\.terms\.obstacles\.k_barrier must be a finite number"),
        ("fabric.terms.obstacles.k_barrier=abc", r"fabric\.terms\.obstacles\.k_barrier must be a number, got 'abc'"),
        ("fabric.goal_tolerance.joint=0", r"fabric\.goal_tolerance\.joint must be a finite number > 0"),
    ],
)
def test_bench_cli_refuses_a_bad_gain_before_any_work(tmp_path, override, message):
    from fabrax.bench.cli import main

    out = tmp_path / "out"
    t0 = time.perf_counter()
    with pytest.raises(SystemExit, match=message):
        main(["method=gf", "problems=mbm_like", "classes=[box]", "limit=1", override, f"out={out}", "progress=false"])
    assert time.perf_counter() - t0 < 60  # nothing was solved (a solve compiles for longer)
    assert not out.exists()  # nothing was written


def test_out_must_be_a_writable_folder_before_any_work(tmp_path):
    from fabrax.bench.cli import main

    afile = tmp_path / "taken"
    afile.write_text("x")
    args = ["method=gf", "problems=mbm_like", "classes=[box]", "limit=1", "progress=false"]
    with pytest.raises(SystemExit, match=r"out=.*taken is a file, not a folder"):
        main(args + [f"out={afile}"])
    with pytest.raises(SystemExit, match=r"out=.*taken/sub is not writable"):
        main(args + [f"out={afile / 'sub'}"])


def test_a_folder_is_held_by_one_run_and_a_finished_run_is_kept(tmp_path):
    out = tmp_path / "run"
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        out.mkdir()
        (out / LOCK).write_text(str(sleeper.pid))  # another live run holds it
        with pytest.raises(OutDirError, match=rf"being written by another run \(pid {sleeper.pid}\)"):
            with claim(out):
                pass
    finally:
        sleeper.kill()
        sleeper.wait()
    with claim(out):  # the dead run's lock is taken over
        assert int((out / LOCK).read_text()) == os.getpid()
        with pytest.raises(OutDirError, match="another run"):  # a second claim while this one holds it
            with claim(out):
                pass
    assert not (out / LOCK).exists()
    (out / "results.json").write_text("{}")
    with pytest.raises(OutDirError, match=r"holds an earlier run \(results.json\).*resume=true"):
        with claim(out):
            pass
    with claim(out, resume=True):
        pass


segment = st.text(st.characters(whitelist_categories=("Ll", "Lu", "Nd"), whitelist_characters=" -_.é"), min_size=1, max_size=8).filter(
    lambda t: t not in (".", "..")
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    parts=st.lists(segment, min_size=1, max_size=3),
    blocker=st.one_of(st.none(), st.integers(0, 2)),
    prior=st.sampled_from([None, "results.json", "solutions.pkl", "live lock", "dead lock"]),
    resume=st.booleans(),
)
def test_claim_of_any_output_path_succeeds_or_refuses_in_one_line(tmp_path_factory, parts, blocker, prior, resume):
    """Property over output paths: a file anywhere on the path, a live run's lock, an earlier run's
    results (without resume) each give one OutDirError line naming out=; every other path is claimed,
    created, locked by this process while held and released after."""
    root = tmp_path_factory.mktemp("out")
    out = root.joinpath(*parts)
    blocked = blocker is not None and blocker < len(parts)
    if blocked:
        at = root.joinpath(*parts[: blocker + 1])
        at.parent.mkdir(parents=True, exist_ok=True)
        at.write_text("x")
    elif prior is not None:
        out.mkdir(parents=True)
        if prior in EARLIER_FILES:
            (out / prior).write_text("{}")
        else:
            (out / LOCK).write_text(str(os.getpid() if prior == "live lock" else DEAD_PID))
    refused = blocked or prior == "live lock" or (prior in EARLIER_FILES and not resume)
    try:
        with claim(out, resume=resume):
            assert not refused and out.is_dir() and int((out / LOCK).read_text()) == os.getpid()
    except OutDirError as e:
        assert refused, str(e)
        assert str(e).startswith(f"out={root}") and "\n" not in str(e)
    else:
        assert not (out / LOCK).exists()


EARLIER_FILES = ("results.json", "solutions.pkl")
DEAD_PID = int(Path("/proc/sys/kernel/pid_max").read_text()) if Path("/proc/sys/kernel/pid_max").exists() else 2**22


def test_two_runs_into_one_folder(tmp_path):
    """The second `fabrax bench` into a folder that a first run finished is refused; the first run's
    results stay."""
    from fabrax.bench.cli import main

    out = tmp_path / "D"
    base = ["method=gf", "problems=mbm_like", "limit=1", "t_max=1.0", f"out={out}", "progress=false"]
    assert main(base + ["classes=[box]"]) == 0
    first = (out / "results.json").read_text()
    with pytest.raises(SystemExit, match="holds an earlier run"):
        main(base + ["classes=[cage]"])
    assert (out / "results.json").read_text() == first


def test_results_json_is_standard_json_with_null_for_nan(tmp_path):
    row = {"problem": "p", "class": "c", "method": "m", "valid_problem": True, "invalid_reason": "", "success": False, "collision": False}
    row |= {"joint_error": float("nan"), "ee_length": np.float32(np.inf), "info": {"cost": np.float64(np.nan), "z": np.array([1.0, np.nan])}}
    write([row], tmp_path, {"note": float("nan")})
    text = (tmp_path / "results.json").read_text()

    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")

    data = json.loads(text, parse_constant=refuse)  # what JavaScript's JSON.parse and jq accept
    (back,) = data["rows"]
    assert back["joint_error"] is None and back["ee_length"] is None and back["info"] == {"cost": None, "z": [1.0, None]}
    assert data["meta"]["note"] is None
    assert strict_json({"a": (1, 2.5, "x", True)}) == {"a": [1, 2.5, "x", True]}


def test_errors_and_invalid_problems_are_counted_with_their_reasons():
    ok = {"class": "box", "method": "gf", "valid_problem": True, "invalid_reason": "", "success": True, "collision": False, "info": {}}
    bad = ok | {"problem": "b", "success": False, "info": {"error": "b: has a pose goal"}}
    invalid = ok | {"problem": "c", "valid_problem": False, "invalid_reason": "c.start_q is in collision with the scene"}
    rows = [ok | {"problem": "a"}, bad, bad | {"problem": "b2", "info": {"error": "b: has a pose goal"}}, invalid]
    assert [r["problem"] for r in errors(rows)] == ["b", "b2"]
    md = summary_table([r | {m: 0.0 for m in ("ee_length", "cspace_length", "ee_ldj", "cspace_ldj", "plan_time_s", "duration_s")} for r in rows])
    assert "**2 errors (the method raised; counted as failures)**" in md and "- 2 x gf: b: has a pose goal" in md
    assert "**1 invalid problems (not run)**" in md and "c.start_q is in collision" in md


def test_a_run_where_every_problem_errored_exits_non_zero(tmp_path):
    """GFCS plans toward joint goals; MπNets-like problems without ik_goals have pose goals, so it
    refuses every one: the run writes its rows and exits non-zero, naming the error."""
    from fabrax.bench.cli import main

    out = tmp_path / "gfcs"
    args = ["method=gfcs", "problems=mpinets_like", "classes=[cubby]", "limit=1", f"out={out}", "progress=false"]
    with pytest.raises(SystemExit, match=r"every problem failed with an error \(1\), e\.g\. .*pose goal"):
        main(args)
    assert "errors (the method raised" in (out / "summary.md").read_text()
    (row,) = json.loads((out / "results.json").read_text())["rows"]
    assert "pose goal" in row["info"]["error"] and not row["success"]


REQUEST = """
start_state:
  joint_state:
    name: [panda_joint1, panda_joint2, panda_joint3, panda_joint4, panda_joint5, panda_joint6, panda_joint7]
    position: [0, -0.785, 0, -2.356, 0, 1.571, 0.785]
goal_constraints:
  - position_constraints:
      - link_name: {link}
        constraint_region:
          primitive_poses: [{{position: {{x: {x}, y: 0.1, z: 0.4}}, orientation: {{x: 0, y: 0, z: 0, w: 1}}}}]
    orientation_constraints:
      - link_name: panda_hand
        orientation: {{x: 1.0, y: 0.0, z: 0.0, w: 0.0}}
"""


def test_moveit_pose_goal_requests_parse_and_out_of_reach_goals_are_invalid(panda):
    from fabrax.problems.generators import flag_unreachable
    from fabrax.problems.problem import Problem, flag
    from fabrax.scene import empty

    names = tuple(panda.joint_names)
    start, goal_q, pose = parse_request(REQUEST.format(link="panda_hand", x=0.5), names)
    assert goal_q is None and np.allclose(pose[0], [0.5, 0.1, 0.4]) and np.allclose(pose[1], [0.0, 1.0, 0.0, 0.0])  # wxyz
    with pytest.raises(ValueError, match="request.*link 'panda_link8'"):
        parse_request(REQUEST.format(link="panda_link8", x=0.5), names)
    with pytest.raises(ValueError, match="neither joint_constraints nor position_constraints"):
        parse_request(REQUEST.split("goal_constraints:")[0] + "goal_constraints: [{}]\n", names)
    far = flag(panda, Problem(start_q=start, scene=empty(), goal_pose=(np.array([5.0, 0.1, 0.4]), pose[1]), name="far"))
    assert not far.valid and "out of its reach" in far.reason
    near = flag(panda, Problem(start_q=start, scene=empty(), goal_pose=pose, name="near"))
    assert near.valid, near.reason
    assert flag_unreachable(panda, near, "panda_hand").valid  # IK reaches it
    inside = flag(panda, Problem(start_q=start, scene=empty(), goal_pose=(np.array([0.0, 0.0, 0.1]), pose[1]), name="inside"))
    assert inside.valid  # within reach: the distance check passes it
    inside = flag_unreachable(panda, inside, "panda_hand")  # the hand would sit inside the arm's own base
    assert not inside.valid and "inside.goal_pose: no collision-free IK solution" in inside.reason


def test_a_malformed_mbm_request_is_one_invalid_problem(tmp_path, panda):
    """Edited MotionBenchMaker files: the problem whose request is malformed is reported invalid, the
    others load."""
    import tarfile

    from fabrax.problems.mbm import ARCHIVE, load_mbm

    data = os.environ.get("FABRAX_DATA")
    if not data or not (Path(data) / ARCHIVE).exists():
        pytest.skip("needs FABRAX_DATA (the MotionBenchMaker problems)")
    root = tmp_path / "data" / "problems"
    with tarfile.open(Path(data) / ARCHIVE, "r:bz2") as tar:
        for m in tar.getmembers():
            if m.isfile() and "box_panda/" in m.name and any(f"{k}{i:04d}.yaml" in m.name for k in ("scene", "request") for i in (1, 2)):
                (root / "box_panda").mkdir(parents=True, exist_ok=True)
                (root / "box_panda" / Path(m.name).name).write_bytes(tar.extractfile(m).read())
    req = root / "box_panda" / "request0002.yaml"
    req.write_text(req.read_text().replace("joint_constraints", "joint_constraint_typo"))
    p1, p2 = load_mbm(panda, tmp_path / "data", ["box"], "train", limit=2)
    assert p1.valid and not p2.valid and "malformed MoveIt request box_panda/request0002.yaml" in p2.reason


def test_view_of_a_missing_run_is_one_line(capsys, tmp_path):
    from fabrax.viz import cli

    with pytest.raises(SystemExit) as e:
        cli.main(["results", str(tmp_path / "nope")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "nope is not a benchmark run directory (no results.json there)" in err and "Traceback" not in err


def test_a_port_probe_of_the_viewer_logs_no_traceback(caplog, free_port):
    """A connection that is not a browser's websocket (a port scan, a health check) closes quietly."""
    import logging
    import socket

    from fabrax.viz.app import Viewer

    port = free_port
    viewer = Viewer("panda", port=port)
    try:
        with caplog.at_level(logging.ERROR, logger="websockets.server"):
            for payload in (b"", b"garbage\r\n\r\n"):
                with socket.create_connection(("127.0.0.1", port), timeout=5) as c:
                    if payload:
                        c.sendall(payload)
                    try:
                        c.recv(64)
                    except OSError:
                        pass
            time.sleep(1.0)
        assert not [r for r in caplog.records if "handshake" in r.getMessage()]
    finally:
        viewer.close()
