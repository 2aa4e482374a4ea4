"""Robots from URDF: kinematic tree, forward kinematics, limits, collision spheres."""

from fabrax.robot.kinematics import PointKinematics, frame_pose, frame_transforms, keypoints, link_poses, point_kinematics, points, sphere_centers
from fabrax.robot.robot import Robot, build_robot, panda_urdf, resolve_urdf
from fabrax.robot.urdf import KinematicTree, parse_urdf

__all__ = [
    "KinematicTree",
    "PointKinematics",
    "Robot",
    "build_robot",
    "frame_pose",
    "frame_transforms",
    "keypoints",
    "link_poses",
    "panda_urdf",
    "resolve_urdf",
    "parse_urdf",
    "point_kinematics",
    "points",
    "sphere_centers",
]
