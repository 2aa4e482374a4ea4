"""Property-based tests of the scene and problem loaders (hypothesis): a malformed input raises a
ValueError naming the field (and, for files, the file); an accepted input is never silently altered."""

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fabrax import scene as sc
from fabrax.problems.mbm import parse_scene

# Values a user might put in any field: numbers, wrong-length lists, strings, None, NaN, mappings.
finite = st.floats(-2.0, 2.0, allow_nan=False)
junk = st.one_of(
    st.none(),
    st.booleans(),
    st.text(max_size=4),
    st.floats(allow_nan=True, allow_infinity=True),
    st.lists(st.one_of(finite, st.text(max_size=2), st.none()), max_size=5),
    st.dictionaries(st.text(max_size=3), finite, max_size=2),
)
VALID = {
    "cuboid": {"type": "cuboid", "center": [0.4, 0.1, 0.3], "quat_wxyz": [1.0, 0.0, 0.0, 0.0], "size": [0.2, 0.1, 0.3]},
    "cylinder": {"type": "cylinder", "center": [0.1, 0.4, 0.2], "quat_wxyz": [0.0, 1.0, 0.0, 0.0], "radius": 0.05, "length": 0.3},
    "sphere": {"type": "sphere", "center": [0.3, -0.2, 0.5], "radius": 0.1},
}
FIELDS = sorted({k for v in VALID.values() for k in v} | {"half_extents", "quat", "quat_xyzw", "name", "colour"})
SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def obstacles(draw):
    """A valid obstacle with some fields replaced, added or removed."""
    obs = dict(VALID[draw(st.sampled_from(sorted(VALID)))])
    for key in draw(st.lists(st.sampled_from(FIELDS), max_size=3)):
        action = draw(st.sampled_from(["set", "drop"]))
        if action == "drop":
            obs.pop(key, None)
        else:
            obs[key] = draw(junk)
    return obs


def _expected(obs: dict) -> dict:
    """What an accepted obstacle must become: its own numbers."""
    out = {"center": np.asarray(obs["center"], float)}
    if obs["type"] == "cuboid":
        out["half"] = np.asarray(obs["half_extents"], float) if "half_extents" in obs else 0.5 * np.asarray(obs["size"], float)
    else:
        out["radius"] = float(obs["radius"])
    return out


@SETTINGS
@given(st.lists(obstacles(), min_size=1, max_size=3))
def test_scene_dict_is_refused_by_field_or_kept_exactly(obs_list):
    try:
        scene = sc.from_dict({"obstacles": obs_list})
    except ValueError as e:
        assert str(e).startswith("obstacles") and "\n" not in str(e)
        return
    got = sc.to_dict(scene)["obstacles"]
    by_type = {t: [o for o in obs_list if o["type"] == t] for t in VALID}
    got_by_type = {t: [o for o in got if o["type"] == t] for t in VALID}
    for t in VALID:
        assert len(by_type[t]) == len(got_by_type[t])
        for given_obs, parsed in zip(by_type[t], got_by_type[t]):
            want = _expected(given_obs)
            assert np.allclose(parsed["center"], want["center"], atol=1e-6)
            if t == "cuboid":
                assert np.allclose(np.asarray(parsed["size"]) / 2, want["half"], atol=1e-6)
            else:
                assert np.isclose(parsed["radius"], want["radius"], atol=1e-6)


MOVEIT = {
    "world": {
        "collision_objects": [
            {
                "id": "shelf",
                "primitives": [{"type": "box", "dimensions": [0.2, 0.3, 0.4]}, {"type": "cylinder", "dimensions": [0.14, 0.03]}],
                "primitive_poses": [
                    {"position": [0.5, 0.0, 0.3], "orientation": [0, 0, 0, 1]},
                    {"position": [0.4, 0.2, 0.3], "orientation": [0, 0, 0, 1]},
                ],
            }
        ]
    }
}


@st.composite
def moveit_scenes(draw):
    """The MoveIt scene above with one of its nested fields replaced or removed."""
    data = yaml.safe_load(yaml.safe_dump(MOVEIT))
    obj = data["world"]["collision_objects"][0]
    i = draw(st.integers(0, 1))
    target = draw(st.sampled_from(["primitives", "primitive_poses", "dimensions", "type", "position", "orientation", "object"]))
    value = draw(junk)
    drop = draw(st.booleans())
    holder, key = {
        "primitives": (obj, "primitives"),
        "primitive_poses": (obj, "primitive_poses"),
        "dimensions": (obj["primitives"][i], "dimensions"),
        "type": (obj["primitives"][i], "type"),
        "position": (obj["primitive_poses"][i], "position"),
        "orientation": (obj["primitive_poses"][i], "orientation"),
        "object": (data["world"]["collision_objects"], 0),
    }[target]
    if drop and isinstance(holder, dict):
        holder.pop(key)
    else:
        holder[key] = value
    return yaml.safe_dump(data)


@SETTINGS
@given(moveit_scenes())
def test_moveit_scene_is_refused_with_its_file_or_parsed_whole(text):
    try:
        parsed = parse_scene(text, where="scene0001.yaml")
    except ValueError as e:
        assert "scene0001.yaml" in str(e) and "\n" not in str(e)
        return
    data = yaml.safe_load(text)
    n = sum(len(o.get("primitives") or []) for o in data["world"]["collision_objects"])
    assert len(parsed["obstacles"]) == n
    sc.from_dict(parsed)  # what the parser accepts, the scene builder accepts


def test_valid_moveit_scene_parses_to_its_numbers():
    obs = parse_scene(yaml.safe_dump(MOVEIT), "s.yaml")["obstacles"]
    assert obs[0]["size"] == [0.2, 0.3, 0.4] and obs[1]["length"] == 0.14 and obs[1]["radius"] == 0.03


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"type": "cuboid", "center": [0, 0, 0], "size": [0.1] * 3, "quat_xyzw": [0, 0, 0, 1]}, r"unknown keys \['quat_xyzw'\]"),
        ({"type": "cuboid", "center": [0, 0, 0], "size": [0.1] * 3, "half_extents": [0.05] * 3}, "not both"),
        ({"type": "sphere", "center": [0, 0, 0], "radius": [0.1, 0.2]}, r"radius: expected one number"),
    ],
)
def test_obstacle_field_errors(bad, message):
    with pytest.raises(ValueError, match=message):
        sc.from_dict({"obstacles": [bad]})


def test_empty_obstacles_in_yaml_is_a_clear_error():
    with pytest.raises(ValueError, match="obstacles: expected a list"):
        sc.from_dict(yaml.safe_load("obstacles:\n"))
    assert sc.from_dict(yaml.safe_load("obstacles: []\n")).cuboids.center.shape == (0, 3)
