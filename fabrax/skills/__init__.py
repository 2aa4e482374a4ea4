"""Motion skills on learned Riemannian manifolds (riemannian_motion_skills_paper): VAEs whose decoders
define a metric, spline geodesics, obstacle-aware ambient metrics, execution with the fabric.
The metric matrix itself is `fabrax.skills.metric.metric` (the submodule keeps its name here)."""

from fabrax.skills.geodesic import CurveMetric, Geodesic, GeodesicConfig, shortest, solver
from fabrax.skills.metric import NONE, Obstacles, ambient, chord2, curve_metric, magnification, obstacles, speed2, speed2_fn
from fabrax.skills.vae import JointVAE, TaskVAE, VAEConfig, fit_joint, fit_task, load, save

__all__ = [
    "NONE",
    "CurveMetric",
    "Geodesic",
    "GeodesicConfig",
    "JointVAE",
    "Obstacles",
    "TaskVAE",
    "VAEConfig",
    "ambient",
    "chord2",
    "curve_metric",
    "fit_joint",
    "fit_task",
    "load",
    "magnification",
    "obstacles",
    "save",
    "shortest",
    "solver",
    "speed2",
    "speed2_fn",
]
