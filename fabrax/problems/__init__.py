"""Motion problems: start, goal and scene, validated at the boundary."""

from fabrax.problems.problem import Problem, batch, make_problem, validate

__all__ = ["Problem", "batch", "make_problem", "validate"]
