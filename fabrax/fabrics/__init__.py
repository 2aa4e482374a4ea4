"""Geometric fabrics: spec algebra, energies, the arm term library and the combined fabric."""

from fabrax.fabrics.arm import ArmFabric, build_arm_fabric
from fabrax.fabrics.fabric import Fabric, FabricEval, Params, unforced
from fabrax.fabrics.lagrangian import eom, hd2_geometry
from fabrax.fabrics.limits import acceleration_box, max_acceleration, solve_in_box, solve_shrinking
from fabrax.fabrics.spec import Spec, combine, energize, energize_alpha, pullback, solve
from fabrax.fabrics.terms import (
    Contribution,
    Term,
    TermInputs,
    damping,
    ee_attractor,
    joint_attractor,
    joint_limits,
    obstacle_repulsion,
    self_collision,
)

__all__ = [
    "ArmFabric",
    "Contribution",
    "Fabric",
    "FabricEval",
    "Params",
    "Spec",
    "Term",
    "TermInputs",
    "acceleration_box",
    "build_arm_fabric",
    "combine",
    "damping",
    "ee_attractor",
    "energize",
    "energize_alpha",
    "eom",
    "hd2_geometry",
    "joint_attractor",
    "joint_limits",
    "max_acceleration",
    "obstacle_repulsion",
    "pullback",
    "self_collision",
    "solve",
    "solve_in_box",
    "solve_shrinking",
    "unforced",
]
