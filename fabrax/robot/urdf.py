"""URDF parsing into a kinematic tree of moving frames.

The tree keeps only what forward kinematics needs: one frame per active joint
(revolute, continuous or prismatic), its parent frame, the constant transform
from the parent frame to the joint at q = 0 (fixed joints and held joints such
as gripper fingers are folded in), and every link's constant offset from the
frame that carries it. Any URDF arm parses; nothing here knows about the Panda.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import os
from pathlib import Path

import numpy as np
import yourdfpy

REVOLUTE, PRISMATIC = 0, 1
_MOVABLE = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC}


@dataclasses.dataclass(frozen=True)
class CollisionGeometry:
    """One <collision> element: kind in {mesh, box, cylinder, sphere}."""

    link: str
    kind: str
    origin: np.ndarray  # 4x4, link frame -> geometry frame
    size: tuple  # box: full extents; cylinder: (radius, length); sphere: (radius,)
    mesh_path: str | None = None
    mesh_scale: tuple = (1.0, 1.0, 1.0)


@dataclasses.dataclass(frozen=True)
class KinematicTree:
    """Static description of a robot's kinematics (numpy, hashable by identity)."""

    name: str
    joint_names: tuple[str, ...]  # active joints, in URDF order
    joint_type: np.ndarray  # (n,) REVOLUTE or PRISMATIC
    joint_axis: np.ndarray  # (n, 3) unit axes in the joint frame
    joint_parent: np.ndarray  # (n,) parent frame index, -1 = base
    joint_origin: np.ndarray  # (n, 4, 4) parent frame -> joint frame at q = 0
    lower: np.ndarray  # (n,)
    upper: np.ndarray  # (n,)
    velocity: np.ndarray  # (n,)
    effort: np.ndarray  # (n,) torque (force) limits, inf where the URDF gives none
    link_names: tuple[str, ...]
    link_frame: np.ndarray  # (L,) frame index carrying the link, -1 = base
    link_offset: np.ndarray  # (L, 4, 4) frame -> link
    link_parent: np.ndarray  # (L,) parent link index, -1 = root
    collisions: tuple[CollisionGeometry, ...]
    held: dict  # joint name -> value for movable joints held fixed
    link_mass: np.ndarray | None = None  # (L,) <inertial> mass, 0 where a link has none
    link_com: np.ndarray | None = None  # (L, 3) centre of mass in the link frame
    link_inertia: np.ndarray | None = None  # (L, 3, 3) inertia about the centre of mass, link-frame axes

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def link_index(self, name: str) -> int:
        if name not in self.link_names:
            raise ValueError(f"link '{name}' is not in robot '{self.name}' (links: {', '.join(self.link_names)})")
        return self.link_names.index(name)


def _rpy_xyz(origin: np.ndarray | None) -> np.ndarray:
    return np.eye(4) if origin is None else np.asarray(origin, dtype=np.float64)


def _motion(kind: int, axis: np.ndarray, value: float) -> np.ndarray:
    """Homogeneous transform of a joint displaced by `value` along/about `axis`."""
    t = np.eye(4)
    if kind == PRISMATIC:
        t[:3, 3] = axis * value
    else:
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        t[:3, :3] = np.eye(3) + np.sin(value) * k + (1 - np.cos(value)) * k @ k
    return t


def package_roots() -> list[Path]:
    """Directories that hold ROS packages: ROS_PACKAGE_PATH plus pip-installed cmeel shares."""
    roots = [Path(p) for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
    try:
        for f in importlib.metadata.files("example-robot-data") or []:
            if str(f).endswith("share/example-robot-data/package.xml"):
                roots.append(Path(f.locate()).parent.parent)
                break
    except importlib.metadata.PackageNotFoundError:
        pass
    return roots


def resolve_uri(uri: str, urdf_dir: Path) -> str:
    """Map a URDF resource (package://, file://, relative or absolute path) to a file."""
    if uri.startswith("file://"):
        uri = uri[len("file://") :]
    if uri.startswith("package://"):
        rest = uri[len("package://") :]
        for root in package_roots() + [urdf_dir.parent.parent, urdf_dir.parent]:
            for candidate in (root / rest, root / rest.split("/", 1)[-1]):
                if candidate.exists():
                    return str(candidate)
        raise ValueError(f"cannot resolve '{uri}': set ROS_PACKAGE_PATH to the folder holding its package")
    path = Path(uri)
    return str(path if path.is_absolute() else urdf_dir / path)


def parse_urdf(path: str | Path, active_joints: list[str] | None = None, held: dict | None = None) -> KinematicTree:
    """Parse a URDF into a `KinematicTree`.

    Args:
      path: URDF file.
      active_joints: movable joints that make up q, in this order (default: every
        movable joint that is not a mimic, not mimicked (a gripper) and not in `held`).
      held: movable joints held at a fixed value (e.g. fingers at their opening).
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"URDF file not found: {path}")
    try:
        urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
    except Exception as e:  # yourdfpy raises several types on malformed XML
        raise ValueError(f"malformed URDF {path}: {e}") from e
    robot = urdf.robot
    held = dict(held or {})
    joints = {j.name: j for j in robot.joints}
    unknown = [n for n in list(held) + list(active_joints or []) if n not in joints]
    if unknown:
        raise ValueError(f"joints {unknown} are not in {path.name}")

    movable = [j.name for j in robot.joints if j.type in _MOVABLE and j.mimic is None]
    if active_joints is None:
        # joints that others mimic are grippers: held (at 0 within limits) unless asked for
        mimicked = {j.mimic.joint for j in robot.joints if j.mimic is not None}
        for n in mimicked - set(held):
            lim = joints[n].limit
            held[n] = float(np.clip(0.0, lim.lower, lim.upper)) if lim is not None and lim.lower is not None else 0.0
        active_joints = [n for n in movable if n not in held]
    for n in active_joints:
        if joints[n].type not in _MOVABLE:
            raise ValueError(f"active joint '{n}' is of type '{joints[n].type}', not movable")
    # values of joints that are not active: held ones, and mimics of held ones
    values = {n: float(v) for n, v in held.items()}
    for j in robot.joints:
        if j.mimic is not None:
            if j.mimic.joint in active_joints:
                raise ValueError(f"joint '{j.name}' mimics active joint '{j.mimic.joint}'; hold it instead")
            values[j.name] = j.mimic.multiplier * values.get(j.mimic.joint, 0.0) + j.mimic.offset
    for n in movable:
        if n not in active_joints:
            values.setdefault(n, 0.0)

    children = {}
    for j in robot.joints:
        children.setdefault(j.parent, []).append(j)
    child_links = {j.child for j in robot.joints}
    roots = [link.name for link in robot.links if link.name not in child_links]
    if len(roots) != 1:
        raise ValueError(f"URDF must have exactly one root link, found {roots}")

    # walk the tree from the root, folding constant transforms into frames
    link_names, link_frame, link_offset, link_parent = [], [], [], []
    frame_of_joint: dict[str, int] = {}
    frames: dict[str, dict] = {}
    stack = [(roots[0], -1, np.eye(4), -1)]
    while stack:
        link, frame, offset, parent = stack.pop()
        index = len(link_names)
        link_names.append(link)
        link_frame.append(frame)
        link_offset.append(offset)
        link_parent.append(parent)
        for j in reversed(children.get(link, [])):
            to_joint = offset @ _rpy_xyz(j.origin)
            if j.name in active_joints:
                frames[j.name] = dict(parent=frame, origin=to_joint, axis=np.asarray(j.axis, float), type=_MOVABLE[j.type])
                stack.append((j.child, j.name, np.eye(4), index))
            else:
                if j.type in _MOVABLE:
                    to_joint = to_joint @ _motion(_MOVABLE[j.type], np.asarray(j.axis, float), values[j.name])
                stack.append((j.child, frame, to_joint, index))
    # order frames as active_joints; frame references become indices
    for i, n in enumerate(active_joints):
        frame_of_joint[n] = i
    ref = lambda f: -1 if f == -1 else frame_of_joint[f]  # noqa: E731
    parents = np.array([ref(frames[n]["parent"]) for n in active_joints], dtype=np.int32)
    # FK evaluates frames in index order, so each parent must come first
    order_ok = all(p < i for i, p in enumerate(parents))
    if not order_ok:
        raise ValueError("active_joints must list every joint after the joints it hangs from")

    lower, upper, velocity, effort = [], [], [], []
    for n in active_joints:
        lim = joints[n].limit
        if joints[n].type == "continuous" or lim is None or lim.lower is None or lim.upper is None:
            lower.append(-np.inf)
            upper.append(np.inf)
        else:
            lower.append(lim.lower)
            upper.append(lim.upper)
        velocity.append(lim.velocity if lim is not None and lim.velocity else np.inf)
        effort.append(lim.effort if lim is not None and lim.effort else np.inf)

    collisions = []
    for link in robot.links:
        for c in link.collisions:
            g = c.geometry
            origin = _rpy_xyz(c.origin)
            if g.mesh is not None:
                scale = tuple(np.broadcast_to(np.asarray(g.mesh.scale if g.mesh.scale is not None else 1.0, float), 3))
                collisions.append(CollisionGeometry(link.name, "mesh", origin, (), resolve_uri(g.mesh.filename, path.parent), scale))
            elif g.box is not None:
                collisions.append(CollisionGeometry(link.name, "box", origin, tuple(map(float, g.box.size))))
            elif g.cylinder is not None:
                collisions.append(CollisionGeometry(link.name, "cylinder", origin, (float(g.cylinder.radius), float(g.cylinder.length))))
            elif g.sphere is not None:
                collisions.append(CollisionGeometry(link.name, "sphere", origin, (float(g.sphere.radius),)))

    mass, com, inertia = np.zeros(len(link_names)), np.zeros((len(link_names), 3)), np.zeros((len(link_names), 3, 3))
    by_name = {link.name: link for link in robot.links}
    for i, name in enumerate(link_names):
        inertial = by_name[name].inertial
        if inertial is None or not inertial.mass:
            continue
        o = inertial.origin if inertial.origin is not None else np.eye(4)
        mass[i], com[i] = float(inertial.mass), o[:3, 3]
        inertia[i] = o[:3, :3] @ np.asarray(inertial.inertia, float) @ o[:3, :3].T
        if not (mass[i] > 0 and np.all(np.isfinite(inertia[i]))):
            raise ValueError(f"{path.name}: link '{name}' has an invalid <inertial> (mass {mass[i]})")

    return KinematicTree(
        name=robot.name,
        joint_names=tuple(active_joints),
        joint_type=np.array([frames[n]["type"] for n in active_joints], dtype=np.int32),
        joint_axis=np.stack([frames[n]["axis"] / np.linalg.norm(frames[n]["axis"]) for n in active_joints]),
        joint_parent=parents,
        joint_origin=np.stack([frames[n]["origin"] for n in active_joints]),
        lower=np.array(lower),
        upper=np.array(upper),
        velocity=np.array(velocity),
        effort=np.array(effort, float),
        link_names=tuple(link_names),
        link_frame=np.array([ref(f) for f in link_frame], dtype=np.int32),
        link_offset=np.stack(link_offset),
        link_parent=np.array(link_parent, dtype=np.int32),
        collisions=tuple(collisions),
        held=held,
        link_mass=mass,
        link_com=com,
        link_inertia=inertia,
    )
