"""The VAMP baseline: scenes reach VAMP as the same primitives, its paths are judged by our checker."""

import dataclasses
import json

import jaxlie
import numpy as np
import pytest

from fabrax.scene import from_dict

vamp = pytest.importorskip("vamp", reason="VAMP is not installed (pip install -e '.[vamp]')")


def test_environment_holds_the_scene_primitives():
    from fabrax.bench.vamp import environment

    q = np.array([0.9, 0.2, -0.3, 0.25]) / np.linalg.norm([0.9, 0.2, -0.3, 0.25])
    scene = from_dict(
        {
            "obstacles": [
                {"type": "cuboid", "center": [0.5, 0.1, 0.3], "quat_wxyz": q.tolist(), "size": [0.2, 0.4, 0.6]},
                {"type": "cylinder", "center": [0.3, -0.2, 0.5], "quat_wxyz": q.tolist(), "radius": 0.05, "length": 0.3},
                {"type": "sphere", "center": [0.0, 0.5, 0.5], "radius": 0.1},
            ]
        }
    ).pad(cuboids=4, cylinders=2, spheres=3)  # padded slots are not obstacles
    rot = np.asarray(jaxlie.SO3(q).as_matrix())
    env = environment(scene, padding=0.01)
    (c,) = env.cuboids
    axes = np.array([[c.axis_1_x, c.axis_1_y, c.axis_1_z], [c.axis_2_x, c.axis_2_y, c.axis_2_z], [c.axis_3_x, c.axis_3_y, c.axis_3_z]])
    np.testing.assert_allclose(axes, rot.T, atol=1e-6)  # VAMP's box axes are the columns of our rotation
    np.testing.assert_allclose([c.x, c.y, c.z], [0.5, 0.1, 0.3], atol=1e-6)
    np.testing.assert_allclose([c.axis_1_r, c.axis_2_r, c.axis_3_r], [0.11, 0.21, 0.31], atol=1e-6)
    (y,) = env.capsules
    ends = np.array([0.3, -0.2, 0.5]) + np.outer([1.0, -1.0], 0.16 * rot[:, 2])
    np.testing.assert_allclose([[y.x1, y.y1, y.z1], [y.x2, y.y2, y.z2]], ends, atol=1e-6)
    assert y.r == pytest.approx(0.06)
    (s,) = env.spheres
    assert [s.x, s.y, s.z, s.r] == pytest.approx([0.0, 0.5, 0.5, 0.11])


def test_a_robot_vamp_does_not_model_is_refused(panda):
    from fabrax.bench.vamp import robot_module

    assert robot_module(panda) is vamp.panda
    with pytest.raises(ValueError, match="VAMP has no model of robot 'arm7'"):
        robot_module(dataclasses.replace(panda, name="arm7"))
    with pytest.raises(ValueError, match="joints"):
        robot_module(dataclasses.replace(panda, joint_names=tuple(f"j{k}" for k in range(7))))


def test_vamp_rrtc_through_the_cli(tmp_path):
    from fabrax.bench.cli import main

    out = tmp_path / "vamp"
    assert main(["method=vamp_rrtc", "problems=mbm_like", "classes=[cage]", "limit=3", f"out={out}", "progress=false"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert len(rows) == 3
    for row in rows:
        assert row["method"] == "vamp_rrtc" and row["valid_problem"]
        if row["reached"]:  # a found path is projected onto our limits, retimed and re-checked by our checker
            assert row["limits_ok"] and row["duration_s"] > 0 and row["plan_time_s"] > 0
