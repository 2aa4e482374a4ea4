"""VAMP's SIMD sampling planners as a method (the bindings: `fabrax.bench.vamp`)."""

from __future__ import annotations

import dataclasses

from fabrax.bench.methods.base import Solution, planned
from fabrax.problems.problem import Problem
from fabrax.robot.robot import Robot


@dataclasses.dataclass
class VAMPMethod:
    """A VAMP planner (rrtc, prm, fcit, aorrtc) with VAMP's own robot model and SIMD collision checks
    (`fabrax.bench.vamp`), its path simplification, then rest-to-rest retiming (`retime`). Planning
    time is VAMP's own solve plus simplification time; the harness re-checks the trajectory with
    the benchmark's checker."""

    planner: str = "rrtc"
    iterations: int = 100_000
    simplify: bool = True
    padding: float = 0.02  # m added to the obstacles VAMP plans around (configs/method/vamp_*.yaml: chosen on train problems)
    name: str = "vamp_rrtc"
    dt: float = 0.01

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]:
        from fabrax.bench.vamp import plan

        return [planned(robot, p, *plan(robot, p, self.planner, self.iterations, self.simplify, self.padding), self.dt) for p in problems]


def build(m: dict, cfg: dict, robot: Robot) -> VAMPMethod:
    """`type: vamp` (configs/method/vamp_*.yaml); a robot VAMP has no model of is refused here."""
    from fabrax.bench.vamp import robot_module

    robot_module(robot)
    return VAMPMethod(dt=cfg["dt"], **m)
