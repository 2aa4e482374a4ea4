"""A run's problems from its settings: MotionBenchMaker, the generated MBM-like and MPiNets-like
sets, and the MπNets-faithful set; below the bench and the viewer, which both rebuild a run's
problems from its resolved config.

The settings are the bench's keys (configs/bench.yaml): `problems`, `classes`, `split`, `limit`,
`seed`, `frame`, `ik_goals`, `data_dir`, and for `problems=mpinets` `types` and `solvable_s`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from fabrax.problems.problem import Problem
from fabrax.robot.robot import Robot

KINDS = ("mbm", "mpinets", "mbm_like", "mpinets_like")

# solvable(budget_s) -> check(robot, problem) -> bool: a global planner's verdict within budget_s
Solvable = Callable[[float], Callable[[Robot, Problem], bool]]
# The solvability budget is counted in states the checker checks, not in wall time, so that a set is
# the same on any machine at any load: budget_s seconds are budget_s * SOLVABLE_STATES_PER_S states
# (the 2-core reference machine's rate, docs/bench.md), searched from OMPL's seed SOLVABLE_SEED.
SOLVABLE_STATES_PER_S = 200_000
SOLVABLE_SEED = 1


def load_problems(cfg: dict, robot: Robot, info: dict | None = None, solvable: Solvable | None = None) -> list[Problem]:
    """The run's problems; `info` (if given) receives how a generated set was drawn (mpinets: how
    many were drawn, dropped as unsolvable, failed to generate). `solvable` is the global planner
    that keeps an MπNets-faithful problem (the bench passes OMPL RRTConnect); a cached set is read
    back without calling it."""
    kind = cfg["problems"]
    if kind == "mbm":
        from fabrax.problems.mbm import load_mbm

        return load_mbm(robot, cfg["data_dir"], cfg["classes"], cfg["split"], cfg["limit"])
    if kind in ("mbm_like", "mpinets_like"):
        from fabrax.problems import procedural

        n = cfg["limit"] or 100
        seed = cfg["seed"] + (0 if cfg["split"] != "train" else 10_000)
        problems = procedural.generate(robot, kind, cfg["classes"], n, seed, frame=cfg["frame"])
        return [with_ik_goal(robot, p, cfg["frame"]) for p in problems] if cfg.get("ik_goals") else problems
    if kind == "mpinets":
        drawn = mpinets_set(cfg, robot, solvable=solvable)
        if info is not None:
            info.update(drawn=drawn.drawn, kept=len(drawn.problems), unsolvable=len(drawn.dropped), failed=len(drawn.failed), solvable=drawn.solvable)
        problems = drawn.problems
        return [with_ik_goal(robot, p, cfg["frame"]) for p in problems] if cfg.get("ik_goals") else problems
    raise ValueError(f"problems must be one of {', '.join(KINDS)}, got {kind!r}")


def solvable_states(budget_s: float) -> int:
    """The solvability budget of `budget_s` reference seconds, in checked states."""
    return int(round(float(budget_s) * SOLVABLE_STATES_PER_S))


def solvable_key(budget_s: float) -> str:
    """The name of the solvability check in the MπNets-faithful set's cache key."""
    return f"RRTConnect {float(budget_s)} s = {solvable_states(budget_s):,} checked states, seed {SOLVABLE_SEED}, exact checker"


def mpinets_set(cfg: dict, robot: Robot, progress: bool | None = None, solvable: Solvable | None = None):
    """The MπNets-faithful set of the run (`fabrax.problems.mpinets`): `limit` problems (default 600),
    test seed `seed`, train seed `seed` + 10000, each kept only if `solvable(solvable_s)` solves it
    from its start to the generator's goal configuration (MπNets keeps only problems a global
    planner solves); cached under $FABRAX_CACHE/problems."""
    from fabrax._environment import cache_root
    from fabrax.problems import mpinets

    if cfg["split"] == "all":
        raise ValueError("problems=mpinets has a train and a test split, not all")
    budget = cfg.get("solvable_s")
    check, key = None, None
    if budget:
        if solvable is None:
            raise ValueError("problems=mpinets with solvable_s needs a global planner to keep solvable problems (solvable=)")
        check, key = solvable(budget), solvable_key(budget)
    show = cfg.get("progress", True) if progress is None else progress
    bar = _Progress(int(cfg["limit"] or 600)) if show else None
    seed = cfg["seed"] + (10_000 if cfg["split"] == "train" else 0)
    try:
        return mpinets.generate(
            robot, int(cfg["limit"] or 600), seed, cfg["classes"], cfg.get("types"), cfg["frame"], check, key, Path(cache_root()) / "problems", bar
        )
    finally:
        if bar is not None:
            bar.close()


class _Progress:
    def __init__(self, n: int):
        from tqdm import tqdm

        self.bar = tqdm(total=n, desc="generating mpinets problems", unit="problem")

    def __call__(self, kept: int, drawn: int) -> None:
        self.bar.n = kept
        self.bar.set_postfix(drawn=drawn, refresh=True)

    def close(self) -> None:
        self.bar.close()


def with_ik_goal(robot: Robot, p: Problem, frame: str) -> Problem:
    """A pose-goal problem with a joint goal added: the collision-free IK solution nearest its start
    (seeded by the problem's name), for joint-space methods (GFCS, OMPL); the pose stays the goal
    that pose and keypoint success are judged against. Without a solution the problem is marked
    invalid (reported, not run)."""
    from fabrax.problems.generators import ik_goal

    if p.goal_q is not None or p.goal_pose is None:
        return p
    if "goal_q" in p.meta:  # the generator's own goal configuration (mpinets: the one its solvability check planned to)
        return dataclasses.replace(p, goal_q=np.asarray(p.meta["goal_q"], np.float64))
    goal = ik_goal(robot, p, frame)
    if goal is None:
        return dataclasses.replace(p, valid=False, reason="no collision-free IK solution of the goal pose")
    return dataclasses.replace(p, goal_q=goal)
