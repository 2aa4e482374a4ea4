"""RL guide (thesis ch. 3-4): the fabric-guided arm environment in brax's Env API."""

from fabrax.rl.config import EnvConfig, ScenesConfig, env_config
from fabrax.rl.env import METRICS, Episode, FabricGuideEnv, make_env
from fabrax.rl.scenes import ScenePool, build_pool, sample_episode

__all__ = [
    "METRICS",
    "EnvConfig",
    "Episode",
    "FabricGuideEnv",
    "ScenePool",
    "ScenesConfig",
    "build_pool",
    "env_config",
    "make_env",
    "sample_episode",
]
