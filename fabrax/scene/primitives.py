"""Scenes as fixed-capacity pytrees of primitives, padded with masks.

A `Scene` holds cuboids, cylinders (axis = local z), spheres and an optional
point cloud. Every kind has a capacity; unused slots are masked out, so scenes
of different sizes stack into one batch (`stack`). Quaternions are wxyz,
lengths in metres, poses in the robot base frame.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class Cuboids:
    center: jax.Array  # (C, 3)
    quat: jax.Array  # (C, 4) wxyz
    half_extents: jax.Array  # (C, 3)
    mask: jax.Array  # (C,) bool


@struct.dataclass
class Cylinders:
    center: jax.Array  # (Y, 3)
    quat: jax.Array  # (Y, 4) wxyz, axis = local z
    radius: jax.Array  # (Y,)
    half_length: jax.Array  # (Y,)
    mask: jax.Array


@struct.dataclass
class Spheres:
    center: jax.Array  # (S, 3)
    radius: jax.Array  # (S,)
    mask: jax.Array


@struct.dataclass
class PointCloud:
    points: jax.Array  # (P, 3)
    mask: jax.Array


@struct.dataclass
class Scene:
    cuboids: Cuboids
    cylinders: Cylinders
    spheres: Spheres
    cloud: PointCloud

    @property
    def capacity(self) -> dict[str, int]:
        return {
            "cuboids": self.cuboids.mask.shape[-1],
            "cylinders": self.cylinders.mask.shape[-1],
            "spheres": self.spheres.mask.shape[-1],
            "points": self.cloud.mask.shape[-1],
        }

    @property
    def n_primitives(self) -> int:
        c = self.capacity
        return c["cuboids"] + c["cylinders"] + c["spheres"] + c["points"]

    def rounded(self, multiple: int = 8, at_least: int = 0) -> "Scene":
        """The same scene with every kind's capacity rounded up to a multiple: scenes of similar
        size then share one shape (one compiled solver) without the cost of a larger common one.
        `at_least` slots for every primitive kind (not the point cloud) give a scene without
        cylinders, say, the shape of one with a few (host checks that compile once per shape)."""
        cap = {k: -(-v // multiple) * multiple for k, v in self.capacity.items()}
        return self.pad(**{k: v if k == "points" else max(v, at_least) for k, v in cap.items()})

    def pad(self, **capacity: int) -> "Scene":
        """The same scene with at least the given capacity per kind."""
        cap = {k: max(v, capacity.get(k, 0)) for k, v in self.capacity.items()}
        if cap == self.capacity:
            return self

        def grow(tree, n):
            return jax.tree.map(lambda a: _append(a, np.zeros((n - a.shape[0],) + a.shape[1:], a.dtype)), tree)

        return Scene(
            cuboids=_unit_quats(grow(self.cuboids, cap["cuboids"])),
            cylinders=_unit_quats(grow(self.cylinders, cap["cylinders"])),
            spheres=grow(self.spheres, cap["spheres"]),
            cloud=grow(self.cloud, cap["points"]),
        )


def _traced(*arrays) -> bool:
    return any(isinstance(a, jax.core.Tracer) for a in arrays)


def _append(a, rows: np.ndarray):
    """`a` with `rows` appended along its first axis; on the host for concrete arrays, where an eager
    `jnp.concatenate` would compile one program per pair of shapes."""
    if _traced(a):
        return jnp.concatenate([a, jnp.asarray(rows)])
    return jnp.asarray(np.concatenate([np.asarray(a), rows]))


def _unit_quats(prims):
    """Padded slots get the identity rotation so that every quaternion is valid."""
    identity = np.array([1.0, 0.0, 0.0, 0.0], prims.quat.dtype)
    if _traced(prims.mask, prims.quat):
        return prims.replace(quat=jnp.where(prims.mask[:, None], prims.quat, identity))
    return prims.replace(quat=jnp.asarray(np.where(np.asarray(prims.mask)[:, None], np.asarray(prims.quat), identity)))


_FLOAT32_MAX = float(np.finfo(np.float32).max)  # scenes are stored in float32: larger values would become inf


def _field(obs: dict, key: str, where: str, n: int | None = None, positive: bool = False) -> np.ndarray:
    if key not in obs:
        raise ValueError(f"{where}: missing field '{key}'")
    try:
        v = np.asarray(obs[key], dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}.{key}: not numeric ({obs[key]!r})") from e
    if n is not None and v.shape != (n,):
        raise ValueError(f"{where}.{key}: expected {n} numbers, got {obs[key]!r}")
    if n is None and v.ndim != 0:
        raise ValueError(f"{where}.{key}: expected one number, got {obs[key]!r}")
    if not np.all(np.abs(v) < _FLOAT32_MAX):
        raise ValueError(f"{where}.{key}: NaN, infinite or beyond float32 {obs[key]!r}")
    if positive and not np.all(v > 0):
        raise ValueError(f"{where}.{key}: sizes must be positive, got {obs[key]!r}")
    return v


def _quat(obs: dict, where: str) -> np.ndarray:
    if "quat_wxyz" not in obs and "quat" not in obs:
        return np.array([1.0, 0.0, 0.0, 0.0])
    if "quat_wxyz" in obs and "quat" in obs:
        raise ValueError(f"{where}: give one of 'quat_wxyz' and 'quat', not both")
    key = "quat_wxyz" if "quat_wxyz" in obs else "quat"
    q = _field(obs, key, where, 4)
    norm = np.linalg.norm(q)
    if norm < 1e-6:
        raise ValueError(f"{where}.{key}: zero quaternion")
    return q / norm


# The fields each primitive accepts; anything else (a typo, `quat_xyzw`) is refused rather than ignored.
_ROTATED = {"type", "name", "center", "quat_wxyz", "quat"}
_KEYS = {
    "cuboid": _ROTATED | {"size", "half_extents"},
    "cylinder": _ROTATED | {"radius", "length"},
    "sphere": {"type", "name", "center", "radius"},
}


# Capacity that holds every benchmark scene (MotionBenchMaker, generated): padding scenes to it gives
# one compiled shape per solver, whatever the problem.
COMMON_CAPACITY = {"cuboids": 32, "cylinders": 16, "spheres": 8, "points": 0}


def empty(cuboids: int = 0, cylinders: int = 0, spheres: int = 0, points: int = 0) -> Scene:
    """A scene with no obstacles and the given capacities."""
    return from_dict({"obstacles": []}, capacity=dict(cuboids=cuboids, cylinders=cylinders, spheres=spheres, points=points))


def from_dict(data: dict[str, Any], capacity: dict[str, int] | None = None) -> Scene:
    """Build a `Scene` from plain data.

    data = {"obstacles": [
              {"type": "cuboid", "center": [x,y,z], "quat_wxyz": [w,x,y,z], "size": [lx,ly,lz]},  # or half_extents
              {"type": "cylinder", "center": ..., "quat_wxyz": ..., "radius": r, "length": l},
              {"type": "sphere", "center": ..., "radius": r}],
            "points": [[x, y, z], ...]}                 # optional point cloud
    Raises ValueError naming the offending field on malformed input.
    """
    if not isinstance(data, dict):
        raise ValueError(f"scene must be a mapping, got {type(data).__name__}")
    unknown = set(data) - {"obstacles", "points", "name"}
    if unknown:
        raise ValueError(f"scene: unknown keys {sorted(map(str, unknown))}")
    obstacles = data.get("obstacles", [])
    if not isinstance(obstacles, (list, tuple)):
        raise ValueError(f"obstacles: expected a list, got {obstacles!r} (write 'obstacles: []' for a scene without obstacles)")
    cub, cyl, sph = [], [], []
    for k, obs in enumerate(obstacles):
        where = f"obstacles[{k}]"
        if not isinstance(obs, dict):
            raise ValueError(f"{where}: must be a mapping")
        kind = obs.get("type")
        kind = "cuboid" if kind == "box" else kind
        if not isinstance(kind, str) or kind not in _KEYS:
            raise ValueError(f"{where}.type: unknown primitive {kind!r} (cuboid, cylinder, sphere)")
        unknown = set(obs) - _KEYS[kind]
        if unknown:
            raise ValueError(f"{where}: unknown keys {sorted(map(str, unknown))} for a {kind} (allowed: {', '.join(sorted(_KEYS[kind]))})")
        center = _field(obs, "center", where, 3)
        if kind == "cuboid":
            if "half_extents" in obs and "size" in obs:
                raise ValueError(f"{where}: give one of 'size' and 'half_extents', not both")
            if "half_extents" in obs:
                half = _field(obs, "half_extents", where, 3, positive=True)
            else:
                half = 0.5 * _field(obs, "size", where, 3, positive=True)
            cub.append((center, _quat(obs, where), half))
        elif kind == "cylinder":
            radius = float(_field(obs, "radius", where, positive=True))
            length = float(_field(obs, "length", where, positive=True))
            cyl.append((center, _quat(obs, where), radius, 0.5 * length))
        else:
            sph.append((center, float(_field(obs, "radius", where, positive=True))))
    pts = np.zeros((0, 3))
    if data.get("points") is not None:
        try:
            pts = np.asarray(data["points"], dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ValueError(f"points: not a list of [x, y, z] numbers ({e})") from e
        pts = pts.reshape(0, 3) if pts.size == 0 else pts
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points: expected a list of [x, y, z], got an array of shape {pts.shape}")
        if not np.all(np.abs(pts) < _FLOAT32_MAX):
            raise ValueError("points: NaN, infinite or beyond float32 coordinate")

    cap = {"cuboids": 0, "cylinders": 0, "spheres": 0, "points": 0, **(capacity or {})}
    sizes = {"cuboids": len(cub), "cylinders": len(cyl), "spheres": len(sph), "points": len(pts)}
    for k, n in sizes.items():
        if cap[k] and n > cap[k]:
            raise ValueError(f"scene has {n} {k}, more than its capacity {cap[k]}")
        cap[k] = max(cap[k], n)

    def rows(items, i, width, fill):
        out = np.tile(np.asarray(fill, np.float64), (cap_k, 1)) if width else np.full(cap_k, fill, np.float64)
        for r, it in enumerate(items):
            out[r] = it[i]
        return jnp.asarray(out, jnp.float32)

    cap_k = cap["cuboids"]
    cuboids = Cuboids(rows(cub, 0, 3, [0, 0, 0]), rows(cub, 1, 4, [1, 0, 0, 0]), rows(cub, 2, 3, [1, 1, 1]), jnp.arange(cap_k) < len(cub))
    cap_k = cap["cylinders"]
    cylinders = Cylinders(
        rows(cyl, 0, 3, [0, 0, 0]), rows(cyl, 1, 4, [1, 0, 0, 0]), rows(cyl, 2, 0, 1.0), rows(cyl, 3, 0, 1.0), jnp.arange(cap_k) < len(cyl)
    )
    cap_k = cap["spheres"]
    spheres = Spheres(rows(sph, 0, 3, [0, 0, 0]), rows(sph, 1, 0, 1.0), jnp.arange(cap_k) < len(sph))
    cloud_pts = np.zeros((cap["points"], 3))
    cloud_pts[: len(pts)] = pts
    cloud = PointCloud(jnp.asarray(cloud_pts, jnp.float32), jnp.arange(cap["points"]) < len(pts))
    return Scene(cuboids, cylinders, spheres, cloud)


def to_dict(scene: Scene) -> dict[str, Any]:
    """Plain-data form of one (unbatched) scene; the inverse of `from_dict`."""
    obs = []
    s = jax.tree.map(np.asarray, scene)
    for c, q, h, m in zip(s.cuboids.center, s.cuboids.quat, s.cuboids.half_extents, s.cuboids.mask):
        if m:
            obs.append({"type": "cuboid", "center": c.tolist(), "quat_wxyz": q.tolist(), "size": (2 * h).tolist()})
    for c, q, r, hl, m in zip(s.cylinders.center, s.cylinders.quat, s.cylinders.radius, s.cylinders.half_length, s.cylinders.mask):
        if m:
            obs.append({"type": "cylinder", "center": c.tolist(), "quat_wxyz": q.tolist(), "radius": float(r), "length": float(2 * hl)})
    for c, r, m in zip(s.spheres.center, s.spheres.radius, s.spheres.mask):
        if m:
            obs.append({"type": "sphere", "center": c.tolist(), "radius": float(r)})
    out: dict[str, Any] = {"obstacles": obs}
    if s.cloud.mask.any():
        out["points"] = s.cloud.points[s.cloud.mask].tolist()
    return out


def load(path: str | Path, capacity: dict[str, int] | None = None) -> Scene:
    """A scene from a JSON file in the `from_dict` format."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"cannot read scene file {path}: {e}") from e
    return from_dict(data, capacity)


def common_capacity(scenes: Sequence[Scene], multiple: int = 8) -> dict[str, int]:
    """The capacity per kind that holds every scene, rounded up to a multiple (`Scene.rounded`):
    batches of similar scenes then share one shape, one compiled solver."""
    return {k: -(-max(s.capacity[k] for s in scenes) // multiple) * multiple for k in scenes[0].capacity}


def stack(scenes: Sequence[Scene]) -> Scene:
    """Stack scenes along a new leading axis, padding every kind to the largest capacity."""
    cap = {k: max(s.capacity[k] for s in scenes) for k in scenes[0].capacity}
    padded = [s.pad(**cap) for s in scenes]
    return jax.tree.map(lambda *a: jnp.stack(a), *padded)
