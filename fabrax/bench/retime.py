"""Time-parameterise a geometric path (waypoints) within velocity and acceleration limits.

Planners such as OMPL return paths, not trajectories. Before their smoothness
and duration are measured they are retimed the way a robot would execute them
safely: along each straight joint-space segment, rest to rest, with a
trapezoidal (or triangular) speed profile whose duration is the shortest that
keeps every joint within its velocity and acceleration limits, all joints
synchronised. The trajectory never leaves the validated polyline (so the
checker sees exactly what the planner validated) and stops at every
waypoint, which makes the baselines' durations conservative and their jerk
what such an execution has.
"""

from __future__ import annotations

import numpy as np

from fabrax.robot.robot import Robot


def _segment_time(delta: np.ndarray, vmax: np.ndarray, amax: np.ndarray) -> tuple[float, float, float]:
    """(duration, cruise speed, acceleration) of s in [0, 1] for one rest-to-rest segment."""
    d = np.abs(delta)
    moving = d > 0
    if not moving.any():
        return 0.0, 0.0, 0.0
    v = np.min(vmax[moving] / d[moving])  # s-units per second
    a = np.min(amax[moving] / d[moving])
    if v * v / a >= 1.0:  # triangular: never reaches cruise speed
        ta = np.sqrt(1.0 / a)
        return 2.0 * ta, a * ta, a
    return 1.0 / v + v / a, v, a


def _s_of_t(t: np.ndarray, duration: float, v: float, a: float) -> np.ndarray:
    ta = v / a
    return np.where(t < ta, 0.5 * a * t * t, np.where(t > duration - ta, 1.0 - 0.5 * a * (duration - t) ** 2, 0.5 * a * ta * ta + v * (t - ta)))


def retime(robot: Robot, path: np.ndarray, dt: float) -> np.ndarray:
    """A trajectory (T, n), sampled every dt, that follows `path` (W, n) segment by segment, rest to rest."""
    path = np.asarray(path, np.float64)
    vmax, amax = np.asarray(robot.velocity, np.float64), np.asarray(robot.acceleration, np.float64)
    segments = [(path[k], path[k + 1], *_segment_time(path[k + 1] - path[k], vmax, amax)) for k in range(len(path) - 1)]
    segments = [s for s in segments if s[2] > 0]
    starts = np.cumsum([0.0] + [s[2] for s in segments])
    t = np.arange(0.0, starts[-1] + dt, dt)
    t[-1] = min(t[-1], starts[-1])
    q = np.repeat(path[-1:], len(t), 0)
    for (a_q, b_q, duration, v, a), t0 in zip(segments, starts[:-1], strict=True):
        sel = (t >= t0) & (t <= t0 + duration)
        s = _s_of_t(t[sel] - t0, duration, v, a)
        q[sel] = a_q + s[:, None] * (b_q - a_q)
    return q
