"""Scenes: padded pytrees of primitives and exact signed distances."""

from fabrax.scene.primitives import (
    COMMON_CAPACITY,
    Cuboids,
    Cylinders,
    PointCloud,
    Scene,
    Spheres,
    common_capacity,
    empty,
    from_dict,
    load,
    stack,
    to_dict,
)
from fabrax.scene.sdf import FAR, distance, distance_kinematics, primitive_mask, signed_distances

__all__ = [
    "COMMON_CAPACITY",
    "common_capacity",
    "FAR",
    "Cuboids",
    "Cylinders",
    "PointCloud",
    "Scene",
    "Spheres",
    "distance",
    "distance_kinematics",
    "empty",
    "from_dict",
    "load",
    "primitive_mask",
    "signed_distances",
    "stack",
    "to_dict",
]
