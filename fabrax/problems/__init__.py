"""Motion problems: start, goal and scene, validated at the boundary."""

from fabrax.problems.problem import Problem, batch, flag, make_problem, validate

__all__ = ["Problem", "batch", "flag", "make_problem", "validate"]
