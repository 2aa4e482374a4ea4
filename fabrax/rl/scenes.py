"""The guide's training scenes (thesis §3.4.1), built once on the host and stacked for `reset`.

Dataset scenes are MotionBenchMaker *train* problems (1-50 of each class) with their start and the
hand pose of their joint goal; generated scenes are cuboid forests, surrounding shelves and flying
cuboids. Every scene also gets `configs_per_scene` collision-free configurations by rejection
sampling, from which `reset` draws the sampled start/goal modes of Table 3.1 (generated scenes
always use those). Scenes are cut to their used slots and padded to the largest, and the static basis point set of every scene
(eq. 3.16) is computed here once, so that a reset only gathers.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fabrax.problems import generators
from fabrax.problems.problem import Problem
from fabrax.rl.config import EnvConfig
from fabrax.rl.observations import bps_vectors, grid_points
from fabrax.robot.robot import Robot
from fabrax.scene import Scene, from_dict, stack

GENERATORS = {
    "cuboid_forest": generators.cuboid_forest,
    "shelves": generators.surrounding_shelves,
    "flying_cuboids": lambda rng: generators.flying_cuboids(rng, n=(10, 12), r_min=0.3, r_max=1.2),
}


@struct.dataclass
class ScenePool:
    scene: Scene  # (P, ...) padded to one capacity
    bps: jax.Array  # (P, c, c, c, 3) static basis point vectors
    start_q: jax.Array  # (P, n) predefined start
    goal_q: jax.Array  # (P, n) configuration whose hand pose is the predefined goal
    configs: jax.Array  # (P, K, n) sampled collision-free configurations
    dataset: jax.Array  # (P,) bool: predefined start/goal are a dataset problem's (else sampled)
    names: tuple = struct.field(pytree_node=False, default=())

    @property
    def size(self) -> int:
        return int(self.start_q.shape[0])


def _fit(scene: Scene, capacity: dict[str, int], name: str) -> Scene:
    """The scene cut to its used slots, refused when a kind is over `capacity` (the pool then pads
    every scene to the largest, so it is never wider than the scenes need)."""
    used = {"cuboids": scene.cuboids, "cylinders": scene.cylinders, "spheres": scene.spheres}
    for kind, prims in used.items():
        n = int(np.asarray(prims.mask).sum())
        if n > capacity.get(kind, 0):
            raise ValueError(f"scene '{name}' has {n} {kind}, over env.scenes.capacity.{kind}={capacity.get(kind, 0)}")
    if int(np.asarray(scene.cloud.mask).sum()):
        raise ValueError(f"scene '{name}' has a point cloud; the guide's scenes are primitives only")

    def used_only(prims):
        keep = np.flatnonzero(np.asarray(prims.mask))
        return jax.tree.map(lambda a: jnp.asarray(np.asarray(a)[keep]), prims)

    empty_cloud = jax.tree.map(lambda a: a[:0], scene.cloud)
    return Scene(used_only(scene.cuboids), used_only(scene.cylinders), used_only(scene.spheres), empty_cloud)


def _configs(robot: Robot, scene: Scene, sc, rng, name: str, start, goal) -> np.ndarray:
    """`sc.configs_per_scene` valid configurations for the sampled modes: uniform within the limits,
    else, in a scene too cramped for that (a dataset problem inside shelves or drawers), half near
    its start and half near its goal (a quarter of each joint's range around them, 5 mm clear)."""
    n = sc.configs_per_scene
    try:
        return generators.sample_configs(robot, scene, n, rng, margin=sc.margin)
    except ValueError:
        if start is None:
            raise ValueError(f"scene '{name}': could not find {n} valid configurations") from None
    try:
        margin = min(sc.margin, 0.005)  # the clearance MπNets-faithful starts and goals are drawn with
        halves = ((start, n - n // 2), (goal, n // 2))
        near = [generators.sample_configs(robot, scene, k, rng, margin=margin, around=q, spread=0.25) for q, k in halves]
    except ValueError:
        raise ValueError(f"scene '{name}': could not find {n} valid configurations, even near its start and goal") from None
    return np.concatenate(near)


def build_pool(robot: Robot, cfg: EnvConfig, problems: list[Problem] = (), frame: str | None = None) -> ScenePool:
    """A `ScenePool` of the dataset `problems` (e.g. `load_mbm(split='train')`; invalid ones are
    skipped; a pose goal becomes the generator's goal configuration where the problem carries one
    (`meta["goal_q"]`, MπNets-faithful problems), else the collision-free IK solution of `frame`
    nearest the start, and a problem without one is skipped) and the generated scenes of `cfg.scenes`."""
    frame = frame or robot.ee_frame
    sc = cfg.scenes
    capacity = dict(sc.capacity)
    rng = np.random.default_rng(sc.seed)
    rows = []  # (name, scene, start, goal, dataset)
    for p in problems:
        if not p.valid:
            continue
        goal = p.goal_q if p.goal_q is not None else (p.meta or {}).get("goal_q")
        if goal is None:  # a pose goal: the pool stores goals as configurations
            goal = generators.ik_goal(robot, p, frame, rng)
            if goal is None:
                continue
        rows.append((p.name, p.scene, np.asarray(p.start_q), np.asarray(goal), True))
    for kind, n in sc.generated:
        for k in range(n):
            rows.append((f"{kind}/{k:04d}", from_dict(GENERATORS[kind](rng)), None, None, False))
    if not rows:
        raise ValueError("the scene pool is empty: no valid dataset problem and no generated scene")
    scenes, starts, goals, configs, dataset, names = [], [], [], [], [], []
    for name, scene, start, goal, is_data in rows:
        scene = _fit(scene, capacity, name)
        qs = _configs(robot, scene, sc, rng, name, start, goal)
        scenes.append(scene)
        starts.append(qs[0] if start is None else start)
        goals.append(qs[1] if goal is None else goal)
        configs.append(qs)
        dataset.append(is_data)
        names.append(name)
    scene = stack(scenes)
    grid = grid_points(cfg.bps_cells, *cfg.bounds)
    bps = jax.jit(jax.vmap(lambda s: bps_vectors(s, grid, cfg.bps_clip)))(scene)
    f32 = lambda a: jnp.asarray(np.asarray(a), jnp.float32)  # noqa: E731
    return ScenePool(scene, bps, f32(starts), f32(goals), f32(configs), jnp.asarray(dataset), tuple(names))


def sample_episode(pool: ScenePool, modes: jax.Array, key: jax.Array):
    """(scene index, start, goal configuration, mode) for one reset: a scene uniformly, then a mode of
    Table 3.1 with probabilities `modes` for dataset scenes; generated scenes always sample both."""
    k_scene, k_mode, k_pick = jax.random.split(key, 3)
    i = jax.random.randint(k_scene, (), 0, pool.size)
    mode = jnp.where(pool.dataset[i], jax.random.choice(k_mode, 4, p=modes), 3)
    configs = pool.configs[i]
    a, b = jax.random.choice(k_pick, configs.shape[0], (2,), replace=False)
    start = jnp.where(mode < 2, pool.start_q[i], configs[a])
    goal = jnp.where(mode % 2 == 0, pool.goal_q[i], configs[b])
    return i, start, goal, mode
