"""The fabric term library for arms (thesis §3.3; gfcs_paper §III), one module per term.

Every term follows the transform-tree recipe (eqs. 2.55-2.59): a Finsler energy L_e and an HD2
geometry h2 in the term's task space are pulled back as (J^T M_e J, J^T M_e (h2 + Jdot qd))
together with the pulled-back energy force J^T (f_e + M_e Jdot qd); forcing potentials enter as
J^T dpsi/dx (eq. 2.60). Distance terms reduce all obstacles of a sphere to a 3x3 metric and a
3-vector before one pullback per sphere (`kernels`). A config's term `type` names its factory in
`TERMS`.
"""

from fabrax.fabrics.terms.base import SPHERE_LANES, Contribution, Term, TermInputs
from fabrax.fabrics.terms.damping import damping
from fabrax.fabrics.terms.distance import RESOLUTIONS
from fabrax.fabrics.terms.ee_attractor import ee_attractor
from fabrax.fabrics.terms.joint_attractor import joint_attractor
from fabrax.fabrics.terms.joint_limits import joint_limits
from fabrax.fabrics.terms.obstacles import obstacle_repulsion
from fabrax.fabrics.terms.self_collision import self_collision
from fabrax.robot.collision import closest_link_pairs

TERMS = {
    "joint_attractor": joint_attractor,
    "joint_limits": joint_limits,
    "damping": damping,
    "ee_attractor": ee_attractor,
    "obstacle_repulsion": obstacle_repulsion,
    "self_collision": self_collision,
}

__all__ = [
    "RESOLUTIONS",
    "SPHERE_LANES",
    "TERMS",
    "Contribution",
    "Term",
    "TermInputs",
    "closest_link_pairs",
    "damping",
    "ee_attractor",
    "joint_attractor",
    "joint_limits",
    "obstacle_repulsion",
    "self_collision",
]
