"""GFCS: geometric fabric command sequences optimised by CMA-ES (gfcs_paper §IV)."""

from fabrax.planners.gfcs.cost import population_cost, sequence_cost, to_commands, to_unconstrained
from fabrax.planners.gfcs.solver import GFCSConfig, GFCSResult, solve, solve_batch, uniform_sampler

__all__ = [
    "GFCSConfig",
    "GFCSResult",
    "population_cost",
    "sequence_cost",
    "solve",
    "solve_batch",
    "to_commands",
    "to_unconstrained",
    "uniform_sampler",
]
