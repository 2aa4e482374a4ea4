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

from fabrax.problems.problem import Problem, flag
from fabrax.robot.robot import Robot
from fabrax.scene import from_dict

CLASSES = ("bookshelf_small", "bookshelf_tall", "bookshelf_thin", "box", "cage", "table_pick", "table_under_pick")
ARCHIVE = "mbm_panda_problems.tar.bz2"
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


def parse_scene(text: str, where: str = "scene") -> dict:
    """A MoveIt PlanningScene YAML as a fabrax scene dict."""
    try:
        data = yaml.safe_load(text)
        objects = data["world"]["collision_objects"] or []
    except (yaml.YAMLError, KeyError, TypeError) as e:
        raise ValueError(f"malformed MoveIt scene {where}: {e}") from e
    obstacles = []
    for obj in objects:
        oid = obj.get("id", "?")
        base = None
        if "pose" in obj:
            base = (obj["pose"]["position"], _quat_xyzw_to_wxyz(obj["pose"]["orientation"]))
        for prim, pose in zip(obj.get("primitives", []), obj.get("primitive_poses", []), strict=True):
            pos, quat = pose["position"], _quat_xyzw_to_wxyz(pose["orientation"])
            if base is not None:
                pos, quat = _compose(base, (pos, quat))
            dims = [float(v) for v in prim["dimensions"]]
            kind = prim["type"]
            if kind == "box":
                obstacles.append({"type": "cuboid", "name": oid, "center": list(pos), "quat_wxyz": quat, "size": dims})
            elif kind == "cylinder":
                obstacles.append({"type": "cylinder", "name": oid, "center": list(pos), "quat_wxyz": quat, "length": dims[0], "radius": dims[1]})
            elif kind == "sphere":
                obstacles.append({"type": "sphere", "name": oid, "center": list(pos), "radius": dims[0]})
            else:
                raise ValueError(f"{where}: object '{oid}' has unsupported primitive '{kind}'")
    return {"obstacles": obstacles}


def parse_request(text: str, joint_names: tuple[str, ...], where: str = "request") -> tuple[np.ndarray, np.ndarray]:
    """(start_q, goal_q) of a MoveIt MotionPlanRequest with joint-space goal constraints."""
    try:
        data = yaml.safe_load(text)
        state = data["start_state"]["joint_state"]
        start = dict(zip(state["name"], state["position"], strict=True))
        goal = {c["joint_name"]: c["position"] for c in data["goal_constraints"][0]["joint_constraints"]}
        return np.array([start[n] for n in joint_names], float), np.array([goal[n] for n in joint_names], float)
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
    """MBM Panda problems as `Problem`s (joint goals), flagged (`valid`, `reason`) when the start or
    goal is outside the limits or in collision for this robot's collision model.

    classes: subset of `CLASSES` (default all); split: train (1-50), test (51-100) or all;
    limit: at most this many problems per class.
    """
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
            scene = from_dict(parse_scene(files[scene_key], scene_key))
            start, goal = parse_request(files[request_key], robot.joint_names, request_key)
            p = Problem(start_q=start, scene=scene, goal_q=goal, name=f"{cls}/{i:04d}", kind=cls)
            problems.append(flag(robot, p))
    return problems


def problem_index(name: str) -> int:
    """The MBM index (1-100) in a problem name like 'box/0051'."""
    m = re.search(r"(\d+)$", name)
    if not m:
        raise ValueError(f"no index in problem name '{name}'")
    return int(m.group(1))
