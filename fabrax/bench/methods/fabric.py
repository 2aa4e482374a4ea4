"""The pure geometric fabric aimed straight at the goal (`gf`, `gf_joint`)."""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import jax
import numpy as np

from fabrax.bench.methods.base import Solution
from fabrax.problems.problem import Problem, batch
from fabrax.robot.robot import Robot
from fabrax.scene import common_capacity


@dataclasses.dataclass
class FabricMethod:
    """The pure fabric aimed straight at the goal, rolled out for at most t_max at dt (gfcs_paper:
    7 s at 0.01 s). aim="pose" (`gf`, the papers' baseline): the end-effector attractor aimed at the
    goal's pose, a joint goal becoming the null-space posture; aim="joint" (`gf_joint`): the joint
    attractor aimed at a joint goal. stop: "goal" ends a rollout at the aim's goal test, "posture"
    once the posture has arrived too; settle: and every joint slower than this (see `rollout.reach`)."""

    fabric: Any
    params: Any
    name: str = "gf"
    aim: str = "pose"
    stop: str = "goal"
    settle: float | None = 0.05  # rad/s: a rollout ends at the goal at rest (None: at the first goal-test hit)
    dt: float = 0.01
    t_max: float = 7.0
    batch_size: int = 64
    _run: Any = dataclasses.field(default=None, repr=False)  # a Compiled rollout, kept across calls

    @property
    def criterion(self) -> str:
        """The success criterion that matches the aim (the runner's default)."""
        return "pose" if self.aim == "pose" else "auto"

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]:
        from fabrax.compiled import Compiled
        from fabrax.rollout import reach

        if self._run is None:
            steps = int(round(self.t_max / self.dt))
            self._run = Compiled(jax.jit(lambda b: reach(self.fabric, self.params, b, self.aim, self.stop, self.settle, dt=self.dt, steps=steps)))
        out: list[Solution] = []
        for start in range(0, len(problems), self.batch_size):
            chunk = problems[start : start + self.batch_size]
            size = min(self.batch_size, 1 << (len(chunk) - 1).bit_length())  # few batch shapes: few compilations
            # one shape per batch: the largest of its scenes, rounded to 8 slots per kind (`Scene.rounded`)
            cap = common_capacity([p.scene for p in chunk])
            padded = [dataclasses.replace(p, scene=p.scene.pad(**cap)) for p in chunk + [chunk[-1]] * (size - len(chunk))]
            b = batch(padded)
            run, compile_s = self._run.get(b)
            t0 = time.perf_counter()
            tr = jax.block_until_ready(run(b))
            per = (time.perf_counter() - t0) / len(chunk)
            q, length = np.asarray(tr.q), np.asarray(tr.length)
            for k in range(len(chunk)):
                out.append(
                    Solution(
                        q[k, : length[k]],
                        self.dt,
                        per,
                        compile_s if k == 0 else 0.0,
                        {"fabric_reached": bool(tr.reached[k]), "t_goal": float(tr.t_goal[k]), "batch": len(chunk)},
                    )
                )
        return out


def build(m: dict, cfg: dict, robot: Robot) -> FabricMethod:
    """`type: fabric` (configs/method/gf*.yaml) with the run's fabric, goal frame, dt and t_max."""
    from fabrax import config

    fabric, params = config.load_fabric(robot, {**cfg["fabric"], "goal_frame": cfg["frame"]})
    return FabricMethod(fabric, params, dt=cfg["dt"], t_max=cfg["t_max"], **m)
