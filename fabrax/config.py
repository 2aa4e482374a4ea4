"""Config files: the repository's `configs/` tree (hydra config groups)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf


def config_dir() -> Path:
    """The hydra config root: $FABRAX_CONFIGS, else the `configs/` folder of a source checkout (beside
    the package), else the copy an installed wheel carries as `fabrax/configs`."""
    env = os.environ.get("FABRAX_CONFIGS")
    here = Path(__file__).resolve().parent
    candidates = [Path(env)] if env else [here.parent / "configs", here / "configs"]
    for path in candidates:
        if path.is_dir():
            return path
    raise ValueError(f"config folder {candidates[0]} not found: set FABRAX_CONFIGS")


def _load_node(group: str, name: str):
    path = config_dir() / group / f"{name}.yaml"
    if not path.exists():
        options = sorted(p.stem for p in (config_dir() / group).glob("*.yaml"))
        raise ValueError(f"no config '{name}' in group '{group}' (options: {', '.join(options)})")
    node = OmegaConf.load(path)
    defaults = node.pop("defaults", [])
    # a hydra defaults list of configs in the same group, then this file (`_self_`)
    parts = [_load_node(group, d) for d in defaults if d != "_self_"]
    return OmegaConf.merge(*parts, node) if parts else node


def load(group: str, name: str) -> dict[str, Any]:
    """One config of a group (e.g. load('robot', 'panda')) as a plain dict, its defaults list merged
    and interpolations resolved."""
    return OmegaConf.to_container(_load_node(group, name), resolve=True)


def load_robot(name: str | dict = "panda"):
    """A `Robot` from configs/robot/<name>.yaml, or from an already composed robot config (a dict,
    e.g. the `robot` group of a hydra config with overrides such as robot.spheres.budget=40)."""
    from fabrax.robot import build_robot

    return build_robot(load("robot", name) if isinstance(name, str) else name)


def robot_choice(cfg: dict) -> str | dict:
    """The robot of an experiment config: its `robot` group if one was chosen (robot=NAME), else
    panda_mbm for MotionBenchMaker problems (cuRobo's spheres, MBM's finger opening) and panda otherwise."""
    return cfg.get("robot") or ("panda_mbm" if cfg.get("problems") == "mbm" else "panda")


def resolve(cfg) -> dict[str, Any]:
    """A composed hydra config as a plain dict. Its `data_dir` becomes $FABRAX_DATA first when that
    is unset, so that the config files interpolating $FABRAX_DATA (the robot's sphere file) read it."""
    data_dir = cfg.get("data_dir")
    if data_dir and not os.environ.get("FABRAX_DATA"):
        os.environ["FABRAX_DATA"] = str(Path(data_dir).resolve())
    return OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)


def load_fabric(robot, name: str | dict = "panda"):
    """An `ArmFabric` and its default parameters from configs/fabric/<name>.yaml, or from an already
    composed fabric config (a dict, e.g. the `fabric` group of a hydra config with overrides)."""
    from fabrax.fabrics import build_arm_fabric

    fabric = build_arm_fabric(robot, load("fabric", name) if isinstance(name, str) else name)
    return fabric, fabric.init()
