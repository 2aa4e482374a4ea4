"""MπNets-faithful problems: the scene families and problem types of the Motion Policy Networks test
set (Fishman et al., CoRL 2022), on which the thesis reports Table 4.1 (fabrics_guided_rl_thesis §4.1).

Four families, drawn with MπNets' weights (cubby 1/6, merged cubby 1/6, dresser 1/3, tabletop 1/3),
and three problem types, half of them task-oriented:

- ``task_oriented``: start and goal both inside containers (two cubby pockets, two open drawers,
  two poses over the table); the straight way between them usually runs through boards.
- ``neutral_start``: start at a neutral posture (``NEUTRAL`` + U(0, 0.25) rad per joint), goal inside.
- ``neutral_goal``: start inside a container, goal the hand pose of a neutral posture.

Scene dimensions, goal-pose distributions and container volumes follow the generator's own
distributions (cubby: front 0.45-0.65 m, two rows and two columns of pockets, turned up to ±10°;
merged cubby: the shelf or wall between the start and goal pockets removed; dresser: a body split
recursively into drawers, two of them open; tabletop: an L-shaped table with 3-14 boxes and
cylinders). MπNets poses its goals for ``right_gripper``, the tool centre point 0.10 m in front of
``panda_hand`` and turned 180° about its z axis: poses are sampled there and converted to the hand
frame (``tcp_to_hand``), which is what a `Problem`'s pose goal names.

Starts and goal configurations are collision-free IK solutions on a random branch (random seeds, a
random one among the valid solutions), checked by the project's exact checker. MπNets keeps a test
problem only when a global planner solves it; `generate` takes that check as a callable
(`solvable`) from the harness, and counts the problems it drops. Each problem is drawn from its
own generator seeded by (seed, index), so a problem is the same whichever filter selects it.
For another arm (`Fit`) the scenes and TCP poses are scaled about the base by the ratio of its
reach to the Panda's, the hand sits its own `tool_length` behind the TCP, and neutral postures are
drawn around its ready posture.

Deviations, each a limit of the scene representation: closed drawers are their front boards (the
rest of a closed drawer lies inside the body, unreachable); the tabletop's mount plate under the
robot has its top at -4 cm, not 0, since the fixed base's collision spheres reach 2.7 cm below the
base frame; scenes over the project's common
capacity (32 cuboids, 16 cylinders; MπNets' cutoff is 40 of each) are drawn again.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import pickle
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fabrax.check.clearance import clearances
from fabrax.problems.problem import Problem, flag
from fabrax.robot.ik import solve_ik
from fabrax.robot.kinematics import frame_pose
from fabrax.robot.robot import Robot
from fabrax.scene import COMMON_CAPACITY, from_dict

FAMILIES = ("cubby", "merged_cubby", "dresser", "tabletop")
FAMILY_WEIGHTS = (1 / 6, 1 / 6, 1 / 3, 1 / 3)
TYPES = ("task_oriented", "neutral_start", "neutral_goal")
TYPE_WEIGHTS = (0.5, 0.25, 0.25)
NEUTRAL = np.array([-0.017792, -0.760124, 0.019783, -2.342050, 0.029841, 1.541194, 0.753449])  # robofin's Franka neutral
TCP_OFFSET = 0.10  # m from panda_hand to right_gripper along the hand's z
PANDA_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
VERSION = 1  # bump when a distribution changes: cached sets are keyed by it
MOUNT_TOP = -0.04  # m: the plate under the robot (MπNets: top at 0) sits below the Panda base's collision spheres
MOUNT_CLEARANCE = 0.015  # m between another arm's lowest base sphere and the mount plate's top
IK_MARGIN = 0.005  # m of clearance a start or goal configuration keeps (exact checker)


# ------------------------------------------------------------------------------------------- frames


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _ry(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (wxyz, w >= 0) of a rotation matrix (Shepperd's method, in float64)."""
    m = np.asarray(m, np.float64)
    tr = np.trace(m)
    k = int(np.argmax([tr, m[0, 0], m[1, 1], m[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    return q if q[0] >= 0 else -q


def _matrix(quat_wxyz) -> np.ndarray:
    w, x, y, z = np.asarray(quat_wxyz, np.float64) / np.linalg.norm(quat_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def tcp_to_hand(position, quat_wxyz, offset: float = TCP_OFFSET) -> tuple[np.ndarray, np.ndarray]:
    """The ``panda_hand`` pose whose tool centre point (MπNets' ``right_gripper``) is at the given pose:
    T_hand = T_tcp · T_off⁻¹ with T_off = (Rz(π), (0, 0, offset)); another arm's `ee_frame` with its
    `tool_length` as `offset`."""
    r = _matrix(quat_wxyz)
    p = np.asarray(position, np.float64) - offset * r[:, 2]
    return p, _quat(r @ _rz(np.pi))


def hand_to_tcp(position, quat_wxyz, offset: float = TCP_OFFSET) -> tuple[np.ndarray, np.ndarray]:
    """The tool centre point's pose from the ``panda_hand`` pose (inverse of `tcp_to_hand`)."""
    r = _matrix(quat_wxyz)
    return np.asarray(position, np.float64) + offset * r[:, 2], _quat(r @ _rz(np.pi))


@dataclasses.dataclass(frozen=True)
class Fit:
    """How the Panda's set is carried to an arm: scenes and TCP poses scaled about the base by
    `scale` (`workspace.workspace_reach` ratio), the hand `offset` behind the TCP (the arm's
    `tool_length`), neutral postures around `neutral` (its ready posture). The Panda's: MπNets' own."""

    scale: float = 1.0
    offset: float = TCP_OFFSET
    neutral: tuple = tuple(NEUTRAL.tolist())
    mount_top: float = MOUNT_TOP  # m: the tabletop's mount plate stays this far down, below the arm's base spheres

    @classmethod
    def of(cls, robot: Robot, frame: str) -> "Fit":
        if tuple(robot.joint_names) == PANDA_JOINTS:
            return cls()
        from fabrax.problems.workspace import PANDA_REACH, workspace_reach

        scale = workspace_reach(robot, frame) / PANDA_REACH
        base = np.asarray(robot.collision.frame) == 0  # spheres fixed to the base
        lowest = float(np.min(np.asarray(robot.collision.local)[base, 2] - np.asarray(robot.collision.radius)[base])) if base.any() else 0.0
        neutral = tuple(np.asarray(robot.ready_q, np.float64).tolist())
        return cls(scale, float(robot.tool_length), neutral, min(MOUNT_TOP, round(lowest - MOUNT_CLEARANCE, 4)))


# ------------------------------------------------------------------------------------------ volumes


@dataclasses.dataclass
class Volume:
    """An axis-aligned box turned by `yaw` about z: where a container's goal poses are drawn."""

    center: np.ndarray
    size: np.ndarray
    yaw: float = 0.0

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        local = rng.uniform(-0.5, 0.5, (n, 3)) * self.size
        return self.center + local @ _rz(self.yaw).T

    def contains(self, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        local = (np.asarray(points) - self.center) @ _rz(self.yaw)
        return np.all(np.abs(local) <= self.size / 2 + tol, axis=-1)


def _box(center, size, yaw: float = 0.0, name: str = "box") -> dict:
    return {
        "type": "cuboid",
        "name": name,
        "center": [float(v) for v in center],
        "quat_wxyz": [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))],
        "size": [float(v) for v in size],
    }


@dataclasses.dataclass
class Layout:
    """A scene (obstacle dicts), its two containers (None for the tabletop) and the family's TCP poses."""

    obstacles: list[dict]
    volumes: tuple[Volume, Volume] | None
    family: str
    params: dict
    tables: list[tuple[np.ndarray, np.ndarray]] = dataclasses.field(default_factory=list)  # tabletop: (lo, hi) corners of task tables
    objects: list[dict] = dataclasses.field(default_factory=list)

    def goal_poses(self, rng: np.random.Generator, which: int, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """n TCP poses (position, rotation matrix) of the family's distribution in container `which`."""
        if self.family == "tabletop":
            return [_table_pose(rng, self) for _ in range(n)]
        points = self.volumes[which].sample(rng, n)
        out = []
        for p in points:
            theta = rng.uniform(-np.pi / 4, np.pi / 4)
            if self.family == "dresser":  # gripper down, fingers at world yaw theta
                x, z = np.array([np.cos(theta), np.sin(theta), 0.0]), np.array([0.0, 0.0, -1.0])
            else:  # approach horizontal at world yaw theta, hand x down
                x, z = np.array([0.0, 0.0, -1.0]), np.array([np.cos(theta), np.sin(theta), 0.0])
            out.append((p, np.stack([x, np.cross(z, x), z], 1)))
        return out


# -------------------------------------------------------------------------------------------- cubby


def _u(rng: np.random.Generator, center: float, radius: float) -> float:
    """MπNets' radius sample: uniform on [center - radius, center + radius]."""
    return float(rng.uniform(center - radius, center + radius))


def cubby(rng: np.random.Generator, merged: bool = False) -> Layout:
    """Two columns x two rows of pockets facing the robot, turned about their centre; with `merged`,
    the shelf and/or wall between the start and goal pockets is removed and both poses are drawn in
    the merged space."""
    left, right, bottom = _u(rng, 0.7, 0.1), _u(rng, -0.7, 0.1), _u(rng, 0.2, 0.1)
    front = _u(rng, 0.55, 0.1)
    back = front + _u(rng, 0.35, 0.2)
    top, mid_z, mid_y = _u(rng, 0.7, 0.1), _u(rng, 0.45, 0.1), _u(rng, 0.0, 0.1)
    t = _u(rng, 0.02, 0.01)
    yaw = _u(rng, 0.0, np.pi / 18)
    pivot = np.array([(front + back) / 2, (left + right) / 2, (top + bottom) / 2])
    depth, width = back - front, left - right
    i, j = (int(k) for k in rng.permutation(4)[:2])  # pockets: 0 left-top, 1 right-top, 2 left-bottom, 3 right-bottom
    shelf = not (merged and (i < 2) != (j < 2))
    wall = not (merged and (i % 2) != (j % 2))
    parts = [
        ([back, pivot[1], top / 2], [t, width, top], "back"),
        ([pivot[0], pivot[1], bottom], [depth, width, t], "bottom"),
        ([pivot[0], pivot[1], top], [depth, width, t], "top"),
        ([pivot[0], right, pivot[2]], [depth, t, top - bottom + t], "right"),
        ([pivot[0], left, pivot[2]], [depth, t, top - bottom + t], "left"),
    ]
    if wall:
        parts.append(([pivot[0], mid_y, pivot[2]], [depth, t, top - bottom + t], "wall"))
    if shelf:
        parts.append(([pivot[0], pivot[1], mid_z], [depth, width, t], "shelf"))
    turn = lambda p: pivot + _rz(yaw) @ (np.asarray(p) - pivot)  # noqa: E731
    obstacles = [_box(turn(c), s, yaw, n) for c, s, n in parts]

    def pocket(k: int) -> Volume:
        ys = (mid_y, left) if k % 2 == 0 else (right, mid_y)
        zs = (mid_z, top) if k < 2 else (bottom, mid_z)
        if not wall:
            ys = (right, left)
        if not shelf:
            zs = (bottom, top)
        c = np.array([pivot[0], sum(ys) / 2, sum(zs) / 2])
        return Volume(turn(c), np.array([depth, ys[1] - ys[0], zs[1] - zs[0]]), yaw)

    family = "merged_cubby" if merged else "cubby"
    params = {"front": front, "back": back, "left": left, "right": right, "bottom": bottom, "top": top, "mid_z": mid_z, "mid_y": mid_y}
    params |= {"thickness": t, "yaw": yaw, "pockets": (i, j), "shelf": shelf, "wall": wall}
    return Layout(obstacles, (pocket(i), pocket(j)), family, params)


# ------------------------------------------------------------------------------------------ dresser

_BOARD = 0.01  # dresser body and split walls
_FRONT, _WALL = 0.019, 0.004  # drawer front board, drawer walls


def _split(rng, x, y, w, h, prob, decay, walls, cells):
    """MπNets' recursive split of the dresser front (x right, y down from the top-left corner)."""
    if not (rng.random() < prob) or (w < 0.3 and h < 0.3):
        cells.append((x, y, w, h))
        return
    vertical = rng.random() < 0.5
    vertical = False if w < 0.3 else (True if h < 0.3 else vertical)
    p = prob * decay
    if vertical:
        walls.append((x + w / 2, y + h / 2, _BOARD, h, "v"))
        nw = w / 2 - _BOARD / 2
        _split(rng, x, y, nw, h, p, decay, walls, cells)
        _split(rng, x + w / 2 + _BOARD / 2, y, nw, h, p, decay, walls, cells)
    else:
        walls.append((x + w / 2, y + h / 2, w, _BOARD, "h"))
        nh = h / 2 - _BOARD / 2
        _split(rng, x, y, w, nh, p, decay, walls, cells)
        _split(rng, x, y + h / 2 + _BOARD / 2, w, nh, p, decay, walls, cells)


def dresser(rng: np.random.Generator) -> Layout | None:
    """A dresser (W 0.8-1.2, D 0.2-0.4, H 0.55-0.85 m) at x 0.55-0.75, its front turned toward the robot
    ±60°, split recursively into drawers; two drawers on (70 % of the time) different levels are open
    (0.81 D out, five boards with walls as tall as their front), closed ones are their front boards.
    Containers: an open drawer's interior, 2 cm from its walls, its top 5 cm cut. None when the
    dresser has fewer than two drawers with room for a hand."""
    width, depth, height = _u(rng, 1.0, 0.2), _u(rng, 0.3, 0.1), _u(rng, 0.7, 0.15)
    x0, y0, rot = _u(rng, 0.65, 0.1), _u(rng, 0.0, 0.1), _u(rng, np.pi / 2, np.pi / 3)
    walls, cells = [], []
    _split(rng, 0.0, 0.0, width, height, 0.7, 0.8, walls, cells)
    if len(cells) < 2:
        return None
    r, origin = _rz(rot), np.array([x0, y0, 0.0])
    world = lambda p: origin + r @ np.asarray(p, float)  # noqa: E731  (dresser frame: x across, +y out of the front, z up)
    body = lambda x, y: np.array([width / 2 - x, depth / 2, height - y])  # noqa: E731  (front point from split coordinates)
    obstacles = [
        _box(world([0, 0, -_BOARD / 2]), [width, depth, _BOARD], rot, "bottom"),
        _box(world([0, 0, height + _BOARD / 2]), [width, depth, _BOARD], rot, "top"),
        _box(world([width / 2 + _BOARD / 2, 0, height / 2]), [_BOARD, depth, height + 2 * _BOARD], rot, "side"),
        _box(world([-width / 2 - _BOARD / 2, 0, height / 2]), [_BOARD, depth, height + 2 * _BOARD], rot, "side"),
        _box(world([0, -depth / 2 + _BOARD / 2, height / 2]), [width + 2 * _BOARD, _BOARD, height + 2 * _BOARD], rot, "back"),
    ]
    for cx, cy, w, h, _ in walls:
        c = body(cx, cy) - [0, depth / 2, 0]
        obstacles.append(_box(world(c), [w, depth, h], rot, "divider"))
    dd, out = 0.9 * depth, 0.81 * depth

    def drawer(cell) -> tuple[list[dict], Volume | None]:
        x, y, w, h = cell
        f = body(x + w / 2, y + h / 2) + [0, out, 0]  # drawer frame: front's inner face centre, pulled out
        boards = [
            ([0, _FRONT / 2, 0], [w, _FRONT, h]),
            ([0, -(dd - _WALL) / 2, (_WALL - h) / 2], [w - 2 * _WALL, dd - _WALL, _WALL]),
            ([(w - _WALL) / 2, (_WALL - dd) / 2, 0], [_WALL, dd - _WALL, h]),
            ([-(w - _WALL) / 2, (_WALL - dd) / 2, 0], [_WALL, dd - _WALL, h]),
            ([0, -dd + _WALL / 2, 0], [w, _WALL, h]),
        ]
        obs = [_box(world(f + off), size, rot, "drawer") for off, size in boards]
        floor = f[2] - h / 2 + _WALL
        vw, vd, vh = w - 2 * _WALL - 0.04, dd - _WALL - 0.04, h - _WALL - 0.02 - 0.05
        if min(vw, vd, vh) < 0.02:
            return obs, None
        c = np.array([f[0], f[1] - dd / 2, floor + vh / 2])
        return obs, Volume(world(c), np.array([vw, vd, vh]), rot)

    order = [int(k) for k in rng.permutation(len(cells))]
    opened = {k: drawer(cells[k]) for k in order}
    roomy = [k for k in order if opened[k][1] is not None]
    pair = None
    for a, i in enumerate(roomy):
        for j in roomy[a + 1 :]:
            top_i = opened[i][1].center[2] + opened[i][1].size[2] / 2
            top_j = opened[j][1].center[2] + opened[j][1].size[2] / 2
            if abs(top_i - top_j) <= 0.05 and rng.random() > 0.3:
                continue  # MπNets keeps same-level pairs 30 % of the time
            pair = (i, j)
            break
        if pair:
            break
    if pair is None:
        return None
    for k, cell in enumerate(cells):
        if k in pair:
            obstacles += opened[k][0]
        else:
            x, y, w, h = cell
            obstacles.append(_box(world(body(x + w / 2, y + h / 2) + [0, _FRONT / 2, 0]), [w, _FRONT, h], rot, "front"))
    params = {"width": width, "depth": depth, "height": height, "x": x0, "y": y0, "rotation": rot, "drawers": len(cells), "open": pair}
    return Layout(obstacles, (opened[pair[0]][1], opened[pair[1]][1]), "dresser", params)


# ----------------------------------------------------------------------------------------- tabletop


def _slab(lo, hi, name) -> dict:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return _box((lo + hi) / 2, hi - lo, 0.0, name)


def _object_sdf(o: dict, p: np.ndarray) -> float:
    c = np.asarray(o["center"])
    if o["type"] == "cylinder":
        radial = np.linalg.norm(p[:2] - c[:2]) - o["radius"]
        axial = abs(p[2] - c[2]) - o["length"] / 2
    else:
        yaw = 2 * np.arctan2(o["quat_wxyz"][3], o["quat_wxyz"][0])
        d = np.abs(_rz(yaw).T @ (p - c)) - np.asarray(o["size"]) / 2
        return float(np.linalg.norm(np.maximum(d, 0.0)) + min(d.max(), 0.0))
    outside = np.hypot(max(radial, 0.0), max(axial, 0.0))
    return float(outside + min(max(radial, axial), 0.0))


def _table_points(rng, tables, n) -> np.ndarray:
    areas = np.array([(hi[0] - lo[0]) * (hi[1] - lo[1]) for lo, hi in tables])
    pick = rng.choice(len(tables), size=n, p=areas / areas.sum())
    pts = np.stack([rng.uniform([lo[0], lo[1], hi[2]], [hi[0], hi[1], hi[2]], (n, 3)) for lo, hi in tables])
    return pts[pick, np.arange(n)]


def tabletop(rng: np.random.Generator) -> Layout:
    """A table (top at 0 m in 35 % of scenes, else 0-0.4 m) from x 0.28-0.38 to 1.28-1.38 m, with an
    L-shaped side table reaching behind the robot in half the scenes; 3-14 objects (70 % boxes, 30 %
    cylinders, 5-35 cm tall, at least 5 cm apart) on the task part (55-65 %) of each table."""
    h = float(rng.choice([rng.uniform(0, 0.4), 0.0], p=[0.65, 0.35]))
    fx0, fx1, fy1 = rng.uniform(0.275, 0.375), rng.uniform(1.275, 1.375), rng.uniform(1.5, 1.65)
    side = rng.uniform() < 0.5
    fy0 = rng.uniform(-1.0, -0.75) if side else rng.uniform(-0.75, -0.55)
    split = fy0 + rng.uniform(0.55, 0.65) * (fy1 - fy0)
    tables = [(np.array([fx0, fy0, -0.02]), np.array([fx1, split, h]))]
    free = [(np.array([fx0, split, -0.02]), np.array([fx1, fy1, h]))]
    mount_c = rng.uniform([-0.02, -0.02], [0.02, 0.02])
    mount_y = rng.uniform(0.9, 0.94)
    if side:
        sy1 = rng.uniform(-0.325, -0.275)
        sx1 = fx0
        sx0 = sx1 - rng.uniform(0, 1.375)
        cut = sx1 - rng.uniform(0.55, 0.65) * (sx1 - sx0)
        tables.append((np.array([cut, fy0, -0.02]), np.array([sx1, sy1, h])))
        free.append((np.array([sx0, fy0, -0.02]), np.array([cut, sy1, h])))
        mount_y = 2 * (mount_c[1] - sy1)
    mount_x = 2 * (fx0 - mount_c[0])
    obstacles = [_slab(lo, hi, "table") for lo, hi in tables + free]
    obstacles.append(_box([mount_c[0], mount_c[1], MOUNT_TOP - 0.01], [mount_x, mount_y, 0.02], 0.0, "mount"))
    count = int(rng.integers(3, 15))
    objects: list[dict] = []
    for p in _table_points(rng, tables, 10 * count):
        if len(objects) >= count:
            break
        sdf = min((_object_sdf(o, p) for o in objects), default=1000.0)
        if sdf <= 0.05:
            continue
        top = min(sdf, 0.15)
        tall = rng.uniform(0.05, 0.35)
        k = len(objects)
        if rng.random() < 0.3:
            objects.append(
                {"type": "cylinder", "name": f"object{k}", "center": [p[0], p[1], h + tall / 2], "radius": rng.uniform(0.05, top), "length": tall}
            )
        else:
            size = [rng.uniform(0.05, top), rng.uniform(0.05, top), tall]
            objects.append(_box([p[0], p[1], h + tall / 2], size, rng.uniform(0, np.pi / 2), f"object{k}"))
    layout = Layout(obstacles + objects, None, "tabletop", {"height": h, "side_table": bool(side), "objects": len(objects)})
    layout.tables, layout.objects = tables, objects
    return layout


def _table_pose(rng: np.random.Generator, layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    """A TCP pose over the table: a point on a task table (on an object's top when within 1 cm of
    it), 1-12 cm above (denser near the surface), roll 135-225°, pitch ±22.5°, yaw ±90°."""
    p = _table_points(rng, layout.tables, 1)[0]
    for o in layout.objects:
        if _object_sdf(o, p) <= 0.01:
            c = np.asarray(o["center"])
            p[2] = c[2] + (o["length"] if o["type"] == "cylinder" else o["size"][2]) / 2
    p[2] += (1 - np.sqrt(rng.uniform())) * 0.11 + 0.01
    roll, pitch, yaw = rng.uniform(3 * np.pi / 4, 5 * np.pi / 4), rng.uniform(-np.pi / 8, np.pi / 8), rng.uniform(-np.pi / 2, np.pi / 2)
    return p, _rz(yaw) @ _ry(pitch) @ _rx(roll)


def layout(family: str, rng: np.random.Generator) -> Layout | None:
    """One scene of a family, or None when the draw is unusable (MπNets draws again)."""
    if family in ("cubby", "merged_cubby"):
        return cubby(rng, merged=family == "merged_cubby")
    if family == "dresser":
        return dresser(rng)
    if family == "tabletop":
        return tabletop(rng)
    raise ValueError(f"unknown MπNets family '{family}' (families: {', '.join(FAMILIES)})")


# --------------------------------------------------------------------------------------------- IK


@functools.partial(jax.jit, static_argnames=("frame",))
def _ik_many(robot: Robot, frame: str, positions, quats, seeds):
    """IK of P poses from S seeds each: (P, S, n) configurations and (P, S) residuals."""
    return jax.vmap(lambda p, q, s: solve_ik(robot, frame, p, q, s))(positions, quats, seeds)


def _ik_in(robot, scene, frame, poses, rng, seeds: int = 16, offset: float = TCP_OFFSET) -> tuple[np.ndarray, int] | None:
    """A collision-free IK solution (random branch) of the first of `poses` (TCP poses) that has one."""
    hand = [tcp_to_hand(p, _quat(m), offset) for p, m in poses]
    pos = jnp.asarray(np.stack([h[0] for h in hand]), jnp.float32)
    quat = jnp.asarray(np.stack([h[1] for h in hand]), jnp.float32)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    q0 = jnp.asarray(rng.uniform(lo, hi, (len(poses), seeds, robot.dof)), jnp.float32)
    qs, err = _ik_many(robot, frame, pos, quat, q0)
    qs, err = np.asarray(qs), np.asarray(err)
    flat = qs.reshape(-1, robot.dof)
    env, slf, ok = (a.reshape(len(poses), seeds) for a in clearances(robot, scene, flat))
    inside = np.all((qs > lo + 0.01) & (qs < hi - 0.01), axis=-1)
    good = (err < 1e-3) & inside & ok & (env > IK_MARGIN) & (slf > 0.0)
    for k in range(len(poses)):
        idx = np.flatnonzero(good[k])
        if len(idx):
            return qs[k, int(rng.choice(idx))].astype(np.float64), k
    return None


def _neutral(robot, scene, rng, tries: int = 8, neutral=NEUTRAL) -> np.ndarray | None:
    """A collision-free neutral posture: NEUTRAL + U(0, 0.25) rad per joint (robofin's 'uniform')."""
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    for _ in range(tries):
        qs = np.clip(np.asarray(neutral) + rng.uniform(0, 0.25, (32, robot.dof)), lo, hi)
        env, slf, ok = clearances(robot, scene, qs)
        good = np.flatnonzero(ok & (env > IK_MARGIN) & (slf > 0.0))
        if len(good):
            return qs[good[0]]
    return None


def _container_config(robot, scene, frame, lay: Layout, which: int, rng, rounds: int = 6, fit: Fit = Fit()):
    """A TCP pose of container `which` and its IK configuration (up to 6 x 16 poses, as MπNets' 100)."""
    for _ in range(rounds):
        poses = lay.goal_poses(rng, which, 16)
        if fit.scale != 1.0:
            poses = [(fit.scale * np.asarray(p), m) for p, m in poses]
        found = _ik_in(robot, scene, frame, poses, rng, offset=fit.offset)
        if found is not None:
            q, k = found
            return poses[k], q
    return None


# ---------------------------------------------------------------------------------------- problems


def draw(seed: int, index: int) -> tuple[str, str]:
    """The (family, problem type) of problem `index`: MπNets' weights, from the problem's own seed."""
    rng = np.random.default_rng([seed, index, 0])
    return str(rng.choice(FAMILIES, p=FAMILY_WEIGHTS)), str(rng.choice(TYPES, p=TYPE_WEIGHTS))


def one(robot: Robot, seed: int, index: int, frame: str = "panda_hand", tries: int = 30, fit: Fit = Fit()) -> Problem | None:
    """Problem `index` of the set drawn with `seed`, or None when `tries` scenes gave no valid problem.
    Its `meta` carries family, problem type, the TCP goal pose and the generator's goal configuration.
    `fit` carries the Panda's scene and poses to another arm (`Fit.of`)."""
    family, kind = draw(seed, index)
    rng = np.random.default_rng([seed, index, 1])
    for _ in range(tries):
        lay = layout(family, rng)
        if lay is None:
            continue
        try:
            obstacles = lay.obstacles
            if fit.scale != 1.0:
                from fabrax.problems.workspace import carry

                obstacles = carry({"obstacles": obstacles}, [], fit.scale, 0.0)[0]["obstacles"]
                for o in obstacles:
                    if o.get("name") == "mount":  # under the arm's own base, not scaled with the scene
                        o["center"][2], o["size"][2] = fit.mount_top - 0.01, 0.02
            scene = from_dict({"obstacles": obstacles}).pad(**COMMON_CAPACITY)
        except ValueError:
            continue  # over the common capacity: draw again
        start = goal_q = tcp = None
        if kind in ("task_oriented", "neutral_goal"):
            found = _container_config(robot, scene, frame, lay, 0, rng, fit=fit)
            if found is None:
                continue
            start = found[1]
        if kind in ("task_oriented", "neutral_start"):
            found = _container_config(robot, scene, frame, lay, 1, rng, fit=fit)
            if found is None:
                continue
            (p, m), goal_q = found
            tcp = (p, _quat(m))
        if kind == "neutral_start":
            start = _neutral(robot, scene, rng, neutral=fit.neutral)
        if kind == "neutral_goal":
            goal_q = _neutral(robot, scene, rng, neutral=fit.neutral)
            if goal_q is not None:
                pose = frame_pose(robot, jnp.asarray(goal_q, jnp.float32), frame)
                tcp = hand_to_tcp(np.asarray(pose.translation(), np.float64), np.asarray(pose.rotation().wxyz, np.float64), fit.offset)
        if start is None or goal_q is None:
            continue
        goal = tcp_to_hand(*tcp, fit.offset)
        meta = {"family": family, "problem_type": kind, "tcp_goal": [np.asarray(tcp[0]).tolist(), np.asarray(tcp[1]).tolist()]}
        meta |= {"goal_q": np.asarray(goal_q).tolist(), "params": _plain(lay.params)}
        p = Problem(start_q=start, scene=scene, goal_pose=goal, name=f"{family}/{kind}/{index:05d}", kind=family, meta=meta)
        if flag(robot, p).valid:
            return p
    return None


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (tuple, list)):
        return [_plain(v) for v in x]
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    return x


@dataclasses.dataclass
class ProblemSet:
    """Problems kept, and how many were drawn: `dropped` failed the solvability check, `failed`
    gave no valid problem in their tries."""

    problems: list[Problem]
    drawn: int
    dropped: list[str]
    failed: list[str]
    solvable: str | None


def generate(
    robot: Robot,
    n: int,
    seed: int = 0,
    classes=None,
    types=None,
    frame: str | None = None,
    solvable: Callable[[Robot, Problem], bool] | None = None,
    solvable_key: str | None = None,
    cache_dir: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ProblemSet:
    """The first n problems of the set drawn with `seed` whose family is in `classes` and type in
    `types` (all when None), each kept only if `solvable(robot, problem)` (problems carry the
    generator's goal configuration in meta["goal_q"]). With `cache_dir`, the set is stored there
    under a key of every setting (`solvable_key` names the check) and read back next time. For an
    arm other than the Panda the scenes and poses are carried into its workspace (`Fit.of`), for
    its `ee_frame` (the default `frame`)."""
    frame = frame or robot.ee_frame
    fit = Fit.of(robot, frame)
    classes = list(classes or FAMILIES)
    types = list(types or TYPES)
    for name, given, known in (("classes", classes, FAMILIES), ("types", types, TYPES)):
        bad = [c for c in given if c not in known]
        if bad:
            raise ValueError(f"unknown MπNets {name} {bad} ({name}: {', '.join(known)})")
    key = {"version": VERSION, "robot": robot.name, "spheres": int(robot.n_spheres), "n": n, "seed": seed, "classes": classes, "types": types}
    key |= {"frame": frame, "solvable": solvable_key if solvable is not None else None}
    if fit != Fit():
        key["fit"] = dataclasses.asdict(fit)
    path = None
    if cache_dir is not None:
        digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
        path = Path(cache_dir) / f"mpinets-{digest}.pkl"
        if path.exists():
            return pickle.loads(path.read_bytes())
    kept, dropped, failed = [], [], []
    index = 0
    while len(kept) < n:
        family, kind = draw(seed, index)
        if family in classes and kind in types:
            p = one(robot, seed, index, frame, fit=fit)
            if p is None:
                failed.append(f"{family}/{kind}/{index:05d}")
            elif solvable is not None and not solvable(robot, p):
                dropped.append(p.name)
            else:
                kept.append(p)
            if progress is not None:
                progress(len(kept), len(kept) + len(dropped) + len(failed))
        index += 1
    out = ProblemSet(kept, index, dropped, failed, key["solvable"])
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(out))
        tmp.replace(path)
    return out
