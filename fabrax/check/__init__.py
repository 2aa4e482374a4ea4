"""The exact checker: one judge of every method's path (DESIGN.md, "Benchmarks").

`clearance` gives per-sphere clearances of a state against a scene, self-collision pairs and
joint limits in JAX; `checker` densifies a path and judges it; `native` is the numba copy of
the clearances for sampling planners' per-state callbacks. It lives below the pillars because
GFCS's reactive study, the skills and the RL env judge collisions with it too.
"""

from fabrax.check.checker import RESOLUTION, CheckResult, check_path, densify
from fabrax.check.clearance import clearances, state_clearances

__all__ = ["RESOLUTION", "CheckResult", "check_path", "clearances", "densify", "state_clearances"]
