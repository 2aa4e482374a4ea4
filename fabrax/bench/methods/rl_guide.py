"""The RL guide (fabrics_guided_rl_thesis ch. 3-4) from a checkpoint, or the env's pure fabric, as a method."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from fabrax.bench.methods.base import Solution
from fabrax.problems.problem import Problem
from fabrax.robot.robot import Robot


@dataclasses.dataclass
class RLGuideMethod:
    """The RL guide (fabrics_guided_rl_thesis ch. 3-4): a trained PPO policy steering the fabric at
    the env's policy rate (2 Hz over a 60 Hz fabric), in curriculum stage 2, from the problem's start
    until the mean keypoint distance is below the env's `success_distance` (0.08 m) or `episode_s`
    (20 s) have passed; a collision judged by the env's checker also ends it. `scripted="switch"`
    rolls out the env's pure-fabric baseline instead (the switch on from the first step: the fabric
    aimed at the goal pose). The trajectory is the arm's configuration at every fabric step.
    Problems are rolled out `batch_size` at a time in one `vmap`; `reaction_ms` and `reaction_ms_std`
    (in every row's info) time one action for a new scene (`reaction_ms`) on this host."""

    env: Any  # a FabricGuideEnv (its pool is unused: problems bring their scenes)
    act: Any = None  # the deterministic policy on one env's observations (`fabrax.rl.policy.Guide.act`)
    name: str = "rl_guide"
    scripted: str | None = None  # "switch": the pure-fabric baseline, no policy
    batch_size: int = 32
    _run: Any = dataclasses.field(default=None, repr=False)
    _reaction_ms: tuple[float, float] | None = dataclasses.field(default=None, repr=False)

    criterion = "keypoints"

    def _action(self, obs):
        if self.scripted == "switch":
            return jax.numpy.zeros(self.env.action_size).at[-1].set(1.0)
        return self.act(obs)

    def _begin(self, scene, start, goal_pos, goal_quat, goal_keypoints):
        """The episode of one problem, in stage 2."""
        import jax.numpy as jnp

        env = self.env
        state = env.begin(scene, env.static_bps(scene), start, goal_pos, goal_quat, goal_keypoints)
        return state.replace(info={**state.info, "stage": jnp.asarray(2, jnp.int32)})

    def _rollout(self, scene, start, goal_pos, goal_quat, goal_keypoints):
        import jax.numpy as jnp

        env = self.env
        state = self._begin(scene, start, goal_pos, goal_quat, goal_keypoints)

        def body(carry, _):
            s, alive = carry
            nxt, qs, _ = env.step_with_path(s, self._action(s.obs))
            nxt = jax.tree.map(lambda x, y: jnp.where(alive, x, y), nxt, s)
            return (nxt, alive & (nxt.done == 0.0)), (qs, alive)

        _, (qs, alive) = jax.lax.scan(body, (state, jnp.ones((), bool)), None, length=env.cfg.episode_steps)
        return qs, alive

    def reaction_ms(self, batch, calls: int = 100) -> tuple[float, float]:
        """Reaction time as the thesis defines it (§4.1: the time to produce an action for the arm given
        a new obstacle scene): mean and std (ms) over `calls` calls after compiling, each on the next
        problem of `batch` (the solve's stacked arguments). A call builds the observation of the new
        scene (its basis-point distances included), runs the policy and one fabric step toward its
        targets; the scripted pure fabric runs the fabric step alone."""
        from fabrax.rollout.rollout import integrate

        env = self.env

        @jax.jit
        def react(scene, start, goal_pos, goal_quat, goal_keypoints):
            s = self._begin(scene, start, goal_pos, goal_quat, goal_keypoints)
            params, _ = env.targets(s.pipeline_state, self._action(s.obs), jax.numpy.asarray(2))
            ep = s.pipeline_state
            return integrate(env.fabric, params, ep.scene, ep.fabric_q, ep.fabric_qd, env.cfg.fabric_dt, env.cfg.integrator)[0]

        @jax.jit
        def fabric_step(scene, start, goal_pos, goal_quat, goal_keypoints, params):
            return integrate(env.fabric, params, scene, start, jax.numpy.zeros_like(start), env.cfg.fabric_dt, env.cfg.integrator)[0]

        n = min(len(batch[1]), calls + 1)
        each = jax.block_until_ready([jax.tree.map(lambda a: a[k], batch) for k in range(n)])  # split before any clock starts
        one = lambda k: each[k % n]  # noqa: E731
        if self.scripted == "switch":
            s0 = jax.jit(self._begin)(*one(0))
            params, _ = jax.jit(env.targets)(s0.pipeline_state, self._action(s0.obs), jax.numpy.asarray(2))
            call = lambda args: fabric_step(*args, params)  # noqa: E731
        else:
            call = lambda args: react(*args)  # noqa: E731
        jax.block_until_ready(call(one(0)))  # compile
        times = []
        for k in range(calls):
            args = one(k + 1)  # a new scene each call, on the device before the clock starts
            t0 = time.perf_counter()
            jax.block_until_ready(call(args))
            times.append(time.perf_counter() - t0)
        times = np.asarray(times) * 1e3
        return float(times.mean()), float(times.std())

    def arguments(self, robot: Robot, problems: list[Problem]) -> tuple:
        """The rollout's stacked arguments for `problems` (scene padded to the common capacity,
        start, goal pose of the fabric's goal frame and its keypoints): every problem aimed at a
        pose, joint goals' poses by one batched FK."""
        from fabrax.problems.problem import batch
        from fabrax.robot.kinematics import keypoints_at_pose
        from fabrax.scene import COMMON_CAPACITY

        frame = self.env.fabric.goal_frame
        b = batch([dataclasses.replace(p, scene=p.scene.pad(**COMMON_CAPACITY)) for p in problems]).with_goal_poses(robot, frame)
        keypoints = jax.vmap(lambda x, r: keypoints_at_pose(robot, frame, x, r))(b.goal_pos, b.goal_quat)  # keypoints ride on the frame
        return b.scene, b.start_q, b.goal_pos, b.goal_quat, keypoints

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]:

        from fabrax.compiled import Compiled

        env = self.env
        if robot.dof != env.robot.dof or robot.name != env.robot.name:
            raise ValueError(f"the guide was trained on robot '{env.robot.name}', the problems are posed for '{robot.name}'")
        if self._run is None:
            self._run = Compiled(jax.jit(jax.vmap(self._rollout)))
        out: list[Solution] = []
        for first in range(0, len(problems), self.batch_size):
            chunk = problems[first : first + self.batch_size]
            size = min(self.batch_size, 1 << (len(chunk) - 1).bit_length())
            args = self.arguments(robot, chunk + [chunk[-1]] * (size - len(chunk)))
            if self._reaction_ms is None:
                self._reaction_ms = self.reaction_ms(args)
            run, compile_s = self._run.get(*args)
            t0 = time.perf_counter()
            qs, alive = jax.block_until_ready(run(*args))
            per = (time.perf_counter() - t0) / len(chunk)
            qs, alive = np.asarray(qs), np.asarray(alive)
            for k, p in enumerate(chunk):
                steps = int(alive[k].sum())
                q = np.concatenate([np.asarray(p.start_q, np.float32)[None], qs[k, :steps].reshape(-1, qs.shape[-1])])
                info = {"policy_steps": steps, "reaction_ms": self._reaction_ms[0], "reaction_ms_std": self._reaction_ms[1], "batch": len(chunk)}
                out.append(Solution(q, env.cfg.fabric_dt, per, compile_s if k == 0 else 0.0, info))
        return out


def build(m: dict, cfg: dict, robot: Robot) -> RLGuideMethod:
    """The RL guide from a checkpoint, or (scripted=switch) the env's pure fabric; its env settings
    are the checkpoint's (robot, fabric, env), else the environment's defaults with this run's robot
    and fabric."""
    from fabrax import config
    from fabrax.rl.config import env_config
    from fabrax.rl.env import FabricGuideEnv

    if m.get("scripted") not in (None, "switch"):
        raise ValueError(f"method.scripted must be null or switch, got {m['scripted']!r}")
    if m.get("checkpoint") is None and m.get("scripted") is None:
        raise ValueError("method=rl_guide needs method.checkpoint=<experiments/rl.py run directory> (or method.scripted=switch)")
    act, env_settings, fabric_cfg = None, {}, {**cfg["fabric"], "goal_frame": cfg["frame"]}
    if m.get("checkpoint") is not None:
        from fabrax.rl.policy import load_guide

        guide = load_guide(m["checkpoint"])
        act, env_settings, fabric_cfg = guide.act, dict(guide.settings["env"]), guide.settings["fabric"]
        trained = guide.settings["robot"]
        if trained["name"] != robot.name:
            raise ValueError(f"the guide was trained on robot '{trained['name']}'; run it with robot={trained['name']}")
        ours = json.loads(json.dumps(cfg.get("robot") or config.load("robot", robot.name)))
        differ = _differing(json.loads(json.dumps(trained)), ours)
        if differ:  # e.g. another sphere budget: other observation shapes, every problem would fail
            raise ValueError(f"the guide was trained with other robot settings ({', '.join(differ)}); set them as in its settings.json")
    episode_s = m.get("episode_s", 20.0)
    if isinstance(episode_s, bool) or not isinstance(episode_s, (int, float)) or not episode_s > 0:
        raise ValueError(f"method.episode_s must be a positive number of seconds, got {episode_s!r}")
    env_settings = {**env_settings, "episode_s": float(episode_s)}  # the thesis' evaluation, whatever the training episodes were
    env_cfg = env_config(env_settings)
    fabric, params = config.load_fabric(robot, fabric_cfg)
    env = FabricGuideEnv(fabric, params, None, env_cfg)
    return RLGuideMethod(env, act, m["name"], m.get("scripted"), int(m.get("batch_size", 32)))


def _differing(a, b, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two nested mappings; two file paths with the same
    file name count as equal (a data folder may sit elsewhere on another machine)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b)) for d in _differing(a.get(k), b.get(k), f"{prefix}{k}.")]
    if isinstance(a, str) and isinstance(b, str) and "/" in a + b:
        return [] if Path(a).name == Path(b).name else [prefix.rstrip(".")]
    return [] if a == b else [prefix.rstrip(".")]
