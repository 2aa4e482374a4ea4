"""The papers' per-problem metrics on a time-sampled joint trajectory.

success      reached the goal at the end, no collision, joint limits respected (time budgets are the
             methods': a fabric rolls out for at most t_max, a planner plans within its budget)
collision    the exact checker (`checker.check_path`) found scene or self collision
ee_length    end-effector (goal frame) path length, m
cspace_length  joint-space path length, rad
ee_ldj, cspace_ldj  log dimensionless jerk of the speed profiles (Hogan & Sternad 2009, the
             velocity-peak form: -ln(T^3 / v_peak^2 * integral jerk^2 dt))
duration_s   trajectory time
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from fabrax.bench.checker import check_path
from fabrax.problems.problem import Problem
from fabrax.robot.kinematics import frame_path
from fabrax.robot.robot import Robot


@dataclasses.dataclass
class Goal:
    """Success tolerances: joint goals by |q - q_goal|_2, pose goals by position and orientation."""

    joint: float = 0.05  # rad
    position: float = 0.01  # m
    orientation_deg: float = 15.0


def log_dimensionless_jerk(speed: np.ndarray, dt: float) -> float:
    """LDJ of a speed profile sampled every dt (velocity-peak normalisation, jerk by finite differences)."""
    speed = np.asarray(speed, np.float64)
    if len(speed) < 3 or speed.max() <= 0:
        return float("nan")
    duration = len(speed) * dt
    jerk = np.diff(speed, 2) / dt**2
    return float(-np.log(duration**3 / speed.max() ** 2 * np.sum(jerk**2) * dt))


def goal_errors(robot: Robot, problem: Problem, q_final: np.ndarray, frame: str) -> tuple[float, float, float]:
    """(joint error rad, position error m, orientation error rad) of the final state."""
    joint = float(np.linalg.norm(q_final - problem.goal_q)) if problem.goal_q is not None else float("nan")
    pos, quat = (np.asarray(a)[0] for a in frame_path(robot, jnp.asarray(q_final[None], jnp.float32), frame))
    if problem.goal_pose is None:
        return joint, float("nan"), float("nan")
    target_pos, target_quat = problem.goal_pose
    dot = abs(float(np.dot(quat, target_quat / np.linalg.norm(target_quat))))
    return joint, float(np.linalg.norm(pos - target_pos)), float(2.0 * np.arccos(min(dot, 1.0)))


def evaluate(
    robot: Robot,
    problem: Problem,
    q: np.ndarray,
    dt: float,
    *,
    goal: Goal = Goal(),
    frame: str = "panda_hand",
    margin: float = 0.0,
) -> dict:
    """All metrics of one trajectory q (T, n) sampled every dt."""
    q = np.asarray(q, np.float64)
    check = check_path(robot, problem.scene, q, margin=margin)
    joint_err, pos_err, rot_err = goal_errors(robot, problem, q[-1], frame)
    if problem.goal_q is not None:
        reached = joint_err <= goal.joint
    else:
        reached = pos_err <= goal.position and rot_err <= np.deg2rad(goal.orientation_deg)
    duration = (len(q) - 1) * dt
    pad = (-len(q)) % 256  # a few compiled lengths, not one per trajectory length
    padded = np.concatenate([q, np.repeat(q[-1:], pad, 0)]) if pad else q
    ee = np.asarray(frame_path(robot, jnp.asarray(padded, jnp.float32), frame)[0], np.float64)[: len(q)]
    dq, dee = np.diff(q, axis=0), np.diff(ee, axis=0)
    return {
        "success": bool(reached and not check.collision and check.limits_ok),
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
    }
