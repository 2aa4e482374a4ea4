"""Train the RL guide with brax's PPO (fabrics_guided_rl_thesis §3.4.4-3.4.6): `fabrax.rl.train`.

    python experiments/rl.py                                   # cpu preset
    python experiments/rl.py rl=dresser                        # the CPU evidence: one scene family
    python experiments/rl.py rl=gpu                            # 4096 envs
    python experiments/rl.py resume=true hydra.run.dir=<run>   # continue from the newest checkpoint
    FABRAX_CPU_DEVICES=2 python experiments/rl.py              # on a 2-core CPU: one XLA device per core

Writes settings.json, checkpoints/<env steps>/ (brax), progress.jsonl and curves.png in the run
directory; evaluate a checkpoint with `fabrax bench method=rl_guide method.checkpoint=<run>`.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import hydra
from omegaconf import DictConfig

import fabrax  # noqa: F401  (XLA flags)

log = logging.getLogger("fabrax.rl")


@hydra.main(config_path="../configs", config_name="rl", version_base=None)
def main(dcfg: DictConfig) -> None:
    from fabrax import config
    from fabrax.rl.train import train

    cfg = config.resolve(dcfg)
    out = Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)
    logging.getLogger("absl").setLevel(logging.WARNING)
    settings = {k: cfg[k] for k in ("robot", "fabric", "env", "eval_scenes", "network", "curriculum", "ppo")}
    import jax

    cores = os.cpu_count() or 1
    if jax.default_backend() == "cpu" and jax.local_device_count() == 1 and cores > 1:
        log.info("one XLA CPU device on %d cores; FABRAX_CPU_DEVICES=%d splits the envs over them (brax's pmap)", cores, cores)
    try:
        train(settings, out, resume=bool(cfg["resume"]), data_dir=cfg.get("data_dir"))
    except ValueError as e:  # a user's settings: one line, no traceback
        raise SystemExit(f"experiments/rl.py: {e}") from None
    log.info("run directory: %s", out)


if __name__ == "__main__":
    main()
