"""Browser viewer on viser: robot meshes and collision spheres, scenes, goals, trajectory playback,
live fabric control and a benchmark results browser (`fabrax view ...`)."""

from fabrax.viz.robot_view import RobotView, visual_urdf
from fabrax.viz.scene_view import draw_scene

__all__ = ["RobotView", "draw_scene", "visual_urdf"]
