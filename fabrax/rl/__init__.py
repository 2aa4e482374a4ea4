"""RL guide (thesis ch. 3-4): the fabric-guided arm environment in brax's Env API."""

from fabrax.compat import quiet_mjx

quiet_mjx()  # before brax imports it: without its optional Warp backend's notices

from fabrax.rl.config import EnvConfig, ScenesConfig, env_config  # noqa: E402
from fabrax.rl.env import METRICS, Episode, FabricGuideEnv, make_env  # noqa: E402
from fabrax.rl.scenes import ScenePool, build_pool, sample_episode  # noqa: E402

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
