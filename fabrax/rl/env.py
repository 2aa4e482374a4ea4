"""The fabric-guided arm environment (thesis §3.4) in brax's `Env` API.

The policy acts at 1 / (substeps fabric_dt) Hz (2 Hz by default) and the fabric is its action
layer at 1 / fabric_dt Hz (60 Hz). An action (Table 3.3) is
    [relative hand translation (3), relative hand rotation, axis-angle (3), joint target (n), switch (1)],
each in [-1, 1]: the translation and rotation (scaled by `ee_translation`, `ee_rotation`, in the
world frame) applied to the current pose of the fabric's goal frame give the end-effector
attractor's target; the joint target, mapped onto the joint limits, aims the posture attractor
that shapes the arm in the null space. Once the switch reads >= `switch_threshold` (stage 2 only)
it latches: the hand target becomes the goal pose and the posture attractor is off for the rest of
the episode.

Rewards (Table 3.5): `sparse_reward` once the mean keypoint distance to the goal is below
`success_distance` (stage 2; the episode ends there), `intrinsic_weight` times the goal-weighted
count reward of eqs. 3.17-3.18 (both stages); a collision, judged by the exact checker on every
fabric step, ends the episode with `-collision_penalty`. The curriculum stage is
`state.info["stage"]` (1 or 2): training advances it by writing that array, without recompiling.
Episodes end on success or collision; the time limit (`EnvConfig.episode_steps`) is brax's
`EpisodeWrapper`'s, so that PPO bootstraps it as a truncation.

Backends: "kinematic" (the arm is the fabric's state) and "mjx" (MuJoCo MJX steps the arm's
dynamics, tracking the fabric with eq. 3.12's PD + inverse-dynamics controller; `fabrax.rl.mjx_sim`).
Both judge collisions with the same exact checker on the arm's own configuration at every fabric
step; the mjx backend also reports MJX's contacts at the step's closest approach and the tracking
error. Everything an episode carries lives in `state.pipeline_state` (an `Episode`), so brax's
auto-reset restores it whole.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
from brax.envs.base import Env, State
from flax import struct

from fabrax.check.clearance import state_clearances
from fabrax.fabrics import ArmFabric, Params, build_arm_fabric
from fabrax.problems.mbm import load_mbm
from fabrax.problems.procedural import MPINETS_LIKE, generate
from fabrax.rl.config import EnvConfig, env_config
from fabrax.rl.observations import bps_vectors, cell_centres, cell_index, grid_points, intrinsic_reward, keypoint_distance, point_distances
from fabrax.rl.scenes import ScenePool, build_pool, sample_episode
from fabrax.robot import Robot, build_robot
from fabrax.robot.kinematics import frame_pose, keypoints, points, sphere_centers
from fabrax.rollout.rollout import integrate
from fabrax.scene import COMMON_CAPACITY, Scene

METRICS = ("success", "collision", "keypoint_distance", "unique_cells", "r_sparse", "r_intrinsic", "switch")
MJX_METRICS = ("mjx_contacts", "mjx_penetration", "tracking_error")  # the mjx backend's extra metrics


@struct.dataclass
class Episode:
    q: jax.Array  # the arm's joint positions (the fabric's in the kinematic backend, MJX's in mjx)
    qd: jax.Array
    fabric_q: jax.Array  # q_e, qd_e, qdd_e: the fabric's state
    fabric_qd: jax.Array
    fabric_qdd: jax.Array
    scene: Scene
    scene_index: jax.Array
    mode: jax.Array  # start/goal mode of Table 3.1 (0-3)
    goal_q: jax.Array  # a configuration whose hand pose is the goal (the start where only the pose is given: `begin`)
    goal_pos: jax.Array
    goal_quat: jax.Array
    goal_keypoints: jax.Array  # (8, 3)
    counts: jax.Array  # (cells^3,) uint8 visits of the exploration map's cells
    switch: jax.Array  # bool, latched
    t: jax.Array  # policy steps taken


class FabricGuideEnv(Env):
    """brax `Env`: reset(rng) -> State, step(state, action) -> State; pure, jit- and vmap-able.
    `pool` may be None for an env whose episodes all come from `begin` (the benchmark method)."""

    def __init__(self, fabric: ArmFabric, params: Params, pool: ScenePool, cfg: EnvConfig):
        self.fabric, self.params, self.pool, self.cfg = fabric, params, pool, cfg
        self.robot = fabric.robot
        self._hand = self.robot.frame_point(fabric.goal_frame)
        self.centres = cell_centres(cfg.map_cells, *cfg.bounds)
        self._modes = jnp.asarray(cfg.scenes.modes, jnp.float32)
        self.metric_names = METRICS + (MJX_METRICS if cfg.backend == "mjx" else ())
        self.sim = None
        if cfg.backend == "mjx":
            from fabrax.rl.mjx_sim import MJXArm

            if pool is None:  # episodes from `begin` with scenes padded to the common capacity (the benchmark's)
                capacity = {k: COMMON_CAPACITY[k] for k in ("cuboids", "cylinders", "spheres")}
            else:
                s = pool.scene
                capacity = {"cuboids": s.cuboids.center.shape[1], "cylinders": s.cylinders.center.shape[1], "spheres": s.spheres.center.shape[1]}
            self.sim = MJXArm(self.robot, capacity, cfg.fabric_dt, cfg.sim_steps, cfg.kp, cfg.kd)

    # -- brax Env properties --------------------------------------------------------------
    @property
    def action_size(self) -> int:
        return 6 + self.robot.dof + 1

    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]:
        c, m, n = self.cfg.bps_cells, self.cfg.map_cells, self.robot.dof
        return {
            "goal_keypoints": (24,),
            "q": (n,),
            "hand_keypoints": (24,),
            "fabric_q": (n,),
            "fabric_qd": (n,),
            "fabric_qdd": (n,),
            "bps": (c, c, c, 3),
            "dynamic_bps": (self.robot.n_spheres,),
            "exploration": (m, m, m, 1),
            "switch": (1,),
        }

    @property
    def backend(self) -> str:
        return self.cfg.backend

    # -- episode --------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        i, start, goal_q, mode = sample_episode(self.pool, self._modes, rng)
        goal = frame_pose(self.robot, goal_q, self.fabric.goal_frame)
        scene = jax.tree.map(lambda a: a[i], self.pool.scene)
        return self.begin(scene, self.pool.bps[i], start, goal.translation(), goal.rotation().wxyz, keypoints(self.robot, goal_q), i, mode, goal_q)

    def begin(self, scene: Scene, bps, start, goal_pos, goal_quat, goal_keypoints, scene_index=0, mode=0, goal_q=None) -> State:
        """An episode from a given scene (with its `static_bps`), start configuration at rest and goal
        pose of the fabric's goal frame with its keypoints (e.g. a benchmark problem's)."""
        zero = jnp.zeros_like(start)
        ep = Episode(
            q=start,
            qd=zero,
            fabric_q=start,
            fabric_qd=zero,
            fabric_qdd=zero,
            scene=scene,
            scene_index=jnp.asarray(scene_index, jnp.int32),
            mode=jnp.asarray(mode, jnp.int32),
            goal_q=start if goal_q is None else goal_q,
            goal_pos=goal_pos,
            goal_quat=goal_quat,
            goal_keypoints=goal_keypoints,
            counts=jnp.zeros(self.cfg.map_cells**3, jnp.uint8),
            switch=jnp.zeros((), bool),
            t=jnp.zeros((), jnp.int32),
        )
        zeros = {k: jnp.zeros(()) for k in self.metric_names}
        obs = self.observe(ep, bps)
        zeros["keypoint_distance"] = keypoint_distance(obs["hand_keypoints"].reshape(8, 3), ep.goal_keypoints)
        return State(ep, obs, jnp.zeros(()), jnp.zeros(()), zeros, {"stage": jnp.ones((), jnp.int32)})

    def static_bps(self, scene: Scene) -> jax.Array:
        """The static basis point set of a scene (eq. 3.16), as the pool computes it."""
        return bps_vectors(scene, grid_points(self.cfg.bps_cells, *self.cfg.bounds), self.cfg.bps_clip)

    def targets(self, ep: Episode, action: jax.Array, stage: jax.Array):
        """The fabric parameters an action commands (see the module docstring) and the latched switch."""
        cfg, robot = self.cfg, self.robot
        a = jnp.clip(action, -1.0, 1.0)
        hand = frame_pose(robot, ep.q, self.fabric.goal_frame)  # the arm's hand (the fabric's in the kinematic backend)
        pos = hand.translation() + cfg.ee_translation * a[:3]
        rot = jaxlie.SO3.exp(cfg.ee_rotation * a[3:6]) @ hand.rotation()
        posture = 0.5 * (robot.lower + robot.upper) + 0.5 * (robot.upper - robot.lower) * a[6 : 6 + robot.dof]
        switch = ep.switch | ((a[-1] >= cfg.switch_threshold) & (stage >= 2))
        pos = jnp.where(switch, ep.goal_pos, pos)
        quat = jnp.where(switch, ep.goal_quat, rot.wxyz)
        params = self.fabric.with_pose_goal(self.params, pos, quat, posture=posture, posture_weight=jnp.where(switch, 0.0, 1.0))
        return params, switch

    def sim_model(self, ep: Episode):
        """The MJX model holding the episode's scene (None in the kinematic backend)."""
        return None if self.sim is None else self.sim.with_scene(self.sim.model, ep.scene)

    def substeps(self, ep: Episode, params: Params, model=None):
        """The fabric's `substeps` steps under `params` from the episode's fabric state, and the arm
        following it: ((fabric q, qd, qdd), (arm q, qd)) at the end, and the arm's q at every
        substep (substeps, n). In the kinematic backend the arm is the fabric; `model` is
        `sim_model(ep)` (built here when not given)."""
        cfg = self.cfg
        model = self.sim_model(ep) if model is None else model

        def substep(carry, _):
            (fq, fqd, _), (q, qd) = carry
            nq, nqd, qdd, _ = integrate(self.fabric, params, ep.scene, fq, fqd, cfg.fabric_dt, cfg.integrator)
            if model is None:
                q, qd = nq, nqd
            else:
                q, qd, _ = self.sim.track(model, q, qd, fq, fqd, qdd)
            return ((nq, nqd, qdd), (q, qd)), q

        start = ((ep.fabric_q, ep.fabric_qd, ep.fabric_qdd), (ep.q, ep.qd))
        return jax.lax.scan(substep, start, None, length=cfg.substeps)

    def step(self, state: State, action: jax.Array) -> State:
        return self.step_with_path(state, action)[0]

    def step_with_path(self, state: State, action: jax.Array):
        """`step`, also returning every fabric substep's q (substeps, n) and the commanded fabric
        parameters (for viewers and scripted rollouts, without running the fabric twice)."""
        cfg, robot, ep = self.cfg, self.robot, state.pipeline_state
        stage = state.info["stage"]
        params, switch = self.targets(ep, action, stage)

        model = self.sim_model(ep)
        ((fq, fqd, fqdd), (q, qd)), qs = self.substeps(ep, params, model)
        env_clear, self_clear, _ = state_clearances(robot, ep.scene, qs)  # the exact checker on every fabric step
        collision = jnp.any(env_clear < 0.0) | jnp.any(self_clear < 0.0)
        hand = jax.vmap(lambda x: points(robot, x, self._hand[0][None], self._hand[1][None])[0])(qs)
        cells, inside = cell_index(hand, cfg.map_cells, *cfg.bounds)
        visited = jnp.zeros(cfg.map_cells**3, bool).at[cells].max(inside)
        counts = jnp.where(visited, jnp.minimum(ep.counts, 254) + 1, ep.counts).astype(jnp.uint8)
        r_int = intrinsic_reward(counts, visited, self.centres, ep.goal_pos)

        ep = ep.replace(q=q, qd=qd, fabric_q=fq, fabric_qd=fqd, fabric_qdd=fqdd, counts=counts, switch=switch, t=ep.t + 1)
        obs = self.observe(ep, state.obs["bps"])
        dist = keypoint_distance(obs["hand_keypoints"].reshape(8, 3), ep.goal_keypoints)
        success = (dist < cfg.success_distance) & (stage >= 2)
        r_sparse = jnp.where(success, jnp.float32(cfg.sparse_reward), jnp.float32(0.0))  # strong float32, as at reset: no retrace
        reward = r_sparse + cfg.intrinsic_weight * r_int - jnp.where(collision, cfg.collision_penalty, 0.0)
        done = success | collision
        metrics = {
            "success": success.astype(jnp.float32),
            "collision": collision.astype(jnp.float32),
            "keypoint_distance": dist,
            "unique_cells": jnp.sum(counts > 0).astype(jnp.float32),
            "r_sparse": r_sparse,
            "r_intrinsic": r_int,
            "switch": switch.astype(jnp.float32),
        }
        if self.sim is not None:  # MJX's contacts where the checker found the least clearance
            worst = qs[jnp.argmin(env_clear)]
            n_contacts, depth = self.sim.contacts(model, worst)
            metrics.update(mjx_contacts=n_contacts.astype(jnp.float32), mjx_penetration=depth, tracking_error=jnp.max(jnp.abs(q - fq)))
        new = state.replace(pipeline_state=ep, obs=obs, reward=reward, done=done.astype(jnp.float32), metrics=metrics)
        return new, qs, params

    def observe(self, ep: Episode, bps: jax.Array) -> dict[str, jax.Array]:
        """Table 3.2 from the episode state; the static BPS comes from the pool (computed once per scene)."""
        cfg, robot = self.cfg, self.robot
        m = cfg.map_cells
        return {
            "goal_keypoints": ep.goal_keypoints.reshape(-1),
            "q": ep.q,
            "hand_keypoints": keypoints(robot, ep.q).reshape(-1),
            "fabric_q": ep.fabric_q,
            "fabric_qd": ep.fabric_qd,
            "fabric_qdd": ep.fabric_qdd,
            "bps": bps,
            "dynamic_bps": point_distances(ep.scene, sphere_centers(robot, ep.q), cfg.bps_clip),
            "exploration": (ep.counts > 0).astype(jnp.float32).reshape(m, m, m, 1),
            "switch": ep.switch.astype(jnp.float32)[None],
        }


def make_env(cfg: EnvConfig | dict | None, robot: Robot | dict, fabric: dict, data_dir=None) -> FabricGuideEnv:
    """The environment: `cfg` an `EnvConfig` or its mapping, `robot` a `Robot` or a robot config
    mapping, `fabric` a fabric config mapping (`fabrax.config.load("fabric", "panda")` reads the
    shipped preset). MBM train problems (1-50) of `cfg.scenes.mbm_classes` are read from `data_dir`
    (default $FABRAX_DATA); procedural problems of `cfg.scenes.procedural` and the
    `cfg.scenes.mpinets` MπNets-faithful problems (their own starts and goal configurations, cached
    under $FABRAX_CACHE/problems) are generated with `procedural_seed` (10000: the benchmark's
    train split)."""
    cfg = cfg if isinstance(cfg, EnvConfig) else env_config(cfg)
    if isinstance(robot, str) or isinstance(fabric, str):
        name = robot if isinstance(robot, str) else fabric
        raise ValueError(f"make_env takes a robot and a fabric config, not the name '{name}': read a preset with fabrax.config.load")
    rob = robot if isinstance(robot, Robot) else build_robot(robot)
    arm = build_arm_fabric(rob, fabric)
    params = arm.init()
    problems = load_mbm(rob, data_dir, cfg.scenes.mbm_classes, split="train", limit=cfg.scenes.mbm_limit) if cfg.scenes.mbm_classes else []
    for cls, n in cfg.scenes.procedural:
        family = "mpinets_like" if cls in MPINETS_LIKE else "mbm_like"
        problems += generate(rob, family, [cls], n, seed=cfg.scenes.procedural_seed, frame=arm.goal_frame) if n else []
    if cfg.scenes.mpinets:
        from fabrax._environment import cache_root
        from fabrax.problems import mpinets

        drawn = mpinets.generate(rob, cfg.scenes.mpinets, cfg.scenes.procedural_seed, frame=arm.goal_frame, cache_dir=cache_root() / "problems")
        problems += drawn.problems
    return FabricGuideEnv(arm, params, build_pool(rob, cfg, problems, arm.goal_frame), cfg)
