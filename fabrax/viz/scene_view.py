"""Scene primitives (cuboids, cylinders, spheres, points) as viser nodes."""

from __future__ import annotations

import numpy as np

from fabrax.scene import Scene, to_dict

OBSTACLE = (200, 120, 60)


def draw_scene(server, scene: Scene | dict, name: str = "/scene", color=OBSTACLE, opacity: float | None = None) -> list:
    """Add every real primitive of `scene` (a `Scene` or its dict form) under `name`; returns the handles
    in obstacle order (point clouds last)."""
    data = to_dict(scene) if isinstance(scene, Scene) else scene
    handles = []
    for i, o in enumerate(data["obstacles"]):
        pose = dict(position=tuple(o["center"]), wxyz=tuple(o.get("quat_wxyz", (1.0, 0.0, 0.0, 0.0))))
        path = f"{name}/{o['type']}_{i}"
        if o["type"] == "cuboid":
            handles.append(server.scene.add_box(path, color=color, dimensions=tuple(o["size"]), opacity=opacity, **pose))
        elif o["type"] == "cylinder":
            handles.append(server.scene.add_cylinder(path, radius=o["radius"], height=o["length"], color=color, opacity=opacity, **pose))
        elif o["type"] == "sphere":
            handles.append(server.scene.add_icosphere(path, radius=o["radius"], color=color, opacity=opacity, position=pose["position"]))
        else:
            raise ValueError(f"obstacle {i}: unknown type '{o['type']}'")
    if data.get("points"):
        pts = np.asarray(data["points"], np.float32)
        handles.append(server.scene.add_point_cloud(f"{name}/points", points=pts, colors=color, point_size=0.01))
    return handles
