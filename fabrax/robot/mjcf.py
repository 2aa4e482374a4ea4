"""MJCF (MuJoCo's model format) generated from a `Robot`: the same kinematic tree, the URDF's
inertials, and the robot's collision spheres as its collision geometry, plus padded slots for a
scene's obstacle primitives. Nothing is downloaded; any URDF arm that builds a `Robot` works.

Collision filtering: robot geoms have contype 1 / conaffinity 2 and obstacle geoms contype 2 /
conaffinity 1, so MuJoCo tests robot-obstacle pairs only (self-collision is the fabric's and the
checker's business). Obstacle slots start far below the floor; `fabrax.rl.mjx_sim` moves and sizes
them per scene.
"""

from __future__ import annotations

import jaxlie
import numpy as np

from fabrax.robot.robot import Robot

PARKED = (0.0, 0.0, -10.0)  # where unused obstacle slots wait
OBSTACLE_KINDS = {"cuboids": "box", "cylinders": "cylinder", "spheres": "sphere"}


def _v(a) -> str:
    return " ".join(f"{float(x):.9g}" for x in np.ravel(a))


def _quat(r: np.ndarray) -> str:
    return _v(np.asarray(jaxlie.SO3.from_matrix(np.asarray(r, float)).wxyz))


def obstacle_geom_names(capacity: dict[str, int]) -> dict[str, list[str]]:
    """Names of the obstacle slots, per primitive kind, in slot order."""
    return {kind: [f"obstacle_{kind}_{i}" for i in range(int(capacity.get(kind, 0)))] for kind in OBSTACLE_KINDS}


def to_mjcf(robot: Robot, capacity: dict[str, int] | None = None, timestep: float = 1.0 / 120.0, armature: float = 0.1) -> str:
    """The MJCF string of `robot` with `capacity` obstacle slots (e.g. {"cuboids": 32, "cylinders": 4}).

    Bodies follow the robot's joint frames; a frame's inertial is the URDF links it carries
    (`Robot.frame_mass`, `frame_com`, `frame_inertia`); a frame without mass gets a small one, as
    MuJoCo needs for a moving body. `armature` (kg m^2) is added to every joint (rotor inertia).
    No actuators: the controller applies joint torques (`qfrc_applied`).
    """
    n = robot.dof
    mass = np.zeros(n + 1) if robot.frame_mass is None else np.asarray(robot.frame_mass, float)
    com = np.zeros((n + 1, 3)) if robot.frame_com is None else np.asarray(robot.frame_com, float)
    inertia = np.zeros((n + 1, 3, 3)) if robot.frame_inertia is None else np.asarray(robot.frame_inertia, float)
    axis, origin_r, origin_t = (np.asarray(a, float) for a in (robot.joint_axis, robot.joint_origin_r, robot.joint_origin_t))
    lower, upper = np.asarray(robot.lower, float), np.asarray(robot.upper, float)
    s_frame, s_local, s_radius = (
        np.asarray(robot.collision.frame),
        np.asarray(robot.collision.local, float),
        np.asarray(robot.collision.radius, float),
    )

    def geoms(frame: int, indent: str) -> list[str]:
        return [
            f'{indent}<geom name="sphere_{s}" type="sphere" size="{s_radius[s]:.9g}" pos="{_v(s_local[s])}" contype="1" conaffinity="2" group="1"/>'
            for s in np.flatnonzero(s_frame == frame)
        ]

    children = {f: [k for k in range(n) if robot.joint_parent[k] + 1 == f] for f in range(n + 1)}

    def body(k: int, depth: int) -> list[str]:
        f, ind = k + 1, "  " * depth
        out = [f'{ind}<body name="{robot.joint_names[k]}_body" pos="{_v(origin_t[k])}" quat="{_quat(origin_r[k])}">']
        if mass[f] > 0:
            i = inertia[f]
            full = _v([i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]])
            out.append(f'{ind}  <inertial pos="{_v(com[f])}" mass="{mass[f]:.9g}" fullinertia="{full}"/>')
        else:
            out.append(f'{ind}  <inertial pos="0 0 0" mass="0.001" diaginertia="1e-6 1e-6 1e-6"/>')
        kind = "hinge" if robot.joint_revolute[k] else "slide"
        limited = np.isfinite(lower[k]) and np.isfinite(upper[k])
        rng = f' range="{lower[k]:.9g} {upper[k]:.9g}"' if limited else ""
        joint = f'name="{robot.joint_names[k]}" type="{kind}" axis="{_v(axis[k])}" limited="{str(limited).lower()}"{rng} armature="{armature:.9g}"'
        out.append(f"{ind}  <joint {joint}/>")
        out += geoms(f, ind + "  ")
        for c in children[f]:
            out += body(c, depth + 1)
        out.append(f"{ind}</body>")
        return out

    world = geoms(0, "    ")
    for k in children[0]:
        world += body(k, 2)
    for kind, names in obstacle_geom_names(capacity or {}).items():
        size = {"cuboids": "0.01 0.01 0.01", "cylinders": "0.01 0.01", "spheres": "0.01"}[kind]
        world += [
            f'    <geom name="{g}" type="{OBSTACLE_KINDS[kind]}" size="{size}" pos="{_v(PARKED)}" contype="2" conaffinity="1" group="2"/>'
            for g in names
        ]
    return "\n".join(
        [
            f'<mujoco model="{robot.name}">',
            '  <compiler angle="radian" inertiafromgeom="false" autolimits="false"/>',
            f'  <option timestep="{timestep:.9g}"/>',
            "  <worldbody>",
            *world,
            "  </worldbody>",
            "</mujoco>",
        ]
    )
