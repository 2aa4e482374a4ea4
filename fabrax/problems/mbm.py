"""MotionBenchMaker (MBM) Panda problems from their original MoveIt YAML.

The data set (7 classes x 100) is read from `mbm_panda_problems.tar.bz2` (or an
extracted `problems/` folder) in the data folder given as an argument or by
`$FABRAX_DATA`. Each problem is a `sceneNNNN.yaml` (a MoveIt PlanningScene:
boxes with full dimensions, cylinders `[height, radius]` along local z,
quaternions xyzw, world = panda_link0) and a `requestNNNN.yaml` (start joint
state, joint-space goal constraints). Problems 1-50 of a class are the train
split (tuning, learning), 51-100 the test split (reports), as in gfcs_paper.
"""

from __future__ import annotations

import os
import re
import tarfile
from pathlib import Path

import numpy as np
import yaml

from fabrax.problems.generators import flag_unreachable
from fabrax.problems.problem import Problem, flag
from fabrax.robot.robot import Robot
from fabrax.scene import empty, from_dict

CLASSES = ("bookshelf_small", "bookshelf_tall", "bookshelf_thin", "box", "cage", "table_pick", "table_under_pick")
# the six classes of gfcs_paper Table I, in its order (table_pick is not among them)
TABLE_I_CLASSES = ("table_under_pick", "box", "bookshelf_tall", "cage", "bookshelf_thin", "bookshelf_small")
ARCHIVE = "mbm_panda_problems.tar.bz2"
MBM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))  # the arm every MotionBenchMaker request is posed for
SPLITS = {"train": range(1, 51), "test": range(51, 101), "all": range(1, 101)}


def data_dir(path: str | Path | None = None) -> Path:
    """The data folder: `path`, else $FABRAX_DATA; a ValueError says how to set it."""
    path = path or os.environ.get("FABRAX_DATA")
    if not path:
        raise ValueError("no data folder: pass data_dir or set FABRAX_DATA (e.g. export FABRAX_DATA=../shared/data)")
    path = Path(path).expanduser()
    if not path.is_dir():
        raise ValueError(f"data folder {path} does not exist")
    return path


def _quat_xyzw_to_wxyz(q) -> list[float]:
    x, y, z, w = (float(v) for v in q)
    return [w, x, y, z]


def _compose(pose_a, pose_b):
    """(position, quat wxyz) of pose_a * pose_b."""
    import jaxlie

    ta = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3(np.asarray(pose_a[1])), np.asarray(pose_a[0]))
    tb = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3(np.asarray(pose_b[1])), np.asarray(pose_b[0]))
    t = ta @ tb
    return np.asarray(t.translation()).tolist(), np.asarray(t.rotation().wxyz).tolist()


def _pose(pose, where: str) -> tuple[list[float], list[float]]:
    """(position, quat wxyz) of a MoveIt pose mapping."""
    try:
        pos = pose["position"]
        pos = [float(pos[k]) for k in ("x", "y", "z")] if isinstance(pos, dict) else [float(v) for v in pos]
        q = pose["orientation"]
        q = [q[k] for k in ("x", "y", "z", "w")] if isinstance(q, dict) else q
        quat = _quat_xyzw_to_wxyz(q)
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{where}: malformed pose {pose!r}") from e
    if len(pos) != 3:
        raise ValueError(f"{where}: position needs 3 numbers, got {pos!r}")
    if not np.all(np.isfinite(pos + quat)):
        raise ValueError(f"{where}: NaN or infinite pose {pose!r}")
    return pos, quat


_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's parser where PyYAML was built with it


def _load_yaml(text: str):
    """`yaml.safe_load` by libyaml's parser when available: the same safe constructor, ~10x faster
    on MotionBenchMaker's scene files, which are most of a class's loading time."""
    return yaml.load(text, Loader=_LOADER)  # noqa: S506 (a safe loader)


# MoveIt's shape_msgs/SolidPrimitive dimensions per type.
_DIMS = {"box": 3, "cylinder": 2, "sphere": 1}


def parse_scene(text: str, where: str = "scene") -> dict:
    """A MoveIt PlanningScene YAML as a fabrax scene dict; a malformed object raises one line naming `where` and the object."""
    try:
        data = _load_yaml(text)
        objects = data["world"]["collision_objects"] or []
    except (yaml.YAMLError, KeyError, TypeError) as e:
        raise ValueError(f"malformed MoveIt scene {where}: {e}") from e
    if not isinstance(objects, list):
        raise ValueError(f"{where}: world.collision_objects must be a list, got {objects!r}")
    obstacles = []
    for k, obj in enumerate(objects):
        if not isinstance(obj, dict):
            raise ValueError(f"{where}: collision_objects[{k}] is not a mapping")
        oid = obj.get("id", f"collision_objects[{k}]")
        at = f"{where}: object {oid!r}"
        for key in ("meshes", "planes"):
            if obj.get(key):
                raise ValueError(f"{at} has {key}, which fabrax scenes do not support (primitives only)")
        prims, poses = obj.get("primitives") or [], obj.get("primitive_poses") or []
        for key, value in (("primitives", prims), ("primitive_poses", poses)):
            if not isinstance(value, list):
                raise ValueError(f"{at}: {key} must be a list, got {value!r}")
        if len(prims) != len(poses):
            raise ValueError(f"{at} has {len(prims)} primitives but {len(poses)} primitive_poses")
        base = _pose(obj["pose"], at) if "pose" in obj else None
        for prim, pose in zip(prims, poses):
            if not isinstance(prim, dict) or "type" not in prim or "dimensions" not in prim:
                raise ValueError(f"{at}: a primitive needs 'type' and 'dimensions', got {prim!r}")
            kind = prim["type"]
            if not isinstance(kind, str) or kind not in _DIMS:
                raise ValueError(f"{at} has unsupported primitive {kind!r}")
            try:
                dims = [float(v) for v in prim["dimensions"]]
            except (TypeError, ValueError) as e:
                raise ValueError(f"{at}: {kind} dimensions are not numbers: {prim['dimensions']!r}") from e
            if len(dims) != _DIMS[kind] or not all(0 < d < np.inf for d in dims):
                raise ValueError(f"{at}: a {kind} needs {_DIMS[kind]} positive dimensions, got {dims}")
            pos, quat = _pose(pose, at)
            if base is not None:
                pos, quat = _compose(base, (pos, quat))
            if kind == "box":
                obstacles.append({"type": "cuboid", "name": oid, "center": list(pos), "quat_wxyz": quat, "size": dims})
            elif kind == "cylinder":
                obstacles.append({"type": "cylinder", "name": oid, "center": list(pos), "quat_wxyz": quat, "length": dims[0], "radius": dims[1]})
            else:
                obstacles.append({"type": "sphere", "name": oid, "center": list(pos), "radius": dims[0]})
    return {"obstacles": obstacles}


def _xyz(v) -> list[float]:
    """A MoveIt vector or point: a mapping {x, y, z} or a list."""
    return [float(v[k]) for k in ("x", "y", "z")] if isinstance(v, dict) else [float(x) for x in v]


def parse_request(
    text: str, joint_names: tuple[str, ...], where: str = "request", frame: str = "panda_hand"
) -> tuple[np.ndarray, np.ndarray | None, tuple[np.ndarray, np.ndarray] | None]:
    """(start_q, goal_q, goal_pose) of a MoveIt MotionPlanRequest: a joint-space goal
    (`joint_constraints`), or a pose goal of `frame` (a position constraint's region centre plus its
    `target_point_offset`, and an orientation constraint, xyzw; goal_pose is (position, wxyz))."""
    try:
        data = _load_yaml(text)
        state = data["start_state"]["joint_state"]
        start = dict(zip(state["name"], state["position"], strict=True))
        start_q = np.array([start[n] for n in joint_names], float)
        goal = data["goal_constraints"][0]
        if goal.get("joint_constraints"):
            values = {c["joint_name"]: c["position"] for c in goal["joint_constraints"]}
            return start_q, np.array([values[n] for n in joint_names], float), None
        if not goal.get("position_constraints") or not goal.get("orientation_constraints"):
            raise ValueError("goal_constraints[0] has neither joint_constraints nor position_constraints with orientation_constraints")
        pos_c, ori_c = goal["position_constraints"][0], goal["orientation_constraints"][0]
        for c in (pos_c, ori_c):
            if c.get("link_name", frame) != frame:
                raise ValueError(f"the pose goal is for link '{c['link_name']}'; the benchmark's goal frame is '{frame}'")
        centre = np.array(_xyz(pos_c["constraint_region"]["primitive_poses"][0]["position"]))
        offset = np.array(_xyz(pos_c.get("target_point_offset") or [0.0, 0.0, 0.0]))
        if np.any(offset):
            raise ValueError("a position constraint with a target_point_offset is not supported")
        o = ori_c["orientation"]
        x, y, z, w = (float(o[k]) for k in ("x", "y", "z", "w")) if isinstance(o, dict) else (float(v) for v in o)
        return start_q, None, (centre, np.array([w, x, y, z]))
    except (yaml.YAMLError, KeyError, TypeError, IndexError, ValueError) as e:
        raise ValueError(f"malformed MoveIt request {where}: {e}") from e


def _read_files(root: Path) -> dict[str, str]:
    """Problem files by their path below `problems/`, from the archive or a folder."""
    archive = root / ARCHIVE
    files = {}
    if archive.exists():
        with tarfile.open(archive, "r:bz2") as tar:
            for m in tar.getmembers():
                if m.isfile() and m.name.endswith(".yaml"):
                    files[m.name.split("problems/", 1)[-1]] = tar.extractfile(m).read().decode()
        return files
    folder = root / "problems"
    if folder.is_dir():
        return {str(p.relative_to(folder)): p.read_text() for p in folder.rglob("*.yaml")}
    raise ValueError(f"neither {archive} nor {folder} exists")


def load_mbm(robot: Robot, path=None, classes=None, split: str = "test", limit: int | None = None) -> list[Problem]:
    """MBM Panda problems as `Problem`s (joint goals, or pose goals of panda_hand where a request has
    them), flagged (`valid`, `reason`) when the start or goal is outside the limits, in collision for
    this robot's collision model, out of its reach or without a collision-free IK solution, or when its files are malformed (that problem
    alone; the others load).

    classes: subset of `CLASSES` (default all); split: train (1-50), test (51-100) or all;
    limit: at most this many problems per class.
    """
    if tuple(robot.joint_names) != MBM_JOINTS:
        raise ValueError(f"MotionBenchMaker's problems are posed for the Panda; robot '{robot.name}' cannot run them (use generated problems)")
    if split not in SPLITS:
        raise ValueError(f"split must be one of {sorted(SPLITS)}, got '{split}'")
    classes = list(classes or CLASSES)
    unknown = [c for c in classes if c not in CLASSES]
    if unknown:
        raise ValueError(f"unknown MBM classes {unknown} (classes: {', '.join(CLASSES)})")
    files = _read_files(data_dir(path))
    problems = []
    for cls in classes:
        indices = list(SPLITS[split])[: limit or None]
        for i in indices:
            scene_key, request_key = f"{cls}_panda/scene{i:04d}.yaml", f"{cls}_panda/request{i:04d}.yaml"
            if scene_key not in files or request_key not in files:
                raise ValueError(f"MBM data is missing {scene_key} or {request_key}")
            name = f"{cls}/{i:04d}"
            try:
                scene = from_dict(parse_scene(files[scene_key], scene_key))
                start, goal, pose = parse_request(files[request_key], robot.joint_names, request_key)
            except ValueError as e:  # this problem alone is reported invalid; the others go on
                problems.append(Problem(np.zeros(robot.dof), empty(), name=name, kind=cls, valid=False, reason=str(e)))
                continue
            p = Problem(start_q=start, scene=scene, goal_q=goal, goal_pose=pose, name=name, kind=cls)
            problems.append(flag_unreachable(robot, flag(robot, p), "panda_hand"))
    return problems


def problem_index(name: str) -> int:
    """The MBM index (1-100) in a problem name like 'box/0051'."""
    m = re.search(r"(\d+)$", name)
    if not m:
        raise ValueError(f"no index in problem name '{name}'")
    return int(m.group(1))
