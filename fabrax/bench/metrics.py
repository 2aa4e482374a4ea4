"""The papers' per-problem metrics on a time-sampled joint trajectory.

success      reached the goal at the end by the run's criterion, no collision, joint limits respected
             (time budgets are the methods': a fabric rolls out for at most t_max, a planner plans
             within its budget)
success_joint, success_pose, success_keypoints
             the same under each criterion: |q - q_goal|_2 <= joint tolerance (joint goals only);
             goal-frame position and orientation within tolerance (the pose of a joint goal is its
             forward kinematics); mean distance of the 8 end-effector keypoints (corners of the
             hand's bounding box) to the goal's below `keypoints` (thesis §3.4.5, 0.08)
collision    the exact checker (`checker.check_path`) found scene or self collision
ee_length    end-effector (goal frame) path length, m
cspace_length  joint-space path length, rad
ee_ldj, cspace_ldj  log dimensionless jerk of the speed profiles (Hogan & Sternad 2009, the
             velocity-peak form: -ln(T^3 / v_peak^2 * integral jerk^2 dt))
duration_s   trajectory time
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from fabrax.check.checker import check_path
from fabrax.problems.problem import Problem
from fabrax.robot.goal import TOLERANCE, orientation_error
from fabrax.robot.kinematics import frame_path, keypoints
from fabrax.robot.robot import Robot

CRITERIA = ("auto", "joint", "pose", "keypoints")


@dataclasses.dataclass
class Goal:
    """Success tolerances, and which of them decides `success`: `auto` is the joint tolerance for
    joint goals and the pose tolerance for pose goals."""

    joint: float = TOLERANCE.joint  # rad
    position: float = TOLERANCE.position  # m
    orientation_deg: float = TOLERANCE.orientation_deg
    keypoints: float = TOLERANCE.keypoints  # m, mean keypoint distance (thesis §3.4.5)
    criterion: str = "auto"

    def __post_init__(self):
        if self.criterion not in CRITERIA:
            raise ValueError(f"goal.criterion must be one of {CRITERIA}, got '{self.criterion}'")


def log_dimensionless_jerk(speed: np.ndarray, dt: float) -> float:
    """LDJ of a speed profile sampled every dt (velocity-peak normalisation, jerk by finite differences)."""
    speed = np.asarray(speed, np.float64)
    if len(speed) < 3 or speed.max() <= 0:
        return float("nan")
    duration = len(speed) * dt
    jerk = np.diff(speed, 2) / dt**2
    return float(-np.log(duration**3 / speed.max() ** 2 * np.sum(jerk**2) * dt))


def _goal_pose(robot: Robot, problem: Problem, frame: str):
    if problem.goal_pose is not None:
        return problem.goal_pose
    pos, quat = frame_path(robot, jnp.asarray(problem.goal_q[None], jnp.float32), frame)
    return np.asarray(pos)[0], np.asarray(quat)[0]


@jax.jit
def _keypoint_error(robot: Robot, q, goal_pos, goal_quat, goal_frame_pos, goal_frame_quat):
    """Mean distance of the keypoints at q to the keypoints at the goal pose (keypoints are rigid with
    the goal frame, so the goal's keypoints are the current ones moved by goal pose * current pose^-1)."""
    now = keypoints(robot, q)
    current = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3(goal_frame_quat), goal_frame_pos)
    goal = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3(goal_quat), goal_pos)
    target = jax.vmap((goal @ current.inverse()).apply)(now)
    return jnp.mean(jnp.linalg.norm(now - target, axis=-1))


def goal_errors(robot: Robot, problem: Problem, q_final: np.ndarray, frame: str) -> tuple[float, float, float, float]:
    """(joint error rad, position error m, orientation error rad, mean keypoint error m) of the final state."""
    joint = float(np.linalg.norm(q_final - problem.goal_q)) if problem.goal_q is not None else float("nan")
    pos, quat = (np.asarray(a)[0] for a in frame_path(robot, jnp.asarray(q_final[None], jnp.float32), frame))
    target_pos, target_quat = _goal_pose(robot, problem, frame)
    target_quat = np.asarray(target_quat) / np.linalg.norm(target_quat)
    kp = float(
        _keypoint_error(robot, jnp.asarray(q_final, jnp.float32), *(jnp.asarray(a, jnp.float32) for a in (target_pos, target_quat, pos, quat)))
    )
    return joint, float(np.linalg.norm(pos - target_pos)), float(orientation_error(np.asarray(quat, np.float64), target_quat)), kp


def evaluate(
    robot: Robot,
    problem: Problem,
    q: np.ndarray,
    dt: float,
    *,
    goal: Goal = Goal(),
    frame: str | None = None,
    margin: float = 0.0,
) -> dict:
    """All metrics of one trajectory q (T, n) sampled every dt; `frame` (default: the robot's
    ee_frame) is the end effector that pose goals and EE lengths are measured on."""
    frame = frame or robot.ee_frame
    q = np.asarray(q, np.float64)
    check = check_path(robot, problem.scene, q, margin=margin)
    joint_err, pos_err, rot_err, kp_err = goal_errors(robot, problem, q[-1], frame)
    ok = not check.collision and check.limits_ok
    by = {
        "joint": problem.goal_q is not None and joint_err <= goal.joint,
        "pose": pos_err <= goal.position and rot_err <= np.deg2rad(goal.orientation_deg),
        "keypoints": kp_err < goal.keypoints,
    }
    criterion = goal.criterion if goal.criterion != "auto" else ("joint" if problem.goal_q is not None else "pose")
    reached = by[criterion]
    duration = (len(q) - 1) * dt
    pad = (-len(q)) % 256  # a few compiled lengths, not one per trajectory length
    padded = np.concatenate([q, np.repeat(q[-1:], pad, 0)]) if pad else q
    ee = np.asarray(frame_path(robot, jnp.asarray(padded, jnp.float32), frame)[0], np.float64)[: len(q)]
    dq, dee = np.diff(q, axis=0), np.diff(ee, axis=0)
    return {
        "success": bool(reached and ok),
        "success_joint": bool(by["joint"] and ok) if problem.goal_q is not None else None,
        "success_pose": bool(by["pose"] and ok),
        "success_keypoints": bool(by["keypoints"] and ok),
        "criterion": criterion,
        "reached": bool(reached),
        "collision": check.collision,
        "limits_ok": check.limits_ok,
        "ee_length": float(np.linalg.norm(dee, axis=1).sum()),
        "cspace_length": float(np.linalg.norm(dq, axis=1).sum()),
        "ee_ldj": log_dimensionless_jerk(np.linalg.norm(dee, axis=1) / dt, dt),
        "cspace_ldj": log_dimensionless_jerk(np.linalg.norm(dq, axis=1) / dt, dt),
        "duration_s": float(duration),
        "min_clearance": check.min_clearance,
        "joint_error": joint_err,
        "position_error": pos_err,
        "orientation_error_deg": float(np.rad2deg(rot_err)),
        "keypoint_error": kp_err,
    }
