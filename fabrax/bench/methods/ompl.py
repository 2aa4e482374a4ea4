"""OMPL's sampling planners as a method (the bindings: `fabrax.bench.ompl`)."""

from __future__ import annotations

import dataclasses

from fabrax.bench.methods.base import Solution, planned
from fabrax.problems.problem import Problem
from fabrax.robot.robot import Robot


@dataclasses.dataclass
class OMPLMethod:
    """An OMPL planner (RRTConnect, BITstar, BiEST, AITstar, ...) on the joint space, state and motion
    validity from the same sphere checker (a motion validator checks each edge's interpolated
    states in one batched call), path simplification, then rest-to-rest retiming (`retime`).
    Planning time is solve plus simplification; compiling the checker is reported apart."""

    planner: str = "RRTConnect"
    budget_s: float = 1.2
    simplify: bool = True
    name: str = "rrtconnect"
    dt: float = 0.01
    resolution: float = 1.0 / 32.0
    first_solution: bool = False  # optimising planners stop at their first solution (`fabrax.bench.ompl.plan`)

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]:
        from fabrax.bench.ompl import plan

        args = (self.planner, self.budget_s, self.simplify, self.resolution, self.first_solution)
        return [planned(robot, p, *plan(robot, p, *args), self.dt) for p in problems]


def build(m: dict, cfg: dict, robot: Robot) -> OMPLMethod:
    """`type: ompl` (configs/method/{rrtconnect,aitstar,...}.yaml)."""
    return OMPLMethod(dt=cfg["dt"], **m)
