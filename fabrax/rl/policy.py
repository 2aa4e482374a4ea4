"""A trained guide from its run directory: settings, networks and the deterministic policy.

`load_guide(path)` takes an experiments/rl.py run directory (its newest checkpoint), one
`checkpoints/<steps>/` directory, or `pretrained`: the guide that ships with fabrax
(fabrax/rl/pretrained/panda, trained on `rl=thesis` scenes; how: its trained.json and
docs/results.md, "The pretrained guide"). A missing or unreadable one is refused with a one-line
`ValueError` naming it.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path
from typing import Any, Callable

from fabrax.rl.networks import LEGACY, make_guide_networks, ppo_observation


@dataclasses.dataclass
class Guide:
    settings: dict[str, Any]  # the run's settings.json
    checkpoint: Path
    params: Any  # (normaliser, policy, value) as brax saves them
    act: Callable  # act(obs) -> action: the deterministic policy on one env's observations (the env's names)
    steps: int  # env steps it was trained for
    network: Any = None  # brax's PPONetworks (the action distribution: `network.parametric_action_distribution`)


PRETRAINED = "pretrained"


def pretrained_dir() -> Path:
    """The shipped guide's run directory (settings.json, trained.json, checkpoints/<steps>/)."""
    return Path(__file__).resolve().parent / "pretrained" / "panda"


def resolve(path: str | Path) -> Path:
    """A guide's path: `pretrained` names the shipped guide, anything else is a path."""
    return pretrained_dir() if str(path) == PRETRAINED else Path(path).resolve()  # orbax takes absolute paths only


def _checkpoint_dir(path: Path) -> tuple[Path, Path]:
    """(checkpoint directory, run directory) of a run directory or a checkpoint directory."""
    from fabrax.rl.train import latest_checkpoint

    if not path.exists():
        raise ValueError(f"no guide checkpoint at {path}: the path does not exist")
    if (path / "ppo_network_config.json").exists():
        return path, path.parent.parent
    ckpt = latest_checkpoint(path)
    if ckpt is None:
        raise ValueError(f"no guide checkpoint at {path}: expected an experiments/rl.py run directory with checkpoints/<steps>/")
    return ckpt, path


def read_settings(path: str | Path) -> dict:
    """A run's settings.json; a run recorded before `network.std` and `network.loc_bound` existed
    had a scale output per state and an unbounded mean (`fabrax.rl.networks.LEGACY`)."""
    settings = json.loads(Path(path).read_text())
    if isinstance(settings.get("network"), dict):
        settings["network"] = {**LEGACY, **settings["network"]}
    return settings


def load_guide(path: str | Path) -> Guide:
    import jax
    from brax.training import checkpoint as brax_checkpoint
    from brax.training.agents.ppo import checkpoint as ppo_checkpoint
    from brax.training.agents.ppo import networks as ppo_networks

    ckpt, run = _checkpoint_dir(resolve(path))
    settings_path = run / "settings.json"
    if not settings_path.exists():
        raise ValueError(f"{settings_path}: missing (the run's settings are needed to rebuild its environment)")
    try:
        settings = read_settings(settings_path)
        config = ppo_checkpoint.load_config(ckpt)
        for key, value in LEGACY.items():  # a checkpoint from before the option
            if key not in config.network_factory_kwargs:
                config.network_factory_kwargs[key] = value
        params = ppo_checkpoint.load(ckpt)
        network = brax_checkpoint.get_network(config, functools.partial(make_guide_networks, shift=True))  # acting only
    except Exception as e:  # orbax / json errors of a damaged checkpoint, whatever their type
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise ValueError(f"{ckpt}: unreadable guide checkpoint ({type(e).__name__}: {first})") from None
    policy = ppo_networks.make_inference_fn(network)(params, deterministic=True)
    key = jax.random.PRNGKey(0)  # unused by the deterministic policy

    def act(obs):
        batched = jax.tree.map(lambda x: x[None], ppo_observation(obs))
        return policy(batched, key)[0][0]

    return Guide(settings, ckpt, params, act, int(ckpt.name), network)
