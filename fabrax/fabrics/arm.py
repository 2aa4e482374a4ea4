"""The arm fabric assembled from a config (configs/fabric/*.yaml), with goal helpers.

Terms are looked up by role: `goal` (joint attractor aimed at a joint goal or
a GFCS command), `posture` (joint attractor that postures the arm in the null
space of a pose goal, thesis §3.3.2), `ee` (end-effector pose attractor), plus
repulsion, limits and damping terms. A joint goal switches on `goal` and off
`ee`/`posture`; a pose goal the reverse, with the posture aimed at a given
joint configuration (e.g. the joint goal whose hand pose is the pose goal) or
at the robot's default posture.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from fabrax import validate
from fabrax.fabrics.fabric import Fabric, Params
from fabrax.fabrics.terms import TERMS
from fabrax.gains import check_config
from fabrax.robot.goal import TOLERANCE, orientation_error
from fabrax.robot.kinematics import frame_pose
from fabrax.robot.robot import Robot
from fabrax.settings import check_keys

AIMS = ("joint", "pose")
AIM_TERMS = ("goal", "posture", "ee")  # the terms that `with_*goal` set


@dataclasses.dataclass(frozen=True, eq=False)
class ArmFabric(Fabric):
    goal_frame: str = "panda_hand"
    joint_tolerance: float = TOLERANCE.joint  # rad, |q - q_goal|_2
    position_tolerance: float = TOLERANCE.position  # m
    orientation_tolerance: float = float(np.deg2rad(TOLERANCE.orientation_deg))  # rad
    posture: tuple = ()
    default_posture_weight: float = 1.0

    def _has(self, name: str) -> bool:
        return any(t.name == name for t in self.terms)

    def _set(self, params: Params, name: str, **values) -> Params:
        if not self._has(name):
            return params
        p = dict(params[name])
        for k, v in values.items():
            p[k] = jnp.broadcast_to(jnp.asarray(v, p[k].dtype), p[k].shape)
        return {**params, name: p}

    def aimed(self, params: Params) -> Params:
        """The goal terms of `params` (AIM_TERMS, batched or not) as a partial tree. Only these
        differ between goals: a rollout over many goals passes them per goal and the rest once
        (`shared` in `fabrax.rollout`)."""
        return {k: params[k] for k in AIM_TERMS if k in params}

    def with_joint_goal(self, params: Params, q_goal: jax.Array, pose: bool = False) -> Params:
        """Aim the fabric at a joint configuration (also: a GFCS command). pose=True adds the
        end-effector attractor on the pose of `goal_frame` at q_goal: the hand leads in task space
        while the joint attractor shapes the arm (thesis §3.3; both targets agree at q_goal)."""
        if not self._has("goal"):
            raise ValueError("this fabric has no 'goal' joint attractor term")
        validate.vector("q_goal", q_goal, self.robot.dof)
        params = self._set(params, "goal", target=q_goal, weight=1.0)
        params = self._set(params, "posture", weight=0.0)
        if pose and self._has("ee"):
            at_goal = frame_pose(self.robot, q_goal, self.goal_frame)
            return self._set(params, "ee", target_pos=at_goal.translation(), target_quat=at_goal.rotation().wxyz, weight=1.0)
        return self._set(params, "ee", weight=0.0)

    def with_pose_goal(
        self, params: Params, position: jax.Array, quat_wxyz: jax.Array, posture: jax.Array | None = None, posture_weight=1.0
    ) -> Params:
        """Aim the fabric at an end-effector pose of `goal_frame`, holding `posture` in the null space
        at `posture_weight` (0 switches the posture off; traceable); without one, the robot's default
        posture at `default_posture_weight` (a posture that does not match the goal pulls against it,
        so it is held more loosely)."""
        if not self._has("ee"):
            raise ValueError("this fabric has no 'ee' end-effector attractor term")
        validate.vector("position", position, 3)
        validate.vector("quat_wxyz", quat_wxyz, 4)
        if posture is not None:
            validate.vector("posture", posture, self.robot.dof)
        params = self._set(params, "ee", target_pos=position, target_quat=quat_wxyz, weight=1.0)
        params = self._set(params, "goal", weight=0.0)
        if posture is not None:
            return self._set(params, "posture", target=posture, weight=posture_weight)
        if self.posture:
            params = self._set(params, "posture", target=jnp.asarray(self.posture), weight=self.default_posture_weight)
        return params

    def with_goal(self, params: Params, joint_goal, goal_q, goal_pos, goal_quat, aim: str = "joint") -> Params:
        """Aim at a problem's goal; traceable, so it batches over problems.

        aim="joint": the joint attractor where `joint_goal` is true, the pose attractor otherwise.
        aim="pose": always the pose attractor; a joint goal becomes the pose of `goal_frame` at
        goal_q, with goal_q as the null-space posture (the thesis' end-effector attractor plus
        joint-space attractor).
        """
        if aim not in AIMS:
            raise ValueError(f"aim must be one of {AIMS}, got '{aim}'")
        if not self._has("ee"):
            return self.with_joint_goal(params, goal_q)
        if aim == "pose":
            at_goal = frame_pose(self.robot, goal_q, self.goal_frame)
            joint = self.with_pose_goal(params, at_goal.translation(), at_goal.rotation().wxyz, goal_q)
        else:
            joint = self.with_joint_goal(params, goal_q)
        pose = self.with_pose_goal(params, goal_pos, goal_quat)
        return jax.tree.map(lambda a, b: jnp.where(joint_goal, a, b), joint, pose)

    def goal_errors(self, params: Params, q: jax.Array):
        """(joint error, position error, orientation error) against the current goal."""
        joint = jnp.linalg.norm(q - params["goal"]["target"]) if self._has("goal") else jnp.inf
        if not self._has("ee"):
            return joint, jnp.inf, jnp.inf
        pose = frame_pose(self.robot, q, self.goal_frame)
        pos = jnp.linalg.norm(pose.translation() - params["ee"]["target_pos"])
        return joint, pos, orientation_error(pose.rotation().wxyz, params["ee"]["target_quat"])

    def joint_reached(self, params: Params, q: jax.Array, qd: jax.Array | None = None, tolerance: float | None = None) -> jax.Array:
        """The joint-goal test alone (no kinematics): |q - q_goal|_2 within `tolerance` (default joint_tolerance)."""
        return jnp.linalg.norm(q - params["goal"]["target"]) <= (self.joint_tolerance if tolerance is None else tolerance)

    def reached(self, params: Params, q: jax.Array, qd: jax.Array | None = None) -> jax.Array:
        """The goal test for time-to-goal: joint error within tolerance, or pose within position and orientation tolerance."""
        joint, pos, rot = self.goal_errors(params, q)
        joint_mode = params["goal"]["weight"] > 0.5 if self._has("goal") else False
        pose_ok = (pos <= self.position_tolerance) & (rot <= self.orientation_tolerance)
        return jnp.where(joint_mode, joint <= self.joint_tolerance, pose_ok)

    def posture_reached(self, params: Params, q: jax.Array, qd: jax.Array | None = None) -> jax.Array:
        """`reached`, and under a pose goal also the posture within the joint tolerance."""
        if not self._has("posture"):
            return self.reached(params, q, qd)
        near = jnp.linalg.norm(q - params["posture"]["target"]) <= self.joint_tolerance
        pose_mode = params["ee"]["weight"] > 0.5 if self._has("ee") else False
        return self.reached(params, q, qd) & (near | ~pose_mode)


def build_arm_fabric(robot: Robot, cfg: dict[str, Any], posture=None) -> ArmFabric:
    """An `ArmFabric` from a config mapping: {terms: {name: {type: ..., params...}}, goal_tolerance: {...}, goal_frame}.
    goal_frame null (or absent) is the robot's `ee_frame`; `posture` (the joint attractors' default
    target) defaults to the robot's ready posture."""
    check_config(cfg)
    goal_frame = cfg.get("goal_frame") or robot.ee_frame or robot.frame_names[-1]  # null: the robot's end effector
    if posture is None:
        posture = robot.ready_q if robot.ready_q is not None else np.zeros(robot.dof)
    terms = []
    for name, spec in (cfg.get("terms") or {}).items():
        spec = dict(spec)
        kind = spec.pop("type", None)
        if kind not in TERMS:
            raise ValueError(f"fabric term '{name}': unknown type '{kind}' (types: {', '.join(TERMS)})")
        if kind == "ee_attractor":
            spec.setdefault("frame", goal_frame)
        if kind == "joint_attractor":
            spec.setdefault("n", robot.dof)
            if "target" not in spec:
                spec["target"] = np.asarray(posture, np.float32)
        terms.append(TERMS[kind](name=name, **spec))
    tol = dict(cfg.get("goal_tolerance") or {})
    check_keys(tol, ("joint", "position", "orientation_deg"), "goal_tolerance")
    fabric = ArmFabric(
        robot=robot,
        terms=tuple(terms),
        goal_frame=goal_frame,
        joint_tolerance=float(tol.get("joint", TOLERANCE.joint)),
        position_tolerance=float(tol.get("position", TOLERANCE.position)),
        orientation_tolerance=float(np.deg2rad(tol.get("orientation_deg", TOLERANCE.orientation_deg))),
        posture=tuple(float(v) for v in np.asarray(posture)),
        energization=cfg.get("energization", "dissipative"),
        default_posture_weight=float(cfg.get("default_posture_weight", 1.0)),
    )
    robot.frame_index(fabric.goal_frame)  # fails early on an unknown frame
    return fabric
