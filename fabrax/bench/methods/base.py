"""What every method is: a robot and a list of problems in, one `Solution` per problem out.

A solution is a joint trajectory sampled every `dt`, the wall time it took to produce (compilation
excluded, reported apart) and free-form info. Methods that batch (fabrics) solve many problems in
one `vmap`; their per-problem time is the batch's wall time divided by its size.
"""

from __future__ import annotations

import dataclasses
import zlib
from typing import Any, Protocol

import numpy as np

from fabrax.problems.problem import Problem
from fabrax.robot.robot import Robot


@dataclasses.dataclass
class Solution:
    q: np.ndarray  # (T, n) trajectory
    dt: float
    plan_time_s: float
    compile_s: float = 0.0
    info: dict[str, Any] = dataclasses.field(default_factory=dict)


class Method(Protocol):
    name: str

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]: ...


def planned(robot: Robot, problem: Problem, path, info: dict, dt: float) -> Solution:
    """A planner's path as a solution: retimed rest to rest (`retime`), or the start when none was
    found; plan time is its solve plus simplification time."""
    from fabrax.bench.retime import retime

    elapsed = info["solve_s"] + info["simplify_s"]
    if path is None:
        return Solution(problem.start_q[None], dt, elapsed, info.get("compile_s", 0.0), info)
    return Solution(retime(robot, path, dt), dt, elapsed, info.get("compile_s", 0.0), {**info, "waypoints": len(path)})


def zlib_hash(name: str) -> int:
    """A stable 31-bit hash of a problem name (seeds per problem, independent of order)."""
    return zlib.crc32(name.encode()) & 0x7FFFFFFF
