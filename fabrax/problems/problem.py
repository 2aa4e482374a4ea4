"""`Problem`: a start, a goal (joint configuration and/or end-effector pose) and a scene.

Problems are validated at the public boundary: a malformed problem raises a
`ValueError` naming the field before anything reaches XLA.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fabrax.check.clearance import clearances
from fabrax.robot.robot import Robot
from fabrax.scene import Scene, from_dict, stack


@dataclasses.dataclass
class Problem:
    start_q: np.ndarray
    scene: Scene
    goal_q: np.ndarray | None = None
    goal_pose: tuple[np.ndarray, np.ndarray] | None = None  # (position xyz, quaternion wxyz) of the goal frame
    name: str = "problem"
    kind: str = "custom"  # problem class, e.g. "bookshelf_small"
    start_qd: np.ndarray | None = None
    valid: bool = True  # False when loaded data fails `validate`; `reason` says why
    reason: str = ""
    meta: dict = dataclasses.field(default_factory=dict)  # generator facts, e.g. family, problem_type, goal_q (a planner's joint goal)

    @property
    def goal_type(self) -> str:
        return "joint" if self.goal_q is not None else "pose"


def _vector(value, name: str, n: int) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}: not numeric ({value!r})") from e
    if v.shape != (n,):
        raise ValueError(f"{name}: expected {n} values, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: NaN or infinite value {v.tolist()}")
    return v


def make_problem(robot: Robot, start_q, scene: Scene | dict, goal_q=None, goal_pose=None, name="problem", kind="custom", start_qd=None) -> Problem:
    """Build and validate a problem (see `validate`)."""
    scene = from_dict(scene) if isinstance(scene, dict) else scene
    p = Problem(
        start_q=_vector(start_q, f"{name}.start_q", robot.dof),
        scene=scene,
        goal_q=None if goal_q is None else _vector(goal_q, f"{name}.goal_q", robot.dof),
        goal_pose=None
        if goal_pose is None
        else (_vector(goal_pose[0], f"{name}.goal_pose.position", 3), _vector(goal_pose[1], f"{name}.goal_pose.quat_wxyz", 4)),
        name=name,
        kind=kind,
        start_qd=None if start_qd is None else _vector(start_qd, f"{name}.start_qd", robot.dof),
    )
    validate(robot, p)
    return p


def validate(robot: Robot, p: Problem, collision_margin: float = 0.0) -> None:
    """Raise ValueError naming the field if the problem is malformed (wrong length, NaN), outside the
    joint limits, starts (or has its joint goal) in collision with the scene or itself, or has a pose
    goal out of the arm's reach (`Robot.reach`)."""
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    if p.goal_q is None and p.goal_pose is None:
        raise ValueError(f"{p.name}: needs goal_q or goal_pose")
    for field, v, n in (("start_q", p.start_q, robot.dof), ("start_qd", p.start_qd, robot.dof), ("goal_q", p.goal_q, robot.dof)):
        if v is not None:
            _vector(v, f"{p.name}.{field}", n)  # loaders build Problems directly: NaN fails no comparison below
    if p.goal_pose is not None:
        _vector(p.goal_pose[0], f"{p.name}.goal_pose.position", 3)
        _vector(p.goal_pose[1], f"{p.name}.goal_pose.quat_wxyz", 4)
    for path, leaf in jax.tree_util.tree_leaves_with_path(p.scene):
        a = np.asarray(leaf)
        if np.issubdtype(a.dtype, np.floating) and not np.all(np.isfinite(a)):
            raise ValueError(f"{p.name}.scene{jax.tree_util.keystr(path)}: NaN or infinite value")
    for field, q in (("start_q", p.start_q), ("goal_q", p.goal_q)):
        if q is None:
            continue
        bad = np.nonzero((q < lo - 1e-6) | (q > hi + 1e-6))[0]
        if len(bad):
            j = int(bad[0])
            raise ValueError(f"{p.name}.{field}[{j}] = {q[j]:.4f} is outside the joint limits [{lo[j]:.4f}, {hi[j]:.4f}] of {robot.joint_names[j]}")
    if p.goal_pose is not None and not math.isclose(float(np.linalg.norm(p.goal_pose[1])), 1.0, abs_tol=1e-3):
        raise ValueError(f"{p.name}.goal_pose.quat_wxyz must be a unit quaternion, got {p.goal_pose[1].tolist()}")
    if p.goal_pose is not None and float(np.linalg.norm(p.goal_pose[0])) > robot.reach:
        dist = float(np.linalg.norm(p.goal_pose[0]))
        raise ValueError(f"{p.name}.goal_pose.position is {dist:.2f} m from the base of {robot.name}, out of its reach ({robot.reach:.2f} m)")
    checks = [("start_q", p.start_q)] + ([("goal_q", p.goal_q)] if p.goal_q is not None else [])
    env, slf, _ = clearances(robot, p.scene, np.stack([q for _, q in checks]))
    for (field, _), e, s in zip(checks, env, slf, strict=True):
        if e < -collision_margin:
            raise ValueError(f"{p.name}.{field} is in collision with the scene (penetration {-e * 1000:.1f} mm)")
        if s < -collision_margin:
            raise ValueError(f"{p.name}.{field} is in self-collision (penetration {-s * 1000:.1f} mm)")


def flag(robot: Robot, p: Problem, collision_margin: float = 0.0) -> Problem:
    """`validate` without raising: sets `p.valid` and `p.reason` (for data sets, where a bad
    problem is reported, never dropped)."""
    try:
        validate(robot, p, collision_margin)
        p.valid, p.reason = True, ""
    except ValueError as e:
        p.valid, p.reason = False, str(e)
    return p


@struct.dataclass
class ProblemBatch:
    """Problems stacked for `jax.vmap`, one typed goal per problem: a joint goal where `joint_goal`,
    else a pose goal of the goal frame. Absent parts are placeholders: goal_q zeros, and a pose goal
    (identity at the origin) until `with_goal_poses` fills in the joint goals' poses."""

    start_q: jax.Array  # (B, n)
    start_qd: jax.Array  # (B, n)
    goal_q: jax.Array  # (B, n)
    goal_pos: jax.Array  # (B, 3)
    goal_quat: jax.Array  # (B, 4) wxyz
    joint_goal: jax.Array  # (B,) bool
    has_pose: jax.Array  # (B,) bool: goal_pos / goal_quat hold a real pose
    scene: Scene  # (B, ...) padded to one capacity

    def __len__(self) -> int:
        return self.start_q.shape[0]

    @classmethod
    def of(cls, p: Problem, capacity: dict[str, int] | None = None) -> "ProblemBatch":
        """One problem without a batch axis (GFCS solves one at a time, `jax.vmap` adds the axis),
        its scene padded to `capacity` (e.g. `COMMON_CAPACITY`: every problem runs one compiled
        solver) or, with None, to its own capacity rounded up to multiples of 8 (`Scene.rounded`:
        one compilation per size of scene; experiments/bench_scene_padding.py measures the
        padding's cost)."""
        scene = p.scene.rounded() if capacity is None else p.scene.pad(**capacity)
        return jax.tree.map(lambda x: x[0], batch([dataclasses.replace(p, scene=scene)]))

    @classmethod
    def stack(cls, items: "list[ProblemBatch]") -> "ProblemBatch":
        """Unbatched problems (`of`) with a leading axis, their scenes padded to the largest
        capacity of each kind (`fabrax.scene.stack`)."""
        if not items:
            raise ValueError("ProblemBatch.stack: no problems")
        arrays = {f.name: jnp.stack([getattr(b, f.name) for b in items]) for f in dataclasses.fields(cls) if f.name != "scene"}
        return cls(**arrays, scene=stack([b.scene for b in items]))

    def with_goal_poses(self, robot: Robot, frame: str) -> "ProblemBatch":
        """Every problem with a goal pose: a joint goal's pose of `frame` by forward kinematics (one
        batched pass), a given pose kept (the RL guide and the metrics aim every problem at a pose)."""
        from fabrax.robot.kinematics import frame_path

        pos, quat = frame_path(robot, self.goal_q, frame)
        keep = self.has_pose[:, None]
        return self.replace(
            goal_pos=jnp.where(keep, self.goal_pos, pos), goal_quat=jnp.where(keep, self.goal_quat, quat), has_pose=jnp.ones_like(self.has_pose)
        )


def batch(problems: list[Problem]) -> ProblemBatch:
    """Stack problems into a `ProblemBatch`; their scenes must share one capacity (`Scene.pad`)."""
    n = len(problems[0].start_q)
    f32 = lambda a: jnp.asarray(np.asarray(a, np.float64), jnp.float32)  # noqa: E731
    return ProblemBatch(
        start_q=f32([p.start_q for p in problems]),
        start_qd=f32([p.start_qd if p.start_qd is not None else np.zeros(n) for p in problems]),
        goal_q=f32([p.goal_q if p.goal_q is not None else np.zeros(n) for p in problems]),
        goal_pos=f32([p.goal_pose[0] if p.goal_pose is not None else np.zeros(3) for p in problems]),
        goal_quat=f32([p.goal_pose[1] if p.goal_pose is not None else [1, 0, 0, 0] for p in problems]),
        joint_goal=jnp.asarray([p.goal_q is not None for p in problems]),
        has_pose=jnp.asarray([p.goal_pose is not None for p in problems]),
        scene=stack([p.scene for p in problems]),
    )
