"""Benchmark harness: the exact checker, metrics and reports."""

from fabrax.problems.checker import RESOLUTION, CheckResult, check_path, densify
from fabrax.problems.clearance import state_clearances

__all__ = ["RESOLUTION", "CheckResult", "check_path", "densify", "state_clearances"]
