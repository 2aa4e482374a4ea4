"""`Robot`: a kinematic tree, limits, collision spheres and self-collision pairs.

Static structure (joint tree, names) lives in hashable fields; numbers are
array leaves, so a `Robot` passes straight through `jax.jit` and `jax.vmap`.
"""

from __future__ import annotations

import importlib.metadata
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fabrax.robot import kinematics
from fabrax.robot import spheres as sphere_lib
from fabrax.robot.collision import RobotCollision
from fabrax.robot.urdf import REVOLUTE, KinematicTree, parse_urdf
from fabrax.settings import check_keys


@struct.dataclass
class Robot:
    name: str = struct.field(pytree_node=False)
    joint_names: tuple = struct.field(pytree_node=False)
    joint_parent: tuple = struct.field(pytree_node=False)
    joint_revolute: tuple = struct.field(pytree_node=False)
    frame_names: tuple = struct.field(pytree_node=False)
    joint_axis: jax.Array  # (n, 3)
    joint_origin_r: jax.Array  # (n, 3, 3)
    joint_origin_t: jax.Array  # (n, 3)
    lower: jax.Array  # (n,)
    upper: jax.Array
    velocity: jax.Array
    acceleration: jax.Array
    jerk: jax.Array
    ancestors: jax.Array  # (n+1, n) bool: joint j moves frame f (f's own joint included)
    link_frame: jax.Array  # (L,) frame index, 0 = base
    link_offset_r: jax.Array  # (L, 3, 3)
    link_offset_t: jax.Array  # (L, 3)
    frame_parent: jax.Array  # (F,) named frames: links first, then extra frames
    frame_offset_r: jax.Array
    frame_offset_t: jax.Array
    collision: RobotCollision  # collision spheres and the self-collision search (fabrax.robot.collision)
    ee_frame: str = struct.field(pytree_node=False, default="")  # the end effector's frame (z along the tool's approach)
    tool_length: float = struct.field(pytree_node=False, default=0.0)  # m from ee_frame along its z to the tool centre point
    keypoint_frame: int = struct.field(pytree_node=False, default=0)  # joint frame that carries the keypoints
    keypoint_local: jax.Array | None = None  # (8, 3) corners of the end effector's bounding box in that frame
    effort: jax.Array | None = None  # (n,) joint torque limits from the URDF (inf where none)
    frame_mass: jax.Array | None = None  # (n+1,) mass rigidly carried by each joint frame (0 = base), from the URDF's <inertial>
    frame_com: jax.Array | None = None  # (n+1, 3) its centre of mass in the frame
    frame_inertia: jax.Array | None = None  # (n+1, 3, 3) its inertia about that centre, frame axes
    ready_q: jax.Array | None = None  # (n,) the ready posture (config default_q; else the middle of the limits)

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    @property
    def n_spheres(self) -> int:
        return self.collision.n_spheres

    def frame_index(self, name: str) -> int:
        if name not in self.frame_names:
            raise ValueError(f"frame '{name}' is not defined on robot '{self.name}' (frames: {', '.join(self.frame_names)})")
        return self.frame_names.index(name)

    @property
    def reach(self) -> float:
        """An upper bound (m) of how far any frame gets from the base: the joint origins' offsets
        summed along the whole tree plus the largest link and extra-frame offset (the triangle
        inequality), so a target farther away is out of reach in every configuration."""
        chain = float(np.sum(np.linalg.norm(np.asarray(self.joint_origin_t), axis=-1)))
        tips = [np.asarray(a) for a in (self.link_offset_t, self.frame_offset_t) if np.size(a)]
        return chain + sum(float(np.max(np.linalg.norm(t, axis=-1))) for t in tips)

    def frame_point(self, name: str, offset=(0.0, 0.0, 0.0)):
        """(frame index, local position) of a point rigidly attached to a named frame."""
        i = self.frame_index(name)
        local = self.frame_offset_r[i] @ jnp.asarray(offset, self.frame_offset_t.dtype) + self.frame_offset_t[i]
        return self.frame_parent[i], local

    def within_limits(self, q, tol: float = 0.0):
        return jnp.all((q >= self.lower - tol) & (q <= self.upper + tol), axis=-1)

    def clip(self, q):
        return jnp.clip(q, self.lower, self.upper)


def panda_urdf() -> Path:
    """The Franka Panda URDF shipped by the `example-robot-data` package."""
    return resolve_urdf("panda_description/urdf/panda.urdf")


def resolve_urdf(spec: str | Path | None) -> Path:
    """The URDF file a robot config names: None is the Panda of `example-robot-data`; an existing
    path (absolute, or relative to the current folder) is used as it is; anything else is a path
    inside `example-robot-data`'s robots folder (e.g. `ur_description/urdf/ur5_robot.urdf`), so a
    config works from any folder and on any machine that installed the package."""
    if spec is None:
        spec = "panda_description/urdf/panda.urdf"
    path = Path(str(spec)).expanduser()
    if path.is_file():
        return path
    if not path.is_absolute():
        try:
            files = importlib.metadata.files("example-robot-data") or []
        except importlib.metadata.PackageNotFoundError:
            files = []
        tail = "/" + path.as_posix().lstrip("/")
        for f in files:
            if ("/" + str(f)).endswith(tail):
                return Path(f.locate())
    if path.is_absolute():
        raise ValueError(f"robot.urdf: {path} not found")
    raise ValueError(f"robot.urdf: '{spec}' not found: neither a file nor a path inside example-robot-data's robots folder")


def _ancestors(parent: np.ndarray) -> np.ndarray:
    """(n+1, n) mask: frame f (0 = base) is moved by joint j."""
    n = len(parent)
    out = np.zeros((n + 1, n), bool)
    for k, p in enumerate(parent):
        out[k + 1] = out[p + 1]
        out[k + 1, k] = True
    return out


def frame_inertials(tree: KinematicTree) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mass, com, inertia) of the links each joint frame carries (frame 0 = base), combined by the
    parallel-axis theorem: I = sum_l R_l I_l R_l^T + m_l (|d_l|^2 E - d_l d_l^T), d_l = c_l - c."""
    n = tree.dof
    mass, com, inertia = np.zeros(n + 1), np.zeros((n + 1, 3)), np.zeros((n + 1, 3, 3))
    if tree.link_mass is None:
        return mass, com, inertia
    r, t = tree.link_offset[:, :3, :3], tree.link_offset[:, :3, 3]
    c_frame = np.einsum("lij,lj->li", r, tree.link_com) + t
    for f in range(n + 1):
        links = np.flatnonzero((tree.link_frame + 1 == f) & (tree.link_mass > 0))
        m = tree.link_mass[links]
        if m.sum() <= 0:
            continue
        mass[f] = m.sum()
        com[f] = (m[:, None] * c_frame[links]).sum(0) / mass[f]
        for k, li in enumerate(links):
            d = c_frame[li] - com[f]
            inertia[f] += r[li] @ tree.link_inertia[li] @ r[li].T + m[k] * (d @ d * np.eye(3) - np.outer(d, d))
    return mass, com, inertia


def _rt(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return m[..., :3, :3], m[..., :3, 3]


def _rpy(rpy) -> np.ndarray:
    r, p, y = rpy
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def self_collision_pairs(
    tree: KinematicTree,
    sphere_frame: np.ndarray,
    sphere_link: np.ndarray,
    sphere_pos_fn,
    radius: np.ndarray,
    n_samples: int,
    max_fraction: float,
    reference_qs: np.ndarray,
    near_distance: float = 0.05,
    near_fraction: float = 0.5,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Sphere pairs that must be checked for self-collision.

    Excluded: spheres on one rigid body or on adjacent bodies, and every pair
    of two links whose spheres overlap at more than `max_fraction` of random
    configurations within limits or at any reference configuration (resting
    contact, not collision), or come closer than `near_distance` at more than
    `near_fraction` of them (links packed around a joint, whose overlap the
    spheres' overshoot cannot tell from contact).
    """
    s = len(radius)
    i, j = np.triu_indices(s, 1)
    parent = np.concatenate([[-1], np.asarray(tree.joint_parent) + 1])  # frame -> parent frame
    fi, fj = sphere_frame[i], sphere_frame[j]
    keep = (fi != fj) & (parent[fi] != fj) & (parent[fj] != fi)
    i, j = i[keep], j[keep]
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(tree.lower), tree.lower, -np.pi)
    hi = np.where(np.isfinite(tree.upper), tree.upper, np.pi)
    qs = np.concatenate([rng.uniform(lo, hi, (n_samples, len(lo))), np.atleast_2d(reference_qs)])
    pos = np.asarray(jax.jit(jax.vmap(sphere_pos_fn))(jnp.asarray(qs, jnp.float32)))
    gap = np.linalg.norm(pos[:, i] - pos[:, j], axis=-1) - radius[i] - radius[j]
    # decide per pair of links, on the smallest gap between their spheres (as MoveIt's ACM does)
    link_pair = sphere_link[i] * (sphere_link.max() + 1) + sphere_link[j]
    keep = np.ones(len(i), bool)
    for lp in np.unique(link_pair):
        sel = link_pair == lp
        g = gap[:, sel].min(1)
        overlap, near = g[:n_samples] < 0, g[:n_samples] < near_distance
        if overlap.mean() > max_fraction or np.any(g[n_samples:] < 0) or near.mean() > near_fraction:
            keep[sel] = False
    return i[keep].astype(np.int32), j[keep].astype(np.int32)


def build_robot(cfg: dict[str, Any]) -> Robot:
    """Build a `Robot` from a config mapping (see configs/robot/panda.yaml).

    Keys: urdf (path, a path inside example-robot-data, or null for its Panda), active_joints,
    ee_frame (default: keypoints.frame, else the last link), tool_length, default_q (the ready
    posture), limits (for joints the URDF leaves unbounded),
    held, acceleration, jerk, frames, spheres {source: fit|file, budget,
    tolerance, file, set}, self_collision {samples, max_fraction, reference_q}.
    """
    known = {
        "name", "urdf", "active_joints", "held", "acceleration", "jerk", "frames", "spheres", "self_collision", "default_q",
        "keypoints", "ee_frame", "tool_length", "limits",
    }  # fmt: skip
    check_keys(cfg, known, "robot config")
    urdf = resolve_urdf(cfg.get("urdf"))
    tree = parse_urdf(urdf, cfg.get("active_joints"), cfg.get("held"))
    n = tree.dof
    _set_limits(tree, cfg.get("limits") or {})
    ready = cfg.get("default_q")
    if ready is not None:
        ready = np.asarray(ready, np.float64)
        if ready.shape != (n,) or not np.all(np.isfinite(ready)):
            raise ValueError(f"robot.default_q must be {n} finite numbers (one per active joint), got {cfg.get('default_q')}")
        outside = np.nonzero((ready < tree.lower - 1e-6) | (ready > tree.upper + 1e-6))[0]
        if len(outside):
            j = int(outside[0])
            raise ValueError(f"robot.default_q[{j}] = {ready[j]} is outside the limits of {tree.joint_names[j]} [{tree.lower[j]}, {tree.upper[j]}]")
    else:
        ready = 0.5 * (tree.lower + tree.upper)

    def per_joint(key, default):
        v = np.asarray(cfg.get(key) if cfg.get(key) is not None else default, dtype=np.float64)
        v = np.broadcast_to(v, (n,)).copy()
        if not np.all(v > 0):
            raise ValueError(f"robot.{key} must be positive for every joint, got {v}")
        return v

    acceleration = per_joint("acceleration", 10.0)
    jerk = per_joint("jerk", 5000.0)

    # named frames: every link, plus extra frames {name: {parent, xyz, rpy}}
    frame_names = list(tree.link_names)
    frame_parent = list(tree.link_frame + 1)
    frame_offset = list(tree.link_offset)
    for fname, spec in (cfg.get("frames") or {}).items():
        spec = dict(spec)
        parent = tree.link_index(spec.get("parent", ""))
        local = np.eye(4)
        local[:3, :3] = _rpy(spec.get("rpy", (0.0, 0.0, 0.0)))
        local[:3, 3] = spec.get("xyz", (0.0, 0.0, 0.0))
        frame_names.append(fname)
        frame_parent.append(tree.link_frame[parent] + 1)
        frame_offset.append(tree.link_offset[parent] @ local)

    # collision spheres, expressed in the frame that carries their link
    sph_cfg = dict(cfg.get("spheres") or {})
    source = sph_cfg.get("source", "fit")
    if source == "fit":
        per_link = sphere_lib.fitted_spheres(
            tree, int(sph_cfg.get("budget", 60)), float(sph_cfg.get("tolerance", 0.001)), seed=int(sph_cfg.get("seed", 0))
        )
    elif source == "file":
        per_link = sphere_lib.load_sphere_file(sph_cfg["file"], sph_cfg.get("set"))
    else:
        raise ValueError(f"robot.spheres.source must be 'fit' or 'file', got '{source}'")
    s_frame, s_local, s_radius, s_link, link_names = [], [], [], [], []
    for link, items in per_link.items():
        li = tree.link_index(link)
        link_names.append(link)
        for s in items:
            off = tree.link_offset[li]
            s_frame.append(tree.link_frame[li] + 1)
            s_local.append(off[:3, :3] @ np.asarray(s["center"], float) + off[:3, 3])
            s_radius.append(float(s["radius"]))
            s_link.append(len(link_names) - 1)

    origin_r, origin_t = _rt(tree.joint_origin)
    link_r, link_t = _rt(tree.link_offset)
    frame_r, frame_t = _rt(np.stack(frame_offset))
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    robot = Robot(
        name=cfg.get("name") or tree.name,
        joint_names=tree.joint_names,
        joint_parent=tuple(int(p) for p in tree.joint_parent),
        joint_revolute=tuple(bool(t == REVOLUTE) for t in tree.joint_type),
        frame_names=tuple(frame_names),
        joint_axis=f32(tree.joint_axis),
        joint_origin_r=f32(origin_r),
        joint_origin_t=f32(origin_t),
        lower=f32(tree.lower),
        upper=f32(tree.upper),
        velocity=f32(tree.velocity),
        acceleration=f32(acceleration),
        jerk=f32(jerk),
        ancestors=jnp.asarray(_ancestors(tree.joint_parent)),
        link_frame=jnp.asarray(tree.link_frame + 1, jnp.int32),
        link_offset_r=f32(link_r),
        link_offset_t=f32(link_t),
        frame_parent=jnp.asarray(frame_parent, jnp.int32),
        frame_offset_r=f32(frame_r),
        frame_offset_t=f32(frame_t),
        collision=RobotCollision(
            link_names=tuple(link_names),
            frame=jnp.asarray(s_frame, jnp.int32),
            local=f32(np.asarray(s_local).reshape(-1, 3)),
            radius=f32(s_radius),
            link=jnp.asarray(s_link, jnp.int32),
            pair_i=jnp.zeros((0,), jnp.int32),  # the pairs are sampled with this robot's kinematics below
            pair_j=jnp.zeros((0,), jnp.int32),
            pair_groups=jnp.zeros((0, 0), jnp.int32),
            pair_groups_mask=jnp.zeros((0, 0), bool),
            link_pair_groups=jnp.zeros((0, 0), jnp.int32),
            link_pair_groups_mask=jnp.zeros((0, 0), bool),
        ),
    )
    sc = dict(cfg.get("self_collision") or {})
    reference = np.asarray(sc.get("reference_q", cfg.get("default_q")) or np.zeros((0, n)), dtype=np.float64).reshape(-1, n)
    pi, pj = self_collision_pairs(
        tree,
        np.asarray(s_frame),
        np.asarray(s_link),
        lambda q: kinematics.sphere_centers(robot, q),
        np.asarray(s_radius),
        int(sc.get("samples", 1000)),
        float(sc.get("max_fraction", 0.2)),
        reference,
        float(sc.get("near_distance", 0.05)),
        float(sc.get("near_fraction", 0.5)),
    )
    s_link = np.asarray(s_link)
    key = s_link[pi] * len(link_names) + s_link[pj]
    width = int(sc.get("group_width", 16))
    chunks, owner = [], []
    for k in np.unique(key):
        members = np.nonzero(key == k)[0]
        for c in range(0, len(members), width):
            chunks.append(members[c : c + width])
            owner.append(k)
    groups, group_mask = _groups(chunks)
    owner = np.asarray(owner)
    link_groups, link_group_mask = _groups([np.nonzero(owner == k)[0] for k in np.unique(owner)])
    ee_frame = cfg.get("ee_frame") or (cfg.get("keypoints") or {}).get("frame") or tree.link_names[-1]
    if ee_frame not in frame_names:
        raise ValueError(f"robot.ee_frame '{ee_frame}' is not a link or frame of {urdf.name} (frames: {', '.join(frame_names)})")
    tool_length = cfg.get("tool_length", 0.0)
    if not isinstance(tool_length, (int, float)) or isinstance(tool_length, bool) or not np.isfinite(tool_length) or tool_length < 0:
        raise ValueError(f"robot.tool_length must be a finite number >= 0 (m), got {tool_length!r}")
    kp_frame, kp_local = _keypoint_box(
        cfg.get("keypoints"), ee_frame, frame_names, frame_parent, frame_offset, link_names, s_link, s_frame, s_local, s_radius
    )
    mass, com, inertia = frame_inertials(tree)
    return robot.replace(
        effort=f32(tree.effort),
        frame_mass=f32(mass),
        frame_com=f32(com),
        frame_inertia=f32(inertia),
        ee_frame=ee_frame,
        tool_length=float(tool_length),
        ready_q=f32(ready),
        keypoint_frame=kp_frame,
        keypoint_local=f32(kp_local),
        collision=robot.collision.replace(
            pair_i=jnp.asarray(pi),
            pair_j=jnp.asarray(pj),
            pair_groups=jnp.asarray(groups),
            pair_groups_mask=jnp.asarray(group_mask),
            link_pair_groups=jnp.asarray(link_groups),
            link_pair_groups_mask=jnp.asarray(link_group_mask),
        ),
    )


def _set_limits(tree: KinematicTree, limits: dict) -> None:
    """Joint limits the URDF lacks (continuous joints) or that the config narrows:
    {joint name: [lower, upper]}; every active joint must end up with finite limits."""
    for name, bounds in limits.items():
        if name not in tree.joint_names:
            raise ValueError(f"robot.limits.{name}: not an active joint (active: {', '.join(tree.joint_names)})")
        lo_hi = np.asarray(bounds, np.float64)
        if lo_hi.shape != (2,) or not np.all(np.isfinite(lo_hi)) or lo_hi[0] >= lo_hi[1]:
            raise ValueError(f"robot.limits.{name} must be [lower, upper] with lower < upper, got {bounds}")
        j = tree.joint_names.index(name)
        tree.lower[j], tree.upper[j] = lo_hi
    for j, name in enumerate(tree.joint_names):
        if not (np.isfinite(tree.lower[j]) and np.isfinite(tree.upper[j])):
            raise ValueError(f"robot.limits.{name}: the URDF gives this joint no limits (continuous); set robot.limits.{name}: [lower, upper]")


def _keypoint_box(spec, ee_frame, frame_names, frame_parent, frame_offset, link_names, s_link, s_frame, s_local, s_radius):
    """The 8 corners of the box, axis-aligned in frame `spec.frame`, around the collision spheres of
    `spec.links` (the end effector's bounding box of thesis §3.4.2), in the joint frame that carries
    them. Without a spec: a 0.1 m cube on the end-effector frame."""
    spec = dict(spec or {})
    check_keys(spec, ("frame", "links"), "robot.keypoints")
    name = spec.get("frame") or ee_frame
    if name not in frame_names:
        raise ValueError(f"robot.keypoints.frame '{name}' is not a frame of the robot")
    f = frame_names.index(name)
    carrier, offset = int(frame_parent[f]), np.asarray(frame_offset[f])
    links = spec.get("links") or []
    missing = [lk for lk in links if lk not in link_names]
    if missing:
        raise ValueError(f"robot.keypoints.links {missing} carry no collision spheres (links with spheres: {', '.join(link_names)})")
    s_link, s_frame, s_local, s_radius = (np.asarray(a) for a in (s_link, s_frame, s_local, s_radius))
    sel = np.isin(s_link, [link_names.index(lk) for lk in links])
    if sel.any() and np.any(s_frame[sel] != carrier):
        raise ValueError(f"robot.keypoints.links must move rigidly with frame '{name}'")
    if sel.any():
        local = (s_local[sel] - offset[:3, 3]) @ offset[:3, :3]  # sphere centres in the keypoint frame
        lo, hi = (local - s_radius[sel, None]).min(0), (local + s_radius[sel, None]).max(0)
    else:
        lo, hi = np.full(3, -0.05), np.full(3, 0.05)
    corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    return carrier, corners @ offset[:3, :3].T + offset[:3, 3]


def _groups(members: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Ragged index lists as a padded (G, max) array (padding repeats the first member) and its mask."""
    members = [m for m in members if len(m)]
    width = max((len(m) for m in members), default=0)
    out = np.zeros((len(members), width), np.int32)
    mask = np.zeros((len(members), width), bool)
    for g, m in enumerate(members):
        out[g] = m[0]
        out[g, : len(m)] = m
        mask[g, : len(m)] = True
    return out, mask
