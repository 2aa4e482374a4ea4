"""`fabrax view rl`: the RL guide's environment rolling out one episode, played back.

Shown: the scene, the goal pose and its keypoints, the end-effector attractor's target of every
policy step, the exploration map's visited cells, and on a toggle the static basis point vectors
(every second grid point along each axis). Actions come from `policy`:
random (uniform in [-1, 1], curriculum stage 1), switch (stage 2 with the fabric switch on from the
first step: the pure fabric aimed at the goal) or hold (`fabrax.rl.scripted`), or a trained guide
(`checkpoint`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fabrax import config
from fabrax.rl import make_env
from fabrax.rl.observations import grid_points
from fabrax.rl.scripted import POLICIES, episode
from fabrax.robot.kinematics import frame_path
from fabrax.scene import to_dict
from fabrax.viz.app import GOAL, PATHS, Viewer
from fabrax.viz.scene_view import draw_scene

TARGET = (230, 200, 60)
CELLS = (90, 140, 230)
BPS = (160, 160, 160)


def few_scenes(env: dict, n: int = 4) -> dict:
    """`env` with at most `n` scenes of each kind (a prefix of each held-out set): one episode is
    shown, so the viewer builds a few scenes, not the whole evaluation pool."""
    sc = dict(env.get("scenes") or {})
    for key in ("generated", "procedural"):
        if key in sc:  # a mapping, or (kind, count) pairs as settings.json stores them
            sc[key] = {k: min(int(v), n) for k, v in dict(sc[key]).items()}
    if sc.get("mpinets"):
        sc["mpinets"] = min(int(sc["mpinets"]), n)
    if sc.get("mbm_classes"):
        sc["mbm_limit"] = min(int(sc.get("mbm_limit", 50)), n)
    return {**env, "scenes": sc}


def rl_view(viewer: Viewer, fabric_name: str = "panda", policy: str = "random", seed: int = 0, env_cfg: dict | None = None, checkpoint=None) -> dict:
    """Roll one episode out and play it back; returns what happened (steps, success, collision).
    With `checkpoint` (an experiments/rl.py run, or `pretrained`) the trained guide acts, on one of
    the first scenes of its run's held-out evaluation set (`eval_scenes`), with the run's fabric."""
    act, fabric = None, fabric_name
    if checkpoint is not None:
        from fabrax.rl.policy import load_guide
        from fabrax.rl.train import eval_settings

        guide = load_guide(checkpoint)
        act, policy, fabric = guide.act, "guide", guide.settings["fabric"]
        env_cfg = few_scenes(eval_settings(guide.settings["env"], guide.settings["eval_scenes"]))
    elif policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, got '{policy}'")
    server = viewer.server
    loading = server.gui.add_markdown("**Rolling out one episode** (the first call compiles the environment, about 20 s on a laptop CPU)...")
    viewer.nodes.append(loading)
    print("[view] rolling out one episode (the first call compiles the environment, about 20 s on a laptop CPU)...", flush=True)
    cfg = env_cfg or {"scenes": {"generated": {"cuboid_forest": 1, "shelves": 1, "flying_cuboids": 1}, "configs_per_scene": 4}}
    fabric = config.load("fabric", fabric) if isinstance(fabric, str) else fabric
    env = make_env(cfg, viewer.robot, fabric)
    start, (qs, targets, counts, metrics, alive) = jax.jit(lambda k: episode(env, policy, k, act))(jax.random.PRNGKey(seed))
    ep = start.pipeline_state
    steps = int(np.asarray(alive).sum())
    q = np.concatenate([np.asarray(ep.q)[None], np.asarray(qs[:steps]).reshape(-1, env.robot.dof)])

    viewer.nodes += draw_scene(server, to_dict(ep.scene), "/scene")
    goal = dict(position=tuple(np.asarray(ep.goal_pos)), wxyz=tuple(np.asarray(ep.goal_quat)))
    viewer.nodes.append(server.scene.add_frame("/goal_pose", axes_length=0.1, axes_radius=0.005, **goal))
    kp = np.asarray(ep.goal_keypoints, np.float32)
    viewer.nodes.append(server.scene.add_point_cloud("/goal_keypoints", points=kp, colors=GOAL, point_size=0.015))
    target = server.scene.add_frame("/ee_target", axes_length=0.08, axes_radius=0.004)
    centres = np.asarray(env.centres, np.float32)
    cells = server.scene.add_point_cloud("/exploration", points=centres[:1], colors=CELLS, point_size=0.02)
    grid = np.asarray(start.obs["bps"])[::2, ::2, ::2]
    base = np.asarray(grid_points(env.cfg.bps_cells, *env.cfg.bounds))[::2, ::2, ::2].reshape(-1, 3)
    seg = np.stack([base, base + grid.reshape(-1, 3)], axis=1).astype(np.float32)
    bps = server.scene.add_line_segments("/bps", points=seg, colors=BPS, thickness=1.0, thickness_units="screen", visible=False)
    show_bps = server.gui.add_checkbox("BPS vectors", initial_value=False)
    show_bps.on_update(lambda _: setattr(bps, "visible", show_bps.value))
    show_map = server.gui.add_checkbox("exploration map", initial_value=True)
    show_map.on_update(lambda _: setattr(cells, "visible", show_map.value))
    status = server.gui.add_markdown("")
    viewer.nodes += [target, cells, bps, show_bps, show_map, status]
    viewer.ee_line(q, "/path", PATHS[0])
    hand = np.asarray(frame_path(viewer.robot, jnp.asarray(q[[0, -1]], jnp.float32), viewer.frame)[0])
    viewer.look(ep.scene, np.stack([np.array([0.0, 0.0, 0.3]), hand[0], np.asarray(ep.goal_pos, float)]))

    targets, counts = np.asarray(targets), np.asarray(counts)
    dist = np.asarray(metrics["keypoint_distance"])
    sub = env.cfg.substeps

    def at(k):  # fabric step k -> its policy step's target, map and status
        i = min(max(k - 1, 0) // sub, max(steps - 1, 0))
        target.position, target.wxyz = tuple(targets[i, :3]), tuple(targets[i, 3:])
        visited = centres[counts[i] > 0]
        if len(visited):
            cells.points = visited
        cells.visible = show_map.value and len(visited) > 0
        status.content = f"policy step {i + 1}/{steps}, keypoint distance {dist[i]:.3f} m"

    viewer.player([(viewer.arm, q)], env.cfg.fabric_dt, on_frame=at)
    last = max(steps - 1, 0)
    info = {
        "policy": policy,
        "scene": env.pool.names[int(ep.scene_index)],
        "steps": steps,
        "success": bool(np.asarray(metrics["success"])[last]),
        "collision": bool(np.asarray(metrics["collision"])[last]),
        "keypoint_distance": float(dist[last]),
        "fabric_steps": len(q),
    }
    loading.content = outcome(info, env.cfg.fabric_dt)
    return info


def outcome(info: dict, dt: float) -> str:
    """The episode's result as the page shows it (markdown): reached, collided or ran out of time."""
    if info["collision"]:
        what = "**collided**"
    elif info["success"]:
        what = "**reached the goal**"
    else:
        what = "**did not reach the goal** (time ran out)"
    return (
        f"`{info['policy']}` on `{info['scene']}`: {what} after {info['steps']} policy steps "
        f"({(info['fabric_steps'] - 1) * dt:.2f} s), final keypoint distance {info['keypoint_distance']:.3f} m"
    )
