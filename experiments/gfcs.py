"""Self-supervised GFCS on one problem class, then evaluation (gfcs_paper §IV-C, §V, Tables I-II).

    python experiments/gfcs.py class_name=table_under_pick
    python experiments/gfcs.py -m class_name=box,cage,bookshelf_tall      # a sweep over classes

Trains the energy-based sampler on the class's train problems (Algorithm 2; checkpointed after every
solve, so re-running with the same hydra.run.dir resumes), then solves the test problems with the
uniform sampler (`gfcs`) and the learned one (`gfcs_learned`), reporting rows after batch 1 and
after the last batch. Writes sampler.msgpack, results.json, summary.md and plots in the run directory.

The reactive study can also re-execute the solutions of an earlier run (a `fabrax bench method=gfcs`
output directory, or this script's) without solving again; its settings must match this run's:

    python experiments/gfcs.py class_name=box evaluate=[] reactive.method=gfcs reactive.results=bench_out/gfcs50
"""

from __future__ import annotations

import dataclasses
import logging
import os
import platform
import time
from pathlib import Path

import hydra
from omegaconf import DictConfig

import fabrax  # noqa: F401  (XLA flags)

log = logging.getLogger("gfcs")  # hydra sends it to the terminal and to the run's gfcs.log


def problems_for(cfg: dict, robot, split: str, limit: int):
    from fabrax.bench.cli import load_problems

    sub = {**cfg, "classes": [cfg["class_name"]], "split": split, "limit": limit}
    return load_problems(sub, robot)


@hydra.main(config_path="../configs", config_name="gfcs", version_base=None)
def main(dcfg: DictConfig) -> None:
    import jax

    from fabrax import config
    from fabrax.bench.methods import GFCSMethod
    from fabrax.bench.methods.gfcs import gfcs_config
    from fabrax.bench.metrics import Goal
    from fabrax.bench.runner import run, summary_table, write
    from fabrax.planners.gfcs.selfsup import run as learn
    from fabrax.planners.gfcs.selfsup import settings

    cfg = config.resolve(dcfg)
    out = Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)
    robot = config.load_robot(config.robot_choice(cfg))
    fabric, params = config.load_fabric(robot, cfg["fabric"])
    m = dict(cfg["method"])
    gfcs_cfg = gfcs_config(m, cfg)
    ss_cfg, enc = settings(cfg)

    learner, learn_s = None, 0.0
    if "gfcs_learned" in cfg["evaluate"]:
        train = [p for p in problems_for(cfg, robot, "train", cfg["train_limit"]) if p.valid]
        log.info(f"{cfg['class_name']}: learning on {len(train)} train problems, {ss_cfg.passes} passes -> {out}")
        t0 = time.perf_counter()
        try:
            learner = learn(fabric, params, train, gfcs_cfg, ss_cfg, out / "sampler.msgpack", enc, log=log.info)
        except ValueError as e:  # a checkpoint of other settings, or an unreadable one
            raise SystemExit(f"experiments/gfcs.py: {e}") from None
        learn_s = time.perf_counter() - t0

    test = problems_for(cfg, robot, "test", cfg["test_limit"])
    rows = []
    for name in cfg["evaluate"]:
        extra = dict(learner=learner, selfsup=ss_cfg, encoding=enc) if name == "gfcs_learned" else {}
        method = GFCSMethod(fabric, params, gfcs_cfg, name, tuple(m["report"]), cfg["seed"], **extra)
        rows += run(method, robot, test, goal=Goal(**cfg["goal"]), margin=cfg["margin"], frame=cfg["frame"], progress=cfg["progress"])
    meta = {
        "config": cfg,
        "learn_s": learn_s,
        "losses": learner.losses if learner else [],
        "gfcs": dataclasses.asdict(gfcs_cfg),
        "versions": {"python": platform.python_version(), "jax": jax.__version__},
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
    }
    if cfg["reactive"]["n_obstacles"] > 0:
        solved = rows if not cfg["reactive"]["results"] else saved_rows(cfg, Path(cfg["reactive"]["results"]))
        meta["reactive"] = reactive(cfg, robot, fabric, params, test, solved, gfcs_cfg)
        log.info(f"reactive re-execution: {meta['reactive']['summary']}")
    write(rows, out, meta)
    if rows:
        log.info("\n" + summary_table(rows))


SAME = ("dt", "t_max", "fabric", "frame")  # settings a saved solution's re-execution depends on


def saved_rows(cfg: dict, path: Path) -> list[dict]:
    """The rows of a saved run (its directory or results.json), refused when it was solved with other settings."""
    import json

    from fabrax import config

    path = path / "results.json" if path.is_dir() else path
    if not path.is_file():
        raise SystemExit(f"reactive.results: no results.json at {path}")
    saved = json.loads(path.read_text())
    old = saved.get("meta", {}).get("config", {})
    as_dict = lambda f: config.load("fabric", f) if isinstance(f, str) else f  # noqa: E731
    differ = [k for k in SAME if k in old and (as_dict(old[k]) != as_dict(cfg[k]) if k == "fabric" else old[k] != cfg[k])]
    differ += [f"method.{k}" for k in ("final_pose", "via_tolerance", "hand_mass") if old.get("method", {}).get(k) != cfg["method"].get(k)]
    if differ:
        raise SystemExit(f"reactive.results: {path} was solved with other settings: {', '.join(differ)}")
    return saved["rows"]


def reactive(cfg: dict, robot, fabric, params, problems, rows, gfcs_cfg) -> dict:
    """gfcs_paper §V: block each solved motion with new cuboids and re-execute the same commands;
    with `reactive.replan_batches` > 0, also re-plan in the new scene by CMA-ES warm-started at the
    old solution (`fabrax.planners.gfcs.reactive.replan`, a fixed budget of batches)."""
    import time

    import jax
    import jax.numpy as jnp
    import numpy as np

    from fabrax.bench.metrics import Goal, evaluate
    from fabrax.check.checker import check_path
    from fabrax.planners.gfcs.cost import to_unconstrained, with_hand_mass
    from fabrax.planners.gfcs.reactive import blocking_cuboids, reexecute, replan, replan_config, with_obstacles
    from fabrax.planners.gfcs.solver import make_step
    from fabrax.problems import ProblemBatch

    steps = int(round(cfg["t_max"] / cfg["dt"]))
    final_pose, via = cfg["method"]["final_pose"], cfg["method"]["via_tolerance"]
    dt, goal = cfg["dt"], Goal(**cfg["goal"])
    executed = with_hand_mass(params, cfg["method"].get("hand_mass"))  # the fabric as the solver rolled it out
    execute = jax.jit(lambda prob, commands, scene: reexecute(fabric, executed, prob, commands, scene, dt, steps, final_pose, via))  # compiled once
    batches = int(cfg["reactive"]["replan_batches"])
    try:
        replan_cfg = replan_config(gfcs_cfg, batches, float(cfg["reactive"]["replan_std"])) if batches else None
    except ValueError as e:
        raise SystemExit(f"experiments/gfcs.py: reactive.replan_batches or replan_std: {e}") from None
    fns = make_step(fabric, params, replan_cfg) if batches else None
    by_name = {p.name: p for p in problems}
    method = cfg["reactive"]["method"]
    rng = np.random.default_rng(cfg["seed"])
    key = jax.random.PRNGKey(cfg["seed"])
    out, skipped = [], []
    for row in rows:
        if row["method"] != method or not row.get("success") or row["problem"] not in by_name:
            continue  # another method's, a failed one, or another class's (a saved multi-class run)
        p = by_name[row["problem"]]
        prob = ProblemBatch.of(p)
        commands = np.asarray(row["info"]["commands"])
        old = execute(prob, jnp.asarray(commands, jnp.float32), prob.scene)
        q_old = np.asarray(old.q[: int(old.length)])
        try:
            new = blocking_cuboids(robot, q_old, p.start_q, p.goal_q, rng, n=cfg["reactive"]["n_obstacles"])
        except ValueError as e:  # no blocking cuboid fits between the path and the start and goal
            skipped.append({"problem": p.name, "reason": str(e)})
            continue
        scene = with_obstacles(p.scene, new)
        blocked = check_path(robot, scene, q_old).collision
        changed = dataclasses.replace(p, scene=scene)
        tr = execute(prob, jnp.asarray(commands, jnp.float32), scene)
        m = evaluate(robot, changed, np.asarray(tr.q[: int(tr.length)]), dt, goal=goal)
        result = {
            "problem": p.name,
            "old_path_blocked": blocked,
            "collision_free": not m["collision"],
            "reached": m["reached"],
            "success": m["success"],
        }
        if batches:
            z = to_unconstrained(jnp.asarray(commands, jnp.float32), robot.lower, robot.upper)
            t0 = time.perf_counter()
            res = replan(fabric, params, ProblemBatch.of(changed), z, jax.random.fold_in(key, len(out)), replan_cfg, steps_fns=fns)
            wall = time.perf_counter() - t0 - res.compile_s
            traj = res.trajectory
            r = evaluate(robot, changed, np.asarray(traj.q[: int(traj.length)]), dt, goal=goal)
            result.update(
                replan_collision_free=not r["collision"],
                replan_reached=r["reached"],
                replan_success=r["success"],
                replan_time_s=wall,
                replan_ee_length=r["ee_length"],
            )
        out.append(result)
    n = len(out)
    rate = lambda k: 100.0 * sum(r[k] for r in out) / n if n else float("nan")  # noqa: E731
    summary = {
        "n": n,
        "skipped": len(skipped),
        "old_path_blocked_pct": rate("old_path_blocked"),
        "collision_free_pct": rate("collision_free"),
        "reached_pct": rate("reached"),
        "success_pct": rate("success"),
    }
    if batches and n:
        summary.update(
            replan_batches=batches,
            replan_std=replan_cfg.std_init,
            replan_population=replan_cfg.population,
            replan_collision_free_pct=rate("replan_collision_free"),
            replan_reached_pct=rate("replan_reached"),
            replan_success_pct=rate("replan_success"),
            replan_time_s=float(np.mean([r["replan_time_s"] for r in out])),
        )
    return {"summary": summary, "rows": out, "skipped": skipped}


if __name__ == "__main__":
    main()
