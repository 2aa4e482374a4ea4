"""Motion skills on learned Riemannian manifolds (riemannian_motion_skills_paper), end to end.

    python experiments/skills.py demo=jc              # J/C synthetic skill, task space
    python experiments/skills.py demo=lasa lasa_shape=Sshape
    python experiments/skills.py demo=joint           # joint space, two IK branches, multi-limb obstacle metric
    python experiments/skills.py -m demo=jc,lasa,joint vae.latent=2,4

Trains the VAE, computes Riemannian and Euclidean geodesics between demonstration starts and ends,
reshapes the metric around an obstacle placed on the demonstrated path, executes the geodesics on the
robot with the fabric, and writes results.json, results.md, skill.msgpack and figures to the run directory.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

import fabrax  # noqa: F401  (XLA flags)


@hydra.main(config_path="../configs", config_name="skills", version_base=None)
def main(dcfg: DictConfig) -> None:
    from fabrax.skills.experiment import run

    cfg = OmegaConf.to_container(dcfg, resolve=True)
    run(cfg, Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir))


if __name__ == "__main__":
    main()
