"""`fabrax view`: open the browser viewer.

    fabrax view demo                         # the built-in shelf problem, the fabric's motion played back
    fabrax view live                         # drag the goal gizmo and the obstacles; the fabric reacts in real time
    fabrax view results bench_out/gf bench_out/gfcs   # step through benchmark runs, methods side by side
    fabrax view skill outputs/skills/<time>          # a motion skill's geodesics, plain and reshaped by an obstacle
    fabrax view rl --policy switch                   # the RL guide's environment: one episode (random, switch, hold)
    fabrax view rl --checkpoint pretrained           # the shipped guide (or outputs/rl/<time>) on a held-out scene

Then open http://127.0.0.1:8080 (--port, --host to change; --seconds N serves N seconds and exits).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fabrax view", description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=["demo", "live", "results", "skill", "rl"])
    parser.add_argument("runs", nargs="*", help="results: run directories holding results.json and paths.npz; skill: one skills run")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8080)
    parser.add_argument("--robot", default="panda", help="robot config in configs/robot (results: the run's robot by default)")
    parser.add_argument("--fabric", default="panda", help="fabric config in configs/fabric")
    parser.add_argument("--policy", default="random", choices=["random", "switch", "hold"], help="rl: the actions")
    parser.add_argument("--seed", type=int, default=0, help="rl: the episode's seed")
    parser.add_argument("--checkpoint", default=None, help="rl: a trained guide acts: pretrained (shipped) or an experiments/rl.py run directory")
    parser.add_argument("--seconds", type=float, default=None, help="serve this long, then exit (default: until Ctrl-C)")
    args = parser.parse_args(argv)
    if args.mode in ("results", "skill") and not args.runs:
        parser.error(f"{args.mode}: give a run directory")
    if not 0 <= args.port <= 65535:  # viser's server thread would fail and leave this one waiting forever
        parser.error(f"--port must be in 0-65535, got {args.port}")
    if args.seconds is not None and not args.seconds > 0:
        parser.error(f"--seconds must be positive, got {args.seconds}")

    for run in args.runs if args.mode in ("results", "skill") else ():
        if not (Path(run) / "results.json").is_file():
            what = "a benchmark run directory" if args.mode == "results" else "a skills run directory"
            parser.error(f"{run} is not {what} (no results.json there)")

    from fabrax.viz import app

    robot = args.robot
    try:
        if args.mode == "skill":
            robot = (json.loads((Path(args.runs[0]) / "results.json").read_text()).get("config") or {}).get("robot", robot)
        if args.mode == "results":
            meta = app.load_results(args.runs[0])[0]
            mbm = meta["config"].get("problems") == "mbm"
            robot = meta.get("robot") or (meta.get("config") or {}).get("robot") or ("panda_mbm" if mbm else robot)
    except (OSError, ValueError, KeyError, AttributeError) as e:  # json's errors are ValueErrors
        raise SystemExit(f"fabrax view {args.mode}: {args.runs[0]}: cannot read the run ({type(e).__name__}: {e})") from None
    viewer = app.Viewer(robot, host=args.host, port=args.port)
    if args.mode == "demo":
        print(app.view_demo(viewer, args.fabric))
    elif args.mode == "live":
        app.live(viewer, args.fabric)
    elif args.mode == "skill":
        print(app.skill_view(viewer, args.runs[0]))
    elif args.mode == "rl":
        from fabrax.viz.rl_view import rl_view

        try:
            print(rl_view(viewer, args.fabric, args.policy, args.seed, checkpoint=args.checkpoint))
        except ValueError as e:  # a missing or damaged checkpoint: one line
            viewer.close()
            raise SystemExit(f"fabrax view rl: {e}") from None
    else:
        app.results_browser(viewer, args.runs)
    print(f"fabrax view {args.mode}: http://{args.host}:{viewer.port}", flush=True)
    try:
        time.sleep(args.seconds) if args.seconds is not None else _forever()
    except KeyboardInterrupt:
        pass
    viewer.close()
    return 0


def _forever() -> None:
    while True:
        time.sleep(3600)
