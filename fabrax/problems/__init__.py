"""Motion problems: start, goal and scene, validated at the boundary."""

from fabrax.problems.problem import Problem, ProblemBatch, batch, flag, make_problem, validate

__all__ = ["Problem", "ProblemBatch", "batch", "flag", "make_problem", "validate"]
