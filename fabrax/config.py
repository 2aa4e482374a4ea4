"""Config files: the repository's `configs/` tree (hydra config groups)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf


def config_dir() -> Path:
    """The hydra config root: $FABRAX_CONFIGS or the `configs/` folder beside the package."""
    env = os.environ.get("FABRAX_CONFIGS")
    path = Path(env) if env else Path(__file__).resolve().parent.parent / "configs"
    if not path.is_dir():
        raise ValueError(f"config folder {path} not found: set FABRAX_CONFIGS")
    return path


def load(group: str, name: str) -> dict[str, Any]:
    """One config of a group (e.g. load('robot', 'panda')) as a plain dict, interpolations resolved."""
    path = config_dir() / group / f"{name}.yaml"
    if not path.exists():
        options = sorted(p.stem for p in (config_dir() / group).glob("*.yaml"))
        raise ValueError(f"no config '{name}' in group '{group}' (options: {', '.join(options)})")
    return OmegaConf.to_container(OmegaConf.load(path), resolve=True)
