"""The method protocol and the built-in methods: the pure geometric fabric, GFCS, the RL guide, OMPL and VAMP planners.

A method takes a robot and a list of problems and returns one `Solution` per
problem: a joint trajectory sampled every `dt`, the wall time it took to
produce (compilation excluded, reported apart) and free-form info. Methods
that batch (fabrics) solve many problems in one `vmap`; their per-problem
time is the batch's wall time divided by its size.
"""

from __future__ import annotations

import dataclasses
import time
import zlib
from typing import Any, Protocol

import jax
import numpy as np

from fabrax.problems.problem import Problem, batch
from fabrax.robot.robot import Robot
from fabrax.scene import common_capacity


@dataclasses.dataclass
class Solution:
    q: np.ndarray  # (T, n) trajectory
    dt: float
    plan_time_s: float
    compile_s: float = 0.0
    info: dict[str, Any] = dataclasses.field(default_factory=dict)


class Method(Protocol):
    name: str

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]: ...


@dataclasses.dataclass
class FabricMethod:
    """The pure fabric aimed straight at the goal, rolled out for at most t_max at dt (gfcs_paper:
    7 s at 0.01 s). aim="pose" (`gf`, the papers' baseline): the end-effector attractor aimed at the
    goal's pose, a joint goal becoming the null-space posture; aim="joint" (`gf_joint`): the joint
    attractor aimed at a joint goal. stop: "goal" ends a rollout at the aim's goal test, "posture"
    once the posture has arrived too; settle: and every joint slower than this (see `rollout.reach`)."""

    fabric: Any
    params: Any
    name: str = "gf"
    aim: str = "pose"
    stop: str = "goal"
    settle: float | None = 0.05  # rad/s: a rollout ends at the goal at rest (None: at the first goal-test hit)
    dt: float = 0.01
    t_max: float = 7.0
    batch_size: int = 64
    _run: Any = dataclasses.field(default=None, repr=False)  # a Compiled rollout, kept across calls

    @property
    def criterion(self) -> str:
        """The success criterion that matches the aim (the runner's default)."""
        return "pose" if self.aim == "pose" else "auto"

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]:
        from fabrax.compiled import Compiled
        from fabrax.rollout import reach

        if self._run is None:
            steps = int(round(self.t_max / self.dt))
            self._run = Compiled(jax.jit(lambda b: reach(self.fabric, self.params, b, self.aim, self.stop, self.settle, dt=self.dt, steps=steps)))
        out: list[Solution] = []
        for start in range(0, len(problems), self.batch_size):
            chunk = problems[start : start + self.batch_size]
            size = min(self.batch_size, 1 << (len(chunk) - 1).bit_length())  # few batch shapes: few compilations
            # one shape per batch: the largest of its scenes, rounded to 8 slots per kind (`Scene.rounded`)
            cap = common_capacity([p.scene for p in chunk])
            padded = [dataclasses.replace(p, scene=p.scene.pad(**cap)) for p in chunk + [chunk[-1]] * (size - len(chunk))]
            b = batch(padded)
            run, compile_s = self._run.get(b)
            t0 = time.perf_counter()
            tr = jax.block_until_ready(run(b))
            per = (time.perf_counter() - t0) / len(chunk)
            q, length = np.asarray(tr.q), np.asarray(tr.length)
            for k in range(len(chunk)):
                out.append(
                    Solution(
                        q[k, : length[k]],
                        self.dt,
                        per,
                        compile_s if k == 0 else 0.0,
                        {"fabric_reached": bool(tr.reached[k]), "t_goal": float(tr.t_goal[k]), "batch": len(chunk)},
                    )
                )
        return out


def _planned(robot: Robot, problem: Problem, path, info: dict, dt: float) -> Solution:
    """A planner's path as a solution: retimed rest to rest (`retime`), or the start when none was
    found; plan time is its solve plus simplification time."""
    from fabrax.bench.retime import retime

    elapsed = info["solve_s"] + info["simplify_s"]
    if path is None:
        return Solution(problem.start_q[None], dt, elapsed, info.get("compile_s", 0.0), info)
    return Solution(retime(robot, path, dt), dt, elapsed, info.get("compile_s", 0.0), {**info, "waypoints": len(path)})


@dataclasses.dataclass
class OMPLMethod:
    """An OMPL planner (RRTConnect, BITstar, BiEST, AITstar, ...) on the joint space, state and motion
    validity from the same sphere checker (a motion validator checks each edge's interpolated
    states in one batched call), path simplification, then rest-to-rest retiming (`retime`).
    Planning time is solve plus simplification; compiling the checker is reported apart."""

    planner: str = "RRTConnect"
    budget_s: float = 1.2
    simplify: bool = True
    name: str = "rrtconnect"
    dt: float = 0.01
    resolution: float = 1.0 / 32.0
    first_solution: bool = False  # optimising planners stop at their first solution (`fabrax.bench.ompl.plan`)

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]:
        from fabrax.bench.ompl import plan

        args = (self.planner, self.budget_s, self.simplify, self.resolution, self.first_solution)
        return [_planned(robot, p, *plan(robot, p, *args), self.dt) for p in problems]


@dataclasses.dataclass
class VAMPMethod:
    """A VAMP planner (rrtc, prm, fcit, aorrtc) with VAMP's own robot model and SIMD collision checks
    (`fabrax.bench.vamp`), its path simplification, then rest-to-rest retiming (`retime`). Planning
    time is VAMP's own solve plus simplification time; the harness re-checks the trajectory with
    the benchmark's checker."""

    planner: str = "rrtc"
    iterations: int = 100_000
    simplify: bool = True
    padding: float = 0.02  # m added to the obstacles VAMP plans around (configs/method/vamp_*.yaml: chosen on train problems)
    name: str = "vamp_rrtc"
    dt: float = 0.01

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]:
        from fabrax.bench.vamp import plan

        return [_planned(robot, p, *plan(robot, p, self.planner, self.iterations, self.simplify, self.padding), self.dt) for p in problems]


@dataclasses.dataclass
class GFCSMethod:
    """GFCS (gfcs_paper Algorithm 1): CMA-ES over fabric command sequences, warm-started by a
    uniform sampler or, with `learner`, by SGLD samples of a trained energy model
    (`fabrax.planners.gfcs.selfsup`). `batch_size` problems are solved together
    (`fabrax.planners.gfcs.solve_batch`: every batch rolls out all their populations in one call,
    their scenes padded to one capacity), so that an accelerator steps batch_size x population arms
    at once; 1 solves one problem at a time, each scene at its own capacity. Reports the best motion
    after the last batch and, as variants `<name> (k b)`, after each batch in `report`. Plan time of
    a variant is the wall time of sampling and its batches (compilation excluded), divided by the
    problems solved together."""

    fabric: Any
    params: Any
    config: Any = None  # planners.gfcs.GFCSConfig (None: its defaults)
    name: str = "gfcs"
    report: tuple = (1, 5)
    seed: int = 0
    learner: Any = None  # a trained selfsup.Learner: warm-start from its SGLD samples
    selfsup: Any = None  # its selfsup.SelfSupConfig
    encoding: Any = None  # its encoding.Encoding
    batch_size: int = 1  # problems solved together
    _steps: Any = dataclasses.field(default=None, repr=False)
    _warm: set = dataclasses.field(default_factory=set, repr=False)  # scene shapes the sampler ran on

    def _samples(self, robot: Robot, prob, key, cfg):
        from fabrax.planners.gfcs.selfsup import learned_samples, reduce

        x = reduce(self.learner, self.encoding.context(robot, prob.start_q, prob.start_qd, prob.goal_q, prob.scene))
        return jax.block_until_ready(learned_samples(self.learner, robot, x, key, cfg.population, cfg.n_commands, self.selfsup))

    def _learned(self, robot: Robot, prob, key, cfg):
        """(samples, wall s) of the learned sampler for one problem, or (None, 0) without one."""
        if self.learner is None:
            return None, 0.0
        k_samp = jax.random.fold_in(key, 1)
        shape = tuple(prob.scene.capacity.values())  # the sampler compiles once per scene shape
        if shape not in self._warm:
            self._samples(robot, prob, k_samp, cfg)  # compile outside the clock
            self._warm.add(shape)
        t0 = time.perf_counter()
        samples = self._samples(robot, prob, k_samp, cfg)
        return samples, time.perf_counter() - t0

    def _key(self, p):
        return jax.random.fold_in(jax.random.PRNGKey(self.seed), zlib_hash(p.name))

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]:
        from fabrax.planners.gfcs import GFCOP, GFCSConfig, solve, solve_batch
        from fabrax.planners.gfcs.solver import make_step

        cfg = self.config or GFCSConfig()
        together = self.batch_size > 1
        if self._steps is None:  # the runner calls solve per chunk: compile once for all of them
            self._steps = make_step(self.fabric, self.params, cfg, problems=together)
        if not together:
            out = []
            for p in problems:
                prob, key = GFCOP.from_problem(p), self._key(p)
                samples, wall = self._learned(robot, prob, key, cfg)
                r = solve(self.fabric, self.params, prob, key, cfg, samples=samples, steps_fns=self._steps)
                out.append(self._solution(r, cfg, wall, 1))
            return out
        # a short last chunk is padded with copies of its last problem: one compiled size
        chunk = list(problems) + [problems[-1]] * (self.batch_size - len(problems)) if len(problems) < self.batch_size else list(problems)
        probs = [GFCOP.from_problem(p) for p in chunk]
        cap = common_capacity([q.scene for q in probs])
        probs = [q.replace(scene=q.scene.pad(**cap)) for q in probs]
        keys = [self._key(p) for p in chunk]
        learned = [self._learned(robot, q, k, cfg) for q, k in zip(probs, keys)]
        samples = None if self.learner is None else jax.numpy.stack([s for s, _ in learned])
        results = solve_batch(self.fabric, self.params, GFCOP.stack(probs), jax.numpy.stack(keys), cfg, samples=samples, steps_fns=self._steps)
        sampling = sum(w for _, w in learned)
        return [self._solution(r, cfg, sampling, len(chunk)) for r in results[: len(problems)]]

    def _solution(self, r, cfg, wall: float, together: int) -> Solution:
        """The final solution with the per-batch variants; wall times are shared by `together` problems."""
        variants = {}
        for b in r.per_batch:
            wall += b["wall_s"]
            tr = b["trajectory"]
            sol = Solution(np.asarray(tr.q[: int(tr.length)]), cfg.dt, wall / together, 0.0, {"cost": b["best_cost"], "batch": b["batch"]})
            if b["batch"] in self.report and b["batch"] != cfg.batches:
                variants[f"{self.name} ({b['batch']} b)"] = sol
        final = sol
        final.compile_s = r.compile_s
        final.info.update(
            {
                "variants": variants,
                "commands": r.best_commands.tolist(),
                "batch_wall_s": [b["wall_s"] / together for b in r.per_batch],
                "problems_together": together,
            }
        )
        return final


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

        n = len(batch[1])
        one = lambda k: jax.tree.map(lambda a: a[k % n], batch)  # noqa: E731
        if self.scripted == "switch":
            s0 = jax.jit(self._begin)(*one(0))
            params, _ = jax.jit(env.targets)(s0.pipeline_state, self._action(s0.obs), jax.numpy.asarray(2))
            call = lambda args: fabric_step(*args, params)  # noqa: E731
        else:
            call = lambda args: react(*args)  # noqa: E731
        jax.block_until_ready(call(one(0)))  # compile
        times = []
        for k in range(calls):
            args = jax.block_until_ready(one(k + 1))  # a new scene each call, on the device before the clock starts
            t0 = time.perf_counter()
            jax.block_until_ready(call(args))
            times.append(time.perf_counter() - t0)
        times = np.asarray(times) * 1e3
        return float(times.mean()), float(times.std())

    def solve(self, robot: Robot, problems: list[Problem]) -> list[Solution]:
        import jax.numpy as jnp

        from fabrax.compiled import Compiled
        from fabrax.robot.kinematics import frame_path, keypoints_at_pose
        from fabrax.scene import COMMON_CAPACITY, stack

        env = self.env
        if robot.dof != env.robot.dof or robot.name != env.robot.name:
            raise ValueError(f"the guide was trained on robot '{env.robot.name}', the problems are posed for '{robot.name}'")
        if self._run is None:
            self._run = Compiled(jax.jit(jax.vmap(self._rollout)))
        frame = env.fabric.goal_frame
        out: list[Solution] = []
        for first in range(0, len(problems), self.batch_size):
            chunk = problems[first : first + self.batch_size]
            size = min(self.batch_size, 1 << (len(chunk) - 1).bit_length())
            padded = chunk + [chunk[-1]] * (size - len(chunk))
            # goal poses: pose goals as given, joint goals through one batched FK
            pos = np.zeros((size, 3), np.float32)
            quat = np.zeros((size, 4), np.float32)
            joint = [k for k, p in enumerate(padded) if p.goal_pose is None]
            if joint:
                jp, jq = frame_path(robot, jnp.asarray(np.stack([padded[k].goal_q for k in joint]), jnp.float32), frame)
                pos[joint], quat[joint] = np.asarray(jp), np.asarray(jq)
            for k, p in enumerate(padded):
                if p.goal_pose is not None:
                    pos[k], quat[k] = p.goal_pose
            args = (
                stack([p.scene.pad(**COMMON_CAPACITY) for p in padded]),
                jnp.asarray(np.stack([p.start_q for p in padded]), jnp.float32),
                jnp.asarray(pos),
                jnp.asarray(quat),
                jax.vmap(lambda x, r: keypoints_at_pose(robot, frame, x, r))(jnp.asarray(pos), jnp.asarray(quat)),  # keypoints ride on the frame
            )
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


def zlib_hash(name: str) -> int:
    """A stable 31-bit hash of a problem name (seeds per problem, independent of order)."""
    return zlib.crc32(name.encode()) & 0x7FFFFFFF
