"""A robot in the viewer: its URDF meshes (viser's ViserUrdf) posed by fabrax joint vectors, and
its collision spheres from fabrax's own kinematics."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
import trimesh
import yourdfpy

from fabrax.robot.kinematics import sphere_centers
from fabrax.robot.robot import Robot, resolve_urdf
from fabrax.robot.urdf import resolve_uri

_centers = jax.jit(sphere_centers)


def visual_urdf(robot_cfg: dict) -> yourdfpy.URDF:
    """The robot's URDF with its visual meshes (package:// resolved as fabrax resolves them)."""
    path = Path(resolve_urdf(robot_cfg.get("urdf")))
    return yourdfpy.URDF.load(str(path), load_meshes=True, build_scene_graph=True, filename_handler=lambda fname: resolve_uri(fname, path.parent))


class RobotView:
    """Draw `robot` at joint vectors q (the robot's active joints; held joints at their config values).

    color/opacity make a ghost (goals, commands). `show_spheres` toggles the collision spheres.
    """

    def __init__(self, server, robot: Robot, robot_cfg: dict, name: str = "/robot", color=None, opacity: float | None = None, urdf=None):
        from viser.extras import ViserUrdf

        self.robot = robot
        override = None if color is None else (*[c / 255 for c in color], 1.0 if opacity is None else opacity)
        self.urdf = ViserUrdf(server, urdf or visual_urdf(robot_cfg), root_node_name=name, mesh_color_override=override)
        names = list(self.urdf.get_actuated_joint_names())
        held = dict(robot_cfg.get("held") or {})
        self._cfg = np.asarray([held.get(n, 0.0) for n in names], np.float64)
        self._slots = []
        for j in robot.joint_names:
            if j not in names:
                raise ValueError(f"joint '{j}' of robot '{robot.name}' is not an actuated joint of its URDF")
            self._slots.append(names.index(j))
        sphere = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
        r = np.asarray(robot.collision.radius)
        self.spheres = server.scene.add_batched_meshes_simple(
            f"{name}_spheres",
            vertices=np.asarray(sphere.vertices, np.float32),
            faces=np.asarray(sphere.faces, np.uint32),
            batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (len(r), 1)).astype(np.float32),
            batched_positions=np.zeros((len(r), 3), np.float32),
            batched_scales=r.astype(np.float32),
            batched_colors=(90, 200, 255),
            opacity=0.5,
            visible=False,
        )
        self.q = None

    def update(self, q) -> None:
        q = np.asarray(q, np.float64)
        cfg = self._cfg.copy()
        cfg[self._slots] = q
        self.urdf.update_cfg(cfg)
        if self.spheres.visible:
            self.spheres.batched_positions = np.asarray(_centers(self.robot, np.asarray(q, np.float32)), np.float32)
        self.q = q

    def show_spheres(self, visible: bool) -> None:
        self.spheres.visible = visible
        if visible and self.q is not None:
            self.update(self.q)

    def remove(self) -> None:
        self.urdf.remove()
        self.spheres.remove()
