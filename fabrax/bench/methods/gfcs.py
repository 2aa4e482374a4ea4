"""GFCS (gfcs_paper Algorithm 1) as a method, one problem or a batch of problems at a time."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from fabrax.bench.methods.base import Solution, zlib_hash
from fabrax.problems.problem import Problem
from fabrax.robot.robot import Robot
from fabrax.scene import common_capacity


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
        from fabrax.planners.gfcs import GFCSConfig, solve, solve_batch
        from fabrax.planners.gfcs.solver import make_step
        from fabrax.problems import ProblemBatch

        cfg = self.config or GFCSConfig()
        if self.learner is not None:
            from fabrax.planners.gfcs.selfsup import require_joint_goals

            require_joint_goals(problems)
        together = self.batch_size > 1
        if self._steps is None:  # the runner calls solve per chunk: compile once for all of them
            self._steps = make_step(self.fabric, self.params, cfg, problems=together)
        if not together:
            out = []
            for p in problems:
                prob, key = ProblemBatch.of(p), self._key(p)
                samples, wall = self._learned(robot, prob, key, cfg)
                r = solve(self.fabric, self.params, prob, key, cfg, samples=samples, steps_fns=self._steps)
                out.append(self._solution(r, cfg, wall, 1))
            return out
        # a short last chunk is padded with copies of its last problem: one compiled size
        chunk = list(problems) + [problems[-1]] * (self.batch_size - len(problems)) if len(problems) < self.batch_size else list(problems)
        probs = [ProblemBatch.of(p) for p in chunk]
        cap = common_capacity([q.scene for q in probs])
        probs = [q.replace(scene=q.scene.pad(**cap)) for q in probs]
        keys = [self._key(p) for p in chunk]
        learned = [self._learned(robot, q, k, cfg) for q, k in zip(probs, keys)]
        samples = None if self.learner is None else jax.numpy.stack([s for s, _ in learned])
        results = solve_batch(self.fabric, self.params, ProblemBatch.stack(probs), jax.numpy.stack(keys), cfg, samples=samples, steps_fns=self._steps)
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


def gfcs_config(method: dict, cfg: dict):
    """GFCS solver settings from a method config (configs/method/gfcs.yaml) and the run's dt and t_max."""
    import dataclasses

    from fabrax.planners.gfcs import GFCSConfig
    from fabrax.settings import from_mapping

    fields = {f.name for f in dataclasses.fields(GFCSConfig)}
    solver = {k: v for k, v in method.items() if k in fields}  # the rest are the bench's (name, report, run, batch_size)
    return from_mapping(GFCSConfig, {**solver, "dt": cfg["dt"], "t_max": cfg["t_max"]}, "method")


def learned_sampler(run_dir: Path, robot: Robot, n_commands: int) -> tuple:
    """(learner, selfsup config, encoding) of an experiments/gfcs.py run directory: its hydra config
    (.hydra/config.yaml) read here, its sampler by `fabrax.planners.gfcs.selfsup.load_run`."""
    import yaml

    from fabrax.planners.gfcs.selfsup import load_run

    cfg_file = run_dir / ".hydra" / "config.yaml"
    if not cfg_file.exists():
        raise ValueError(f"{run_dir}: not an experiments/gfcs.py run directory (no .hydra/config.yaml)")
    try:
        return load_run(run_dir, yaml.safe_load(cfg_file.read_text()), robot, n_commands)
    except FileNotFoundError as e:
        raise ValueError(str(e)) from None


def build(m: dict, cfg: dict, robot: Robot) -> GFCSMethod:
    """`type: gfcs` (configs/method/gfcs*.yaml); `run:` loads a trained sampler of an
    experiments/gfcs.py run."""
    from fabrax import config

    fabric, params = config.load_fabric(robot, {**cfg["fabric"], "goal_frame": cfg["frame"]})
    gfcs_cfg = gfcs_config(m, cfg)
    learned = {}
    if m.get("run"):
        learned = dict(zip(("learner", "selfsup", "encoding"), learned_sampler(Path(m["run"]), robot, gfcs_cfg.n_commands)))
    batch = m.get("batch_size", 1)
    if not isinstance(batch, int) or isinstance(batch, bool) or batch < 1:
        raise ValueError(f"method.batch_size must be a positive integer, got {batch!r}")
    return GFCSMethod(fabric, params, gfcs_cfg, m["name"], tuple(m["report"]), cfg["seed"], **learned, batch_size=batch)
