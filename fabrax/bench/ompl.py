"""OMPL baselines (optional: `pip install -e ".[bench]"`, which pins `ompl==1.7.0`).

Planners run on the joint space with the benchmark's own checker: a state is
valid when its collision spheres clear the scene and each other and it is
within the joint limits; a motion validator checks every edge at the checker's
resolution. Both call the numba-compiled copy of the checker
(`fabrax.check.native`), not JAX, so that a callback costs
microseconds, as OMPL's C++ users' checkers do. OMPL 1.7.0's Python module crashes
while the interpreter shuts down, so programs that load it end with
`os._exit` (see `fabrax.bench.cli`).
"""

from __future__ import annotations

import time

import numpy as np

from fabrax.check.checker import densify
from fabrax.check.native import NativeChecker
from fabrax.problems.problem import Problem
from fabrax.robot.robot import Robot

PLANNERS = ("RRTConnect", "BITstar", "BiEST", "AITstar", "RRTstar", "PRM")


def available() -> tuple[str, ...]:
    """The planners the installed OMPL binds (empty if OMPL is not installed)."""
    try:
        from ompl import geometric as og
    except ImportError:
        return ()
    return tuple(p for p in PLANNERS if hasattr(og, p))


class _Checker:
    """State and motion validity from the native (numba) checker, equal to the exact checker: no JAX
    dispatch per OMPL callback. A motion's states at the checker's resolution are checked in order,
    stopping at the first invalid one."""

    def __init__(self, robot: Robot, problem: Problem, resolution: float):
        self.native, self.resolution = NativeChecker(robot, problem.scene), resolution
        self.calls = self.states = 0

    def warm_up(self) -> None:
        """Compile (or load numba's cache) before the planner's clock starts."""
        self.native.all_valid(np.zeros((1, self.native.dof)))

    def valid(self, q: np.ndarray) -> bool:
        self.calls += 1
        self.states += 1
        return self.native.all_valid(q)

    def motion(self, a: np.ndarray, b: np.ndarray) -> bool:
        dense = densify(np.stack([a, b]), self.resolution)[0][1:]  # OMPL checked the start state
        self.calls += 1
        self.states += len(dense)
        return self.native.all_valid(dense)


def plan(
    robot: Robot,
    problem: Problem,
    planner: str,
    budget_s: float,
    simplify: bool,
    resolution: float,
    first_solution: bool = False,
    max_states: int | None = None,
    seed: int | None = None,
):
    """A collision-free joint path (W, n) from start to the joint goal, or None; and info. With
    `first_solution`, an optimising planner (AIT*, BIT*, RRT*) stops at its first solution instead
    of refining it until the budget ends (success within the budget is the same; the time is the
    time to a first solution).

    Deterministic runs: `max_states` ends the search once the checker has checked that many
    states (instead of after `budget_s`, which then does not apply), and `seed` (> 0) re-seeds
    OMPL's generator of random seeds first, so the same problem gives the same path on any machine
    at any load."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    if seed is not None:
        if seed <= 0:
            raise ValueError(f"seed must be a positive integer (OMPL's RNG.setSeed), got {seed}")
        ou.setLogLevel(ou.LOG_NONE)  # re-seeding after the first RNG logs an error, but takes effect
        ou.RNG.setSeed(int(seed))
    ou.setLogLevel(ou.LOG_ERROR)
    if not hasattr(og, planner):
        raise ValueError(
            f"the installed OMPL does not bind planner '{planner}' (bound: {', '.join(available())}); ompl 1.7.0 binds all of {PLANNERS}"
        )
    if problem.goal_q is None:
        raise ValueError(f"{problem.name}: OMPL baselines plan to joint goals; this problem has a pose goal")
    n = robot.dof
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for j in range(n):
        bounds.setLow(j, float(robot.lower[j]))
        bounds.setHigh(j, float(robot.upper[j]))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    check = _Checker(robot, problem, resolution)
    t0 = time.perf_counter()
    check.warm_up()
    compile_s = time.perf_counter() - t0
    as_array = lambda s: np.array([s[j] for j in range(n)])  # noqa: E731
    si.setStateValidityChecker(ob.StateValidityCheckerFn(lambda s: check.valid(as_array(s))))

    class Motion(ob.MotionValidator):
        def checkMotion(self, s1, s2, *last_valid):
            return check.motion(as_array(s1), as_array(s2))

    motion = Motion(si)
    si.setMotionValidator(motion)
    si.setup()
    start, goal = ob.State(space), ob.State(space)
    q0, q1 = (np.clip(q, robot.lower, robot.upper) for q in (problem.start_q, problem.goal_q))  # validated to 1e-6
    for j in range(n):
        start[j] = float(q0[j])
        goal[j] = float(q1[j])
    pdef = ob.ProblemDefinition(si)
    pdef.setStartAndGoalStates(start, goal)
    objective = ob.PathLengthOptimizationObjective(si)
    if first_solution:
        objective.setCostThreshold(ob.Cost(float("inf")))  # any solution satisfies the objective: the planner returns
    pdef.setOptimizationObjective(objective)
    p = getattr(og, planner)(si)
    p.setProblemDefinition(pdef)
    p.setup()
    t0 = time.perf_counter()
    if max_states is not None:
        status = p.solve(ob.PlannerTerminationCondition(ob.PlannerTerminationConditionFn(lambda: check.states >= max_states)))
    else:
        status = p.solve(budget_s)
    solve_s = time.perf_counter() - t0
    info = {
        "planner": planner,
        "status": str(status),
        "solve_s": solve_s,
        "simplify_s": 0.0,
        "compile_s": compile_s,
        "first_solution": first_solution,
    }
    if not pdef.hasExactSolution():
        return None, {**info, "validity_calls": check.calls, "states_checked": check.states}
    path = pdef.getSolutionPath()
    if simplify:
        t0 = time.perf_counter()
        og.PathSimplifier(si).simplifyMax(path)
        info["simplify_s"] = time.perf_counter() - t0
    waypoints = np.array([as_array(path.getState(i)) for i in range(path.getStateCount())])
    return waypoints, {**info, "validity_calls": check.calls, "states_checked": check.states}


def solvable(budget_s: float):
    """check(robot, problem) -> bool: RRTConnect finds a path from the start to the generator's goal
    configuration (`meta["goal_q"]`) under the exact checker within budget_s reference seconds (the
    MπNets-faithful set's filter, `fabrax.problems.load`): a budget of checked states from a fixed
    seed, so the verdict does not depend on the machine or its load."""
    from fabrax.problems.load import SOLVABLE_SEED, solvable_states

    states = solvable_states(budget_s)

    def check(robot: Robot, p: Problem) -> bool:
        import dataclasses

        q_goal = np.asarray(p.meta["goal_q"])
        path, _ = plan(robot, dataclasses.replace(p, goal_q=q_goal), "RRTConnect", budget_s, False, 1.0 / 32.0, max_states=states, seed=SOLVABLE_SEED)
        return path is not None

    return check
