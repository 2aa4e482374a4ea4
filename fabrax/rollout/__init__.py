"""Rollouts: integrators, scanned rollouts with time to goal, command sequences."""

from fabrax.rollout.rollout import INTEGRATORS, accel, integrate, reach, rollout, rollout_population, rollout_sequence
from fabrax.rollout.trajectory import Trajectory, to_numpy

__all__ = ["INTEGRATORS", "Trajectory", "accel", "integrate", "reach", "rollout", "rollout_population", "rollout_sequence", "to_numpy"]
