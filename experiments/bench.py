"""`fabrax bench` as a hydra app, for sweeps: every job gets its own run directory holding hydra's
resolved config (.hydra/), results.json (with seed and versions), paths.npz and summary.md.

    python experiments/bench.py method=gf problems=mbm classes=[box] limit=10
    python experiments/bench.py -m method=gf classes=[box],[cage] fabric.terms.goal.k_force=3.0,4.2 limit=10
    python experiments/bench.py -m hydra/launcher=fabrax_joblib ...     # jobs in parallel on this machine
    python experiments/bench.py -m hydra/launcher=fabrax_slurm ...      # jobs on a Slurm cluster (submitit)
    fabrax collect multirun/bench/<date>                                # one table over the sweep
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from fabrax import config


@hydra.main(config_path="../configs", config_name="bench", version_base=None)
def main(dcfg: DictConfig) -> None:
    from fabrax.bench.cli import run_bench

    cfg = config.resolve(dcfg)
    run_bench(cfg, Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir))


if __name__ == "__main__":
    main()
