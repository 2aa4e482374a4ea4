"""Ship a trained guide as fabrax's `pretrained` one (fabrax/rl/pretrained/panda).

    python experiments/ship_guide.py outputs/rl/<run> --step 128000 --curves docs/results/rl_thesis

Copies the run's settings.json and the checkpoint of `--step` (default: the newest) into the
package, and writes trained.json: the command that trained it (from the run's hydra overrides,
`resume=true` dropped: say in `--note` where a run was resumed),
the env steps, the wall time at that step, the hardware and the library versions. `--curves`
copies progress.jsonl and curves.png beside the results. The guide is then loadable as
`method.checkpoint=pretrained` and by `fabrax view rl --checkpoint pretrained`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="an experiments/rl.py run directory")
    ap.add_argument("--step", type=int, default=None, help="the checkpoint's env steps (default: the newest)")
    ap.add_argument("--curves", type=Path, default=None, help="copy progress.jsonl and curves.png here")
    ap.add_argument("--into", type=Path, default=None, help="where to put it (default: the package's pretrained guide)")
    ap.add_argument("--note", default="", help="how the run went, e.g. where it was resumed (kept in trained.json)")
    args = ap.parse_args(argv)

    import jax

    from fabrax.rl.policy import pretrained_dir
    from fabrax.rl.train import latest_checkpoint

    run = args.run.resolve()
    ckpt = latest_checkpoint(run) if args.step is None else run / "checkpoints" / f"{args.step:012d}"
    if ckpt is None or not ckpt.is_dir():
        print(f"ship_guide: no checkpoint {'' if args.step is None else args.step} in {run / 'checkpoints'}", file=sys.stderr)
        return 2
    steps = int(ckpt.name)
    rows = [json.loads(line) for line in (run / "progress.jsonl").read_text().splitlines() if line.strip()]
    evals = {r["step"]: r for r in rows if "eval" in r}
    overrides_path = run / ".hydra" / "overrides.yaml"
    overrides = [line[2:].strip() for line in overrides_path.read_text().splitlines() if line.startswith("- ")] if overrides_path.exists() else []
    overrides = [o for o in overrides if not o.startswith(("hydra.", "resume="))]
    settings = json.loads((run / "settings.json").read_text())
    devices = jax.devices()
    trained = {
        "command": " ".join(["python experiments/rl.py", *overrides]),
        "steps": steps,
        "wall_s": evals.get(steps, rows[-1])["wall_s"],
        "hardware": f"{os.cpu_count()} x {_cpu()}" if devices[0].platform == "cpu" else f"{len(devices)} x {devices[0].device_kind}",
        "devices": evals.get(steps, rows[-1]).get("devices", 1),
        "num_envs": settings["ppo"]["num_envs"],
        "held_out_eval": evals.get(steps, {}).get("eval"),
        "note": args.note,
        "versions": {"jax": jax.__version__, "brax": __import__("brax").__version__, "python": platform.python_version()},
    }
    out = (args.into or pretrained_dir()).resolve()
    if out.exists():
        shutil.rmtree(out)
    (out / "checkpoints").mkdir(parents=True)
    shutil.copy(run / "settings.json", out / "settings.json")
    shutil.copytree(ckpt, out / "checkpoints" / ckpt.name)
    (out / "trained.json").write_text(json.dumps(trained, indent=2) + "\n")
    if args.curves:
        args.curves.mkdir(parents=True, exist_ok=True)
        for name in ("progress.jsonl", "curves.png", "settings.json"):
            if (run / name).exists():
                shutil.copy(run / name, args.curves / name)
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    print(f"shipped {ckpt} ({steps} env steps, {size / 1e6:.1f} MB) to {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
