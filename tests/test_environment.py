"""The process environment fabrax sets before jax starts, and compatibility across the JAX range."""

import json
import os
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fabrax import _environment as E
from fabrax import compat


def test_fusion_flag_only_for_jaxlib_that_knows_it_and_only_on_cpu():
    assert E.cpu_flags("0.9.2", on_cpu=True) == [E.FUSION_FLAG]
    assert E.cpu_flags("0.10.2", on_cpu=True) == [E.FUSION_FLAG]
    assert E.cpu_flags("0.11.2", on_cpu=True) == []  # jaxlib 0.11 aborts on the unknown flag
    assert E.cpu_flags("0.12.0.dev20270101", on_cpu=True) == []
    assert E.cpu_flags("0.9.2", on_cpu=False) == []  # never for a GPU or TPU process
    assert E.cpu_flags(None, on_cpu=True) == []


def test_xla_flags_keep_the_users_and_add_devices():
    assert E.xla_flags("", "0.9.2", True) == E.FUSION_FLAG
    assert E.xla_flags("--xla_cpu_use_fusion_emitters=true", "0.9.2", True) == "--xla_cpu_use_fusion_emitters=true"
    assert E.xla_flags("--foo=1", "0.11.2", True, "4") == "--foo=1 --xla_force_host_platform_device_count=4"
    assert E.xla_flags("--xla_force_host_platform_device_count=8", "0.11.2", True, "2") == "--xla_force_host_platform_device_count=8"
    with pytest.raises(ValueError, match="FABRAX_CPU_DEVICES"):
        E.xla_flags("", "0.9.2", True, "two")


def test_cpu_is_told_by_jax_platforms_or_the_installed_plugins():
    none = lambda d: None  # noqa: E731
    cuda = lambda d: "0.11.2" if d == "jax-cuda13-plugin" else None  # noqa: E731
    assert E.computes_on_cpu({}, none)
    assert not E.computes_on_cpu({}, cuda)
    assert E.computes_on_cpu({"JAX_PLATFORMS": "cpu"}, cuda)
    assert not E.computes_on_cpu({"JAX_PLATFORMS": "cuda,cpu"}, none)


def test_hosts_with_other_instruction_sets_get_other_cache_folders():
    a = "model name\t: AMD EPYC 9R14\nflags\t\t: fpu sse avx2 avx512f\n" * 2
    b = "model name\t: AMD EPYC 9R14\nflags\t\t: fpu sse avx2\n"
    assert E.host_digest(a) == E.host_digest(a[: len(a) // 2])  # one line of each kind counts, not the core count
    assert E.host_digest(a) != E.host_digest(b)
    assert len(E.host_digest()) == 12


def test_compile_cache_dir_follows_fabrax_cache_and_can_be_turned_off(tmp_path):
    env = {"FABRAX_CACHE": str(tmp_path)}
    assert E.compile_cache_dir(env, "0.10.2") == str(tmp_path / "jax" / E.host_digest())
    assert E.compile_cache_dir({**env, "FABRAX_COMPILE_CACHE": "0"}, "0.10.2") is None
    assert E.compile_cache_dir({"JAX_COMPILATION_CACHE_DIR": "/elsewhere", "FABRAX_COMPILE_CACHE": "0"}) == "/elsewhere"
    # jaxlib 0.9 on a CPU: off unless asked for (its loader logs false mismatches); on a GPU, on
    assert E.compile_cache_dir(env, "0.9.2") is None
    assert E.compile_cache_dir({**env, "FABRAX_COMPILE_CACHE": "1"}, "0.9.2") == str(tmp_path / "jax" / E.host_digest())
    assert E.compile_cache_dir(env, "0.9.2", on_cpu=False) == str(tmp_path / "jax" / E.host_digest())


def _child(code: str, **env) -> dict:
    base = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_COMPILATION_CACHE_DIR", "FABRAX_COMPILE_CACHE")}
    out = subprocess.run([sys.executable, "-c", code], env={**base, **env}, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_second_process_loads_the_compiled_program_from_the_cache(tmp_path):
    """The persistent cache is on by default: the second process compiling the same program finds
    its executable on disk (jax's cache-hit counter), the first one does not."""
    code = (
        "import json, fabrax, jax, jax.numpy as jnp\n"
        "from jax._src import monitoring\n"
        "hits = []\n"
        "monitoring.register_event_listener(lambda e, **k: hits.append(e) if e == '/jax/compilation_cache/cache_hits' else None)\n"
        "jax.config.update('jax_persistent_cache_min_compile_time_secs', 0)\n"
        "f = jax.jit(lambda x: jnp.sin(x) @ jnp.cos(x).T + 1.0)\n"
        "f(jnp.ones((8, 8))).block_until_ready()\n"
        "flags = __import__('os').environ.get('XLA_FLAGS', '')\n"
        "print(json.dumps({'dir': jax.config.jax_compilation_cache_dir, 'flags': flags, 'hits': len(hits)}))\n"
    )
    first = _child(code, FABRAX_CACHE=str(tmp_path), FABRAX_COMPILE_CACHE="1")  # on for every jaxlib
    second = _child(code, FABRAX_CACHE=str(tmp_path), FABRAX_COMPILE_CACHE="1")
    assert first["dir"] == str(tmp_path / "jax" / E.host_digest())
    assert any(Path(first["dir"]).iterdir())
    assert first["hits"] == 0 and second["hits"] >= 1
    off = _child(code, FABRAX_CACHE=str(tmp_path / "off"), FABRAX_COMPILE_CACHE="0")
    assert off["dir"] is None and not (tmp_path / "off").exists()
    expect_flag = E.computes_on_cpu() and E.version_tuple(version("jaxlib")) < E.FUSION_FLAG_LAST
    assert (E.FUSION_FLAG in first["flags"]) == expect_flag


def test_device_put_replicated_for_brax():
    """brax 0.14's PPO calls `jax.device_put_replicated`; after `brax_ppo()` it works on this jax, and
    the public-API fallback replicates the same way."""
    ppo = compat.brax_ppo()
    assert callable(ppo.train)
    devices = jax.local_devices()
    tree = {"w": jnp.arange(6.0).reshape(2, 3), "step": jnp.asarray(3)}
    for fn in (jax.device_put_replicated, compat.device_put_replicated):
        out = fn(tree, devices)
        assert out["w"].shape == (len(devices), 2, 3) and out["step"].shape == (len(devices),)
        np.testing.assert_array_equal(np.asarray(out["w"][0]), np.asarray(tree["w"]))
        assert {d for s in out["w"].addressable_shards for d in [s.device]} == set(devices)
        # what brax does with it: a pmapped function over the replicas
        summed = jax.pmap(lambda t: t["w"].sum() + t["step"])(out)
        np.testing.assert_allclose(np.asarray(summed), np.full(len(devices), 18.0))


_BRAX_EVALUATION = """
import json
import jax, jax.numpy as jnp
from fabrax import compat
compat.brax_ppo()
from brax import envs
from brax.envs.base import Env, State
from brax.training import acting
from brax.training.acme import running_statistics

class Toy(Env):
    observation_size, action_size, backend = 2, 2, "toy"

    def reset(self, rng):
        z = jnp.zeros(())
        return State(pipeline_state=None, obs=jnp.zeros(2), reward=z, done=z, metrics={"x": z}, info={})

    def step(self, s, action):
        return s.replace(obs=s.obs + action, reward=jnp.sum(action), metrics={**s.metrics, "x": s.metrics["x"] + 1.0})

policy = lambda w: lambda obs, key: (w * jnp.ones_like(obs), {})
env = envs.training.wrap(Toy(), episode_length=4)
ev = acting.Evaluator(env, policy, num_eval_envs=2, episode_length=4, action_repeat=1, key=jax.random.PRNGKey(0))
replicated = jax.pmap(lambda x: x * 1.0)(jnp.full((jax.local_device_count(),), 0.5))
params = replicated[0]  # as brax's PPO passes its parameters (`_unpmap`)
lowered = []
jax.monitoring.register_event_duration_secs_listener(lambda e, s, **kw: lowered.append(e) if e.endswith("jaxpr_to_mlir_module_duration") else None)
ev.run_evaluation(params, {})
first = len(lowered)
for _ in range(2):
    ev.run_evaluation(params, {})
later = len(lowered) - first
weak = jax.eval_shape(lambda s: s, running_statistics.init_state(jnp.zeros(3))).std_eps.weak_type
print(json.dumps({"devices": jax.local_device_count(), "first": first, "later": later, "weak": weak}))
"""


@pytest.mark.parametrize("devices", [1, 2])
def test_brax_evaluation_compiles_its_unroll_once(devices):
    """After `brax_ppo()`: the normaliser's initial `std_eps` is typed as every update returns it,
    and brax's evaluator, run first from its own initial state and then from the state its unroll
    returned, with parameters placed as PPO places them (replicated over every device), lowers and
    compiles the unroll once, on one device and on two (it did twice: the first state was not
    committed to a device)."""
    env = {**os.environ, "FABRAX_CPU_DEVICES": str(devices)}
    out = subprocess.run([sys.executable, "-c", _BRAX_EVALUATION], capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["devices"] == devices and not got["weak"]
    assert got["first"] >= 1 and got["later"] == 0


def test_importing_the_rl_guide_prints_no_optional_backend_notices():
    """mujoco-mjx prints two "Failed to import warp" lines without NVIDIA Warp; fabrax drops them."""
    out = subprocess.run(
        [sys.executable, "-c", "import fabrax.rl, brax.training.agents.ppo.train; print('ok')"], capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines() == ["ok"] and "warp" not in out.stderr.lower()
