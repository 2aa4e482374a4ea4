"""The `fabrax` command: `fabrax demo`, and the hydra experiments under `experiments/`."""

from __future__ import annotations

import sys

COMMANDS = {
    "demo": ("fabrax.demo", "run the Panda fabric on the built-in shelf problem"),
    "bench": ("fabrax.bench.cli", "benchmark a method on MotionBenchMaker or generated problems (hydra overrides)"),
    "collect": ("fabrax.bench.collect", "one table of success and EE length over a sweep's run directories"),
    "view": ("fabrax.viz.cli", "browser viewer: demo playback, live fabric control, benchmark results"),
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in COMMANDS:
        print("usage: fabrax <command> [args]\n\ncommands:")
        for name, (_, text) in COMMANDS.items():
            print(f"  {name:10s} {text}")
        return 0 if argv and argv[0] in ("-h", "--help") else 2
    import importlib

    return importlib.import_module(COMMANDS[argv[0]][0]).main(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
