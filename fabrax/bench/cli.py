"""`fabrax bench key=value ...`: run one method on one problem set (configs/bench.yaml, hydra overrides).

fabrax bench method=gf problems=mbm classes=[box] split=test limit=5 out=bench_out/gf seed=0
fabrax bench method=gf fabric.terms.goal.k_force=3.0 ...      # any fabric gain

Sweeps (hydra multirun, one run directory per job): experiments/bench.py -m ...; see README.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

from fabrax import config
from fabrax.bench.outdir import OutDirError, claim


def compose(overrides: list[str]):
    """The bench config with command-line overrides (unknown keys fail with hydra's error)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf.errors import MissingMandatoryValue

    try:
        with initialize_config_dir(config_dir=str(config.config_dir()), version_base=None):
            cfg = hydra_compose("bench", overrides=overrides)
        return config.resolve(cfg)
    except (HydraException, MissingMandatoryValue) as e:
        message = " ".join(str(e).split("\nConfig search path")[0].split())  # one line, without hydra's search path
        raise SystemExit(f"fabrax bench: {message}") from None


def check(cfg: dict) -> None:
    """One-line errors for the run's own keys, before anything is loaded or compiled."""
    limit, classes = cfg["limit"], cfg["classes"]
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 1):
        raise SystemExit(f"fabrax bench: limit must be a positive integer (problems per class) or null, got {limit!r}")
    if classes is not None and not (isinstance(classes, list) and classes and all(isinstance(c, str) for c in classes)):
        raise SystemExit(f"fabrax bench: classes must be a non-empty list of class names, e.g. classes=[box,cage], got {classes!r}")
    types = cfg.get("types")
    if types is not None:
        if cfg["problems"] != "mpinets":
            raise SystemExit(f"fabrax bench: types= selects problem types of problems=mpinets, not of {cfg['problems']}")
        if not (isinstance(types, list) and types and all(isinstance(t, str) for t in types)):
            raise SystemExit(f"fabrax bench: types must be a non-empty list, e.g. types=[task_oriented], got {types!r}")
    budget = cfg.get("solvable_s")
    if budget is not None and (isinstance(budget, bool) or not isinstance(budget, (int, float)) or budget <= 0):
        raise SystemExit(f"fabrax bench: solvable_s must be a positive number of seconds or null, got {budget!r}")
    if cfg["problems"] == "mbm":
        from fabrax.problems.mbm import MBM_JOINTS

        choice = config.robot_choice(cfg)
        joints = (config.load("robot", choice) if isinstance(choice, str) else choice).get("active_joints")
        if list(joints or []) != list(MBM_JOINTS):
            name = choice if isinstance(choice, str) else choice.get("name")
            raise SystemExit(
                f"fabrax bench: problems=mbm are MotionBenchMaker's Panda problems; robot={name} cannot run them: use problems=mbm_like, mpinets_like or mpinets"
            )
    if cfg["split"] not in ("train", "test", "all"):
        raise SystemExit(f"fabrax bench: split must be train, test or all, got {cfg['split']!r}")
    for key in ("dt", "t_max"):
        if isinstance(cfg[key], bool) or not isinstance(cfg[key], (int, float)) or not cfg[key] > 0:
            raise SystemExit(f"fabrax bench: {key} must be a positive number (s), got {cfg[key]!r}")
    if cfg.get("fabric") is not None:
        from fabrax.gains import check_config

        try:
            check_config(cfg["fabric"])
        except ValueError as e:
            raise SystemExit(f"fabrax bench: {e}") from None


def load_problems(cfg: dict, robot, info: dict | None = None) -> list:
    """The run's problems; `info` (if given) receives how a generated set was drawn (mpinets: how
    many were drawn, dropped as unsolvable, failed to generate)."""
    kind = cfg["problems"]
    if kind == "mbm":
        from fabrax.problems.mbm import load_mbm

        return load_mbm(robot, cfg["data_dir"], cfg["classes"], cfg["split"], cfg["limit"])
    if kind in ("mbm_like", "mpinets_like"):
        from fabrax.problems import procedural

        n = cfg["limit"] or 100
        seed = cfg["seed"] + (0 if cfg["split"] != "train" else 10_000)
        problems = procedural.generate(robot, kind, cfg["classes"], n, seed, frame=cfg["frame"])
        return [with_ik_goal(robot, p, cfg["frame"]) for p in problems] if cfg.get("ik_goals") else problems
    if kind == "mpinets":
        drawn = mpinets_set(cfg, robot)
        if info is not None:
            info.update(drawn=drawn.drawn, kept=len(drawn.problems), unsolvable=len(drawn.dropped), failed=len(drawn.failed), solvable=drawn.solvable)
        problems = drawn.problems
        return [with_ik_goal(robot, p, cfg["frame"]) for p in problems] if cfg.get("ik_goals") else problems
    raise SystemExit(f"fabrax bench: problems must be mbm, mpinets, mbm_like or mpinets_like, got '{kind}'")


def mpinets_set(cfg: dict, robot, progress: bool | None = None):
    """The MπNets-faithful set of the run (`fabrax.problems.mpinets`): `limit` problems (default 600),
    test seed `seed`, train seed `seed` + 10000, each kept only if OMPL RRTConnect solves it from its
    start to the generator's goal configuration within `solvable_s` (MπNets keeps only problems a
    global planner solves); cached under $FABRAX_CACHE/problems."""
    from fabrax._environment import cache_root
    from fabrax.problems import mpinets

    if cfg["split"] == "all":
        raise SystemExit("fabrax bench: problems=mpinets has a train and a test split, not all")
    budget = cfg.get("solvable_s")
    check, key = None, None
    if budget:
        from fabrax.bench.ompl import available

        if "RRTConnect" not in available():
            hint = "install OMPL (pip install -e '.[bench]') or set solvable_s=null"
            raise SystemExit(f"fabrax bench: problems=mpinets keeps only problems OMPL RRTConnect solves; {hint}")
        check, key = _solvable(budget), f"RRTConnect {float(budget)} s, exact checker"
    show = cfg.get("progress", True) if progress is None else progress
    bar = _Progress(int(cfg["limit"] or 600)) if show else None
    seed = cfg["seed"] + (10_000 if cfg["split"] == "train" else 0)
    try:
        out = mpinets.generate(
            robot, int(cfg["limit"] or 600), seed, cfg["classes"], cfg.get("types"), cfg["frame"], check, key, cache_root() / "problems", bar
        )
    finally:
        if bar is not None:
            bar.close()
    return out


class _Progress:
    def __init__(self, n: int):
        from tqdm import tqdm

        self.bar = tqdm(total=n, desc="generating mpinets problems", unit="problem")

    def __call__(self, kept: int, drawn: int) -> None:
        self.bar.n = kept
        self.bar.set_postfix(drawn=drawn, refresh=True)

    def close(self) -> None:
        self.bar.close()


def _solvable(budget_s: float):
    def check(robot, p) -> bool:
        import dataclasses

        import numpy as np

        from fabrax.bench.ompl import plan

        path, _ = plan(robot, dataclasses.replace(p, goal_q=np.asarray(p.meta["goal_q"])), "RRTConnect", budget_s, False, 1.0 / 32.0)
        return path is not None

    return check


def with_ik_goal(robot, p, frame: str):
    """A pose-goal problem with a joint goal added: the collision-free IK solution nearest its start
    (seeded by the problem's name), for joint-space methods (GFCS, OMPL); the pose stays the goal
    that pose and keypoint success are judged against. Without a solution the problem is marked
    invalid (reported, not run)."""
    import dataclasses

    import numpy as np

    from fabrax.problems.generators import ik_goal

    if p.goal_q is not None or p.goal_pose is None:
        return p
    if "goal_q" in p.meta:  # the generator's own goal configuration (mpinets: the one its solvability check planned to)
        return dataclasses.replace(p, goal_q=np.asarray(p.meta["goal_q"], np.float64))
    goal = ik_goal(robot, p, frame)
    if goal is None:
        return dataclasses.replace(p, valid=False, reason="no collision-free IK solution of the goal pose")
    return dataclasses.replace(p, goal_q=goal)


def gfcs_config(method: dict, cfg: dict):
    """GFCS solver settings from a method config (configs/method/gfcs.yaml) and the run's dt and t_max."""
    from fabrax.planners.gfcs import GFCSConfig

    keys = ("n_commands", "population", "batches", "std_init", "stop_after", "patience", "via_tolerance", "final_pose", "length_weight", "direct")
    return GFCSConfig(**{k: method[k] for k in keys}, dt=cfg["dt"], t_max=cfg["t_max"])


def make_method(cfg: dict, robot):
    from fabrax.bench.methods import FabricMethod, GFCSMethod, OMPLMethod

    m = dict(cfg["method"])
    kind = m.pop("type")
    if kind == "fabric":
        fabric, params = config.load_fabric(robot, {**cfg["fabric"], "goal_frame": cfg["frame"]})
        return FabricMethod(fabric, params, dt=cfg["dt"], t_max=cfg["t_max"], **m)
    if kind == "gfcs":
        fabric, params = config.load_fabric(robot, {**cfg["fabric"], "goal_frame": cfg["frame"]})
        gfcs_cfg = gfcs_config(m, cfg)
        learned = {}
        if m.get("run"):  # a trained sampler from an experiments/gfcs.py run
            from fabrax.planners.gfcs.selfsup import load_run

            try:
                learned = dict(zip(("learner", "selfsup", "encoding"), load_run(m["run"], robot, gfcs_cfg.n_commands)))
            except (FileNotFoundError, ValueError) as e:
                raise SystemExit(f"fabrax bench: {e}") from None
        batch = m.get("batch_size", 1)
        if not isinstance(batch, int) or isinstance(batch, bool) or batch < 1:
            raise SystemExit(f"fabrax bench: method.batch_size must be a positive integer, got {batch!r}")
        return GFCSMethod(fabric, params, gfcs_cfg, m["name"], tuple(m["report"]), cfg["seed"], **learned, batch_size=batch)
    if kind == "ompl":
        return OMPLMethod(dt=cfg["dt"], **m)
    if kind == "vamp":
        from fabrax.bench.methods import VAMPMethod
        from fabrax.bench.vamp import robot_module

        try:
            robot_module(robot)
        except ValueError as e:
            raise SystemExit(f"fabrax bench: {e}") from None
        return VAMPMethod(dt=cfg["dt"], **m)
    if kind == "rl_guide":
        return rl_guide_method(m, cfg, robot)
    raise SystemExit(f"fabrax bench: unknown method type '{kind}'")


def rl_guide_method(m: dict, cfg: dict, robot):
    """The RL guide from a checkpoint, or (scripted=switch) the env's pure fabric; its env settings
    are the checkpoint's (robot, fabric, env), else the environment's defaults with this run's robot
    and fabric."""
    from fabrax.bench.methods import RLGuideMethod
    from fabrax.rl.config import env_config
    from fabrax.rl.env import FabricGuideEnv

    if m.get("scripted") not in (None, "switch"):
        raise SystemExit(f"fabrax bench: method.scripted must be null or switch, got {m['scripted']!r}")
    if m.get("checkpoint") is None and m.get("scripted") is None:
        raise SystemExit("fabrax bench: method=rl_guide needs method.checkpoint=<experiments/rl.py run directory> (or method.scripted=switch)")
    act, env_settings, fabric_cfg = None, {}, {**cfg["fabric"], "goal_frame": cfg["frame"]}
    if m.get("checkpoint") is not None:
        from fabrax.rl.policy import load_guide

        try:
            guide = load_guide(m["checkpoint"])
        except ValueError as e:
            raise SystemExit(f"fabrax bench: {e}") from None
        act, env_settings, fabric_cfg = guide.act, dict(guide.settings["env"]), guide.settings["fabric"]
        trained = guide.settings["robot"]
        if trained["name"] != robot.name:
            raise SystemExit(f"fabrax bench: the guide was trained on robot '{trained['name']}'; run it with robot={trained['name']}")
        ours = json.loads(json.dumps(cfg.get("robot") or config.load("robot", robot.name)))
        differ = _differing(json.loads(json.dumps(trained)), ours)
        if differ:  # e.g. another sphere budget: other observation shapes, every problem would fail
            raise SystemExit(f"fabrax bench: the guide was trained with other robot settings ({', '.join(differ)}); set them as in its settings.json")
    episode_s = m.get("episode_s", 20.0)
    if isinstance(episode_s, bool) or not isinstance(episode_s, (int, float)) or not episode_s > 0:
        raise SystemExit(f"fabrax bench: method.episode_s must be a positive number of seconds, got {episode_s!r}")
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


def run_bench(cfg: dict, out: Path) -> list[dict]:
    """Run the configured method on the configured problems; write results.json, paths.npz,
    summary.md and plots to `out`, which is claimed before any work (`fabrax.bench.outdir`). Returns
    the rows; after writing them, exits non-zero when every valid problem's method raised or no
    problem is valid."""
    check(cfg)
    try:
        with claim(out, bool(cfg.get("resume", False))):
            return _run_bench(cfg, out)
    except OutDirError as e:
        raise SystemExit(f"fabrax bench: {e}") from None


def _run_bench(cfg: dict, out: Path) -> list[dict]:
    import jax

    from fabrax.bench.metrics import Goal
    from fabrax.bench.runner import CheckpointMismatch, errors, run, summary_table, write

    robot_name = config.robot_choice(cfg)
    hint = "" if os.environ.get("FABRAX_DATA") else " (set FABRAX_DATA or data_dir= to the shared data folder, e.g. ../shared/data)"
    try:
        robot = config.load_robot(robot_name)
        cfg = {**cfg, "frame": cfg.get("frame") or robot.ee_frame}
        robot.frame_index(cfg["frame"])  # an unknown frame= fails here, in one line
        method = make_method(cfg, robot)
    except (ValueError, FileNotFoundError) as e:  # e.g. a robot's sphere file read from the data folder
        raise SystemExit(f"fabrax bench: {e}{hint}") from None
    problem_set: dict = {}
    try:
        problems = load_problems(cfg, robot, problem_set)
    except (ValueError, FileNotFoundError) as e:
        raise SystemExit(f"fabrax bench: {e}{hint}") from None
    t0 = time.perf_counter()
    settings = {k: v for k, v in cfg.items() if k not in ("out", "progress", "resume")}
    try:
        rows = run(
            method,
            robot,
            problems,
            goal=Goal(**cfg["goal"]),
            margin=cfg["margin"],
            frame=cfg["frame"],
            progress=cfg["progress"],
            checkpoint=out / "solutions.pkl",
            settings=settings,
            resume=bool(cfg.get("resume", False)),
        )
    except CheckpointMismatch as e:
        raise SystemExit(f"fabrax bench: {e}") from None
    meta = {
        "config": cfg,
        "robot": robot_name,
        "seed": cfg["seed"],
        "wall_s": time.perf_counter() - t0,
        "versions": {"python": platform.python_version(), "jax": jax.__version__, "fabrax": _version()},
        "source": _source(),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "argv": sys.argv[1:],
        "problem_set": problem_set or None,
    }
    write(rows, out, meta)
    print(summary_table(rows))
    print(f"results: {out / 'results.json'}")
    sys.stdout.flush()
    valid = [r for r in rows if r["valid_problem"]]
    failed = errors(rows)
    if valid and len(failed) == len(valid):
        raise SystemExit(f"fabrax bench: every problem failed with an error ({len(failed)}), e.g. {failed[0]['info']['error']}; results: {out}")
    if not valid:
        reason = rows[0]["invalid_reason"] if rows else "-"
        raise SystemExit(f"fabrax bench: none of the {len(rows)} problems is valid, e.g. {reason}; results: {out}")
    return rows


def _version() -> str:
    from importlib.metadata import version

    return version("fabrax")


def _source() -> dict:
    """Which fabrax ran: its package directory and git commit (None outside a checkout). Before/after
    comparisons run an older commit from a worktree, and `python -m` puts the current directory
    first on the import path, so the version number alone cannot tell them apart."""
    import subprocess

    import fabrax

    root = Path(fabrax.__file__).resolve().parent
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return {"path": str(root), "commit": commit or None}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0
    cfg = compose(argv)
    run_bench(cfg, Path(cfg["out"]))
    if "ompl" in sys.modules:
        os._exit(0)  # OMPL 1.7.0's Python module crashes while the interpreter shuts down
    return 0


if __name__ == "__main__":
    sys.exit(main())
