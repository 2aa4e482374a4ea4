"""`fabrax bench key=value ...`: run one method on one problem set (configs/bench.yaml, hydra overrides).

fabrax bench method=gf problems=mbm classes=[box] split=test limit=5 out=bench_out/gf seed=0
fabrax bench method=gf fabric.terms.goal.k_force=3.0 ...      # any fabric gain

Sweeps (hydra multirun, one run directory per job): experiments/bench.py -m ...; see README.
"""

from __future__ import annotations

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
                f"fabrax bench: problems=mbm are MotionBenchMaker's Panda problems; robot={name} cannot run them: "
                "use problems=mbm_like, mpinets_like or mpinets"
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
    """The run's problems (`fabrax.problems.load`), kept solvable by OMPL RRTConnect for
    problems=mpinets; a one-line error for a missing planner or a bad setting."""
    from fabrax.bench.ompl import available, solvable
    from fabrax.problems.load import load_problems as load

    if cfg["problems"] == "mpinets" and cfg.get("solvable_s") and cfg["split"] != "all" and "RRTConnect" not in available():
        hint = "install OMPL (pip install -e '.[bench]') or set solvable_s=null"
        raise SystemExit(f"fabrax bench: problems=mpinets keeps only problems OMPL RRTConnect solves; {hint}")
    try:
        return load(cfg, robot, info, solvable=solvable)
    except ValueError as e:
        raise SystemExit(f"fabrax bench: {e}") from None


def make_method(cfg: dict, robot):
    """The run's method (`fabrax.bench.methods`); a bad method setting ends in one line."""
    from fabrax.bench.methods import make_method as make

    try:
        return make(cfg, robot)
    except ValueError as e:
        raise SystemExit(f"fabrax bench: {e}") from None


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
