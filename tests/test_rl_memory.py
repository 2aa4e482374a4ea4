"""The rollout-memory check that refuses a PPO preset too large for its device before training."""

import dataclasses

import pytest

from fabrax.rl.memory import check_rollout_fits, observation_floats, rollout_bytes
from fabrax.rl.train import PPOConfig

PANDA_OBS = {  # the guide's observation for the Panda (RLGuideEnv.observation_size, thesis Table 3.2)
    "goal_keypoints": (24,),
    "q": (7,),
    "hand_keypoints": (24,),
    "fabric_q": (7,),
    "fabric_qd": (7,),
    "fabric_qdd": (7,),
    "bps": (16, 16, 16, 3),
    "dynamic_bps": (60,),
    "exploration": (20, 20, 20, 1),
    "switch": (1,),
}
GIB = 1024**3


def _gpu_preset() -> PPOConfig:
    import yaml

    from fabrax import config

    base = yaml.safe_load((config.config_dir() / "rl.yaml").read_text())["ppo"]
    preset = yaml.safe_load((config.config_dir() / "rl" / "gpu.yaml").read_text())["ppo"]
    return PPOConfig(**{**base, **preset})


def test_rollout_floor_counts_two_observations_per_transition():
    assert observation_floats(PANDA_OBS) == 20425
    assert rollout_bytes(8, 4, 2, {"x": (3,)}) == 2 * 64 * 3 * 4


def test_the_gpu_preset_fits_one_80_gb_gpu_and_its_old_size_did_not():
    p = _gpu_preset()
    assert check_rollout_fits(p, PANDA_OBS, devices=1, limit=78 * GIB) < 78 * GIB
    old = dataclasses.replace(p, num_minibatches=32)  # the preset before it was sized: ~80 GiB of observations
    with pytest.raises(ValueError, match=r"ppo: one training step keeps at least .* lower ppo.num_minibatches"):
        check_rollout_fits(old, PANDA_OBS, devices=1, limit=78 * GIB)
    assert check_rollout_fits(old, PANDA_OBS, devices=2, limit=78 * GIB)  # split over two devices it fits
