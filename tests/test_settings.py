"""One config mechanism: typed dataclasses hold the defaults, `fabrax.settings.from_mapping` builds
them from preset mappings, names an unknown key or a wrongly typed value, and the shipped presets
compose to the dataclasses' defaults where they claim to."""

import dataclasses

import pytest

from fabrax.settings import check_keys, from_mapping


@dataclasses.dataclass(frozen=True)
class Inner:
    steps: int = 50
    noise: float = 0.1


@dataclasses.dataclass(frozen=True)
class Outer:
    rate: float = 1e-3
    on: bool = True
    name: str = "a"
    limit: float | None = None
    widths: tuple[int, ...] = (8, 8)
    box: tuple[float, float, float] = (0.0, 0.0, 0.0)
    counts: tuple[tuple[str, int], ...] = ()
    inner: Inner = Inner(steps=20)


def test_values_are_converted_to_their_field_types_over_the_defaults():
    got = from_mapping(Outer, {"rate": 1, "widths": [4, 2], "box": [1, 2, 3], "counts": [["a", 1]], "limit": None}, "outer")
    assert got == Outer(rate=1.0, widths=(4, 2), box=(1.0, 2.0, 3.0), counts=(("a", 1),))
    assert isinstance(got.rate, float) and hash(got)  # hashable: a jit static argument
    assert from_mapping(Outer, None, "outer") == Outer() and from_mapping(Outer, got, "outer") is got


def test_a_nested_mapping_overrides_the_fields_own_default():
    got = from_mapping(Outer, {"inner": {"noise": 0.5}}, "outer")
    assert got.inner == Inner(steps=20, noise=0.5)  # steps stays Outer's default for inner, not Inner's 50


@pytest.mark.parametrize(
    "mapping, message",
    [
        ({"rte": 1.0}, r"unknown outer keys \['rte'\] \(known: box, counts, inner, limit, name, on, rate, widths\)"),
        ({"inner": {"stepz": 3}}, r"unknown outer.inner keys \['stepz'\]"),
        ({"rate": "fast"}, r"outer.rate must be a number, got 'fast'"),
        ({"on": 1}, r"outer.on must be true or false, got 1"),
        ({"inner": {"steps": 2.5}}, r"outer.inner.steps must be an integer, got 2.5"),
        ({"widths": [4, "x"]}, r"outer.widths\[1\] must be an integer, got 'x'"),
        ({"box": [1, 2]}, r"outer.box must have 3 entries, got 2"),
        ({"limit": "none"}, r"outer.limit must be a number, got 'none'"),
        ({"name": 3}, r"outer.name must be a string, got 3"),
    ],
)
def test_bad_values_raise_one_line_naming_the_key(mapping, message):
    with pytest.raises(ValueError, match=message) as e:
        from_mapping(Outer, mapping, "outer")
    assert "\n" not in str(e.value)


def test_check_keys_names_the_unknown_ones():
    check_keys({"a": 1}, ("a", "b"), "thing")
    with pytest.raises(ValueError, match=r"unknown thing keys \['c'\] \(known: a, b\)"):
        check_keys({"a": 1, "c": 2}, ("a", "b"), "thing")


def _preset(name: str) -> dict:
    import yaml

    from fabrax import config

    return yaml.safe_load((config.config_dir() / f"{name}.yaml").read_text())


def test_presets_build_their_dataclasses():
    """configs/gfcs.yaml's selfsup and encoding sections and configs/skills.yaml's sections are
    fields of their dataclasses; a misspelt key in a preset would fail here."""
    from fabrax.planners.gfcs.selfsup import SelfSupConfig, settings
    from fabrax.skills import execute, geodesic, vae

    gfcs = _preset("gfcs")
    ss, enc = settings(gfcs)
    assert isinstance(ss, SelfSupConfig) and ss.sgld.steps == gfcs["selfsup"]["sgld"]["steps"]
    assert enc.low == tuple(gfcs["encoding"]["low"])
    skills = _preset("skills")
    from_mapping(vae.VAEConfig, {**skills["vae"], "seed": skills["seed"]}, "vae")
    from_mapping(geodesic.GeodesicConfig, skills["geodesic"], "geodesic")
    from_mapping(execute.FollowConfig, skills["follow"], "follow")


def test_a_badly_typed_method_key_is_named():
    from fabrax import config
    from fabrax.bench.methods.gfcs import gfcs_config

    with pytest.raises(ValueError, match="method.population must be an integer, got 'many'"):
        gfcs_config({**config.load("method", "gfcs"), "population": "many"}, {"dt": 0.01, "t_max": 7.0})


def test_the_rl_base_preset_restates_the_dataclass_defaults():
    """configs/rl.yaml lists every PPO and env setting so hydra can override it; its values are
    the typed defaults (the presets under configs/rl/ differ), so the CLI and `train()` agree."""
    import dataclasses

    from fabrax.rl.config import EnvConfig, ScenesConfig
    from fabrax.rl.train import PPOConfig

    base = _preset("rl")
    assert base["ppo"] == dataclasses.asdict(PPOConfig())
    env = dict(base["env"])
    scenes = env.pop("scenes")
    for key, value in env.items():
        assert value == getattr(EnvConfig(), key), key
    assert scenes["generated"] == dict(ScenesConfig().generated)


def test_ppo_schedules_map_to_brax_arguments():
    """FIXED is brax's ADAPTIVE_KL clamped to the rate (the normaliser moves after the update, the
    rate never moves); NONE and ADAPTIVE_KL pass through; anything else is named."""
    from fabrax.rl.train import brax_kwargs, ppo_config

    fixed = brax_kwargs(ppo_config({}))
    assert fixed["learning_rate_schedule"] == "ADAPTIVE_KL"
    assert fixed["learning_rate_schedule_min_lr"] == fixed["learning_rate_schedule_max_lr"] == fixed["learning_rate"]
    assert "num_timesteps" not in fixed
    none = brax_kwargs(ppo_config({"learning_rate_schedule": "NONE"}))
    assert none["learning_rate_schedule"] == "NONE" and "learning_rate_schedule_min_lr" not in none
    with pytest.raises(ValueError, match=r"ppo.learning_rate_schedule must be one of \['FIXED', 'NONE', 'ADAPTIVE_KL'\], got 'COSINE'"):
        ppo_config({"learning_rate_schedule": "COSINE"})
