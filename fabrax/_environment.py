"""The process environment fabrax sets before jax starts its backends: XLA flags and the compile cache.

Kept free of jax imports: XLA reads `XLA_FLAGS` once, when its first backend starts, and jax reads
its `JAX_*` options when it is imported, so `fabrax/__init__.py` calls `prepare()` first.

- `--xla_cpu_use_fusion_emitters=false`: XLA's CPU fusion emitters compile long chains of small
  ops (kinematics, per-sphere terms) exponentially slowly. The flag is a CPU backend option that
  jaxlib 0.11 removed, and an unknown flag in `XLA_FLAGS` aborts the process when any backend
  starts, GPU included; so it is set only for jaxlib < 0.11 and only where the process computes on
  the CPU (no GPU/TPU plugin installed, or `JAX_PLATFORMS` starting with `cpu`).
- `FABRAX_CPU_DEVICES=N`: N XLA host devices, so that batches shard over N cores (`fabrax.sharding`).
- The persistent compilation cache (`JAX_COMPILATION_CACHE_DIR`) under
  `$FABRAX_CACHE/jax/<host>` (default `~/.cache/fabrax/jax/<host>`): a second process that
  compiles the same program (the same demo, bench or solver shapes) loads it instead. `<host>` is
  a digest of the processor's model and instruction-set flags: XLA's CPU executables are built for
  the host's instruction set, and a home directory shared by the nodes of a cluster must not hand
  one node's AVX-512 code to another. `FABRAX_COMPILE_CACHE=0` turns it off, `=1` on; a
  `JAX_COMPILATION_CACHE_DIR` set by the user wins. On a CPU with jaxlib < 0.10 it stays off
  unless asked for: that jaxlib's loader logs a false "machine type ... doesn't match" error of a few
  thousand characters for every executable it loads on some processors (AMD EPYC among them).
"""

from __future__ import annotations

import hashlib
import os
import platform
import re
from importlib import metadata
from pathlib import Path

FUSION_FLAG = "--xla_cpu_use_fusion_emitters=false"
FUSION_FLAG_LAST = (0, 11)  # the first jaxlib release that no longer knows the flag
ACCELERATOR_PLUGINS = ("jax-cuda12-plugin", "jax-cuda13-plugin", "jax-rocm6-plugin", "jax-rocm7-plugin", "libtpu", "libtpu-nightly")


def version_tuple(text: str) -> tuple[int, ...]:
    """'0.10.2' -> (0, 10, 2); a suffix such as '.dev20260101' or 'rc1' is dropped."""
    return tuple(int(m) for m in re.findall(r"\d+", text.split("+")[0])[:3])


def _installed(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def computes_on_cpu(env: dict[str, str] | None = None, installed=_installed) -> bool:
    """Whether jax will pick the CPU as its default backend: `JAX_PLATFORMS` names it first, or,
    unset, no accelerator plugin is installed."""
    env = os.environ if env is None else env
    platforms = env.get("JAX_PLATFORMS", "").strip()
    if platforms:
        return platforms.split(",")[0].strip().lower() == "cpu"
    return not any(installed(d) for d in ACCELERATOR_PLUGINS)


def cpu_flags(jaxlib_version: str | None, on_cpu: bool) -> list[str]:
    """The CPU-only XLA flags this jaxlib accepts, for a process that computes on the CPU."""
    if not on_cpu or jaxlib_version is None or version_tuple(jaxlib_version) >= FUSION_FLAG_LAST:
        return []
    return [FUSION_FLAG]


def xla_flags(current: str, jaxlib_version: str | None, on_cpu: bool, cpu_devices: str = "") -> str:
    """`XLA_FLAGS` with fabrax's flags added; a flag the user set already is left as it is."""
    flags = current.split()
    for flag in cpu_flags(jaxlib_version, on_cpu):
        if not any(f.split("=")[0] == flag.split("=")[0] for f in flags):
            flags.append(flag)
    if cpu_devices:
        if not cpu_devices.isdigit() or int(cpu_devices) < 1:
            raise ValueError(f"FABRAX_CPU_DEVICES must be a positive integer, got '{cpu_devices}'")
        if not any(f.startswith("--xla_force_host_platform_device_count") for f in flags):
            flags.append(f"--xla_force_host_platform_device_count={cpu_devices}")
    return " ".join(flags)


def cache_root(env: dict[str, str] | None = None) -> Path:
    """fabrax's on-disk cache: `$FABRAX_CACHE`, default `~/.cache/fabrax` (fitted spheres, compiled programs)."""
    env = os.environ if env is None else env
    return Path(env.get("FABRAX_CACHE") or Path.home() / ".cache" / "fabrax")


def host_digest(cpuinfo: str | None = None) -> str:
    """12 hex digits naming this host's processor: its model and instruction-set flags (Linux's
    /proc/cpuinfo; elsewhere the platform's processor string)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            cpuinfo = f"{platform.machine()} {platform.processor()}"
    keep = [line for line in cpuinfo.splitlines() if line.split(":")[0].strip() in ("model name", "flags", "Features", "CPU part")]
    text = "\n".join(dict.fromkeys(keep)) or cpuinfo  # one line of each kind: the cores are alike
    return hashlib.sha256(f"{platform.machine()}\n{text}".encode()).hexdigest()[:12]


CACHE_QUIET = (0, 10)  # the first jaxlib whose CPU loader does not log false machine mismatches


def compile_cache_dir(env: dict[str, str] | None = None, jaxlib_version: str | None = None, on_cpu: bool = True) -> str | None:
    """Where jax's persistent compilation cache goes, or None when it stays off."""
    env = os.environ if env is None else env
    if env.get("JAX_COMPILATION_CACHE_DIR"):
        return env["JAX_COMPILATION_CACHE_DIR"]
    asked = env.get("FABRAX_COMPILE_CACHE", "").strip().lower()
    if asked in ("0", "false", "off", "no"):
        return None
    quiet = not on_cpu or jaxlib_version is None or version_tuple(jaxlib_version) >= CACHE_QUIET
    if not quiet and asked not in ("1", "true", "on", "yes"):
        return None
    return str(cache_root(env) / "jax" / host_digest())


def prepare() -> None:
    """Set the process's XLA flags and compile cache (before jax starts; see the module docstring)."""
    os.environ["XLA_FLAGS"] = xla_flags(
        os.environ.get("XLA_FLAGS", ""), _installed("jaxlib"), computes_on_cpu(), os.environ.get("FABRAX_CPU_DEVICES", "")
    )
    if not os.environ["XLA_FLAGS"]:
        del os.environ["XLA_FLAGS"]
    cache = compile_cache_dir(jaxlib_version=_installed("jaxlib"), on_cpu=computes_on_cpu())
    if cache is None:
        return
    import sys

    if "jax" in sys.modules:  # imported before fabrax: its options were read already
        import jax

        if jax.config.jax_compilation_cache_dir is None:
            jax.config.update("jax_compilation_cache_dir", cache)
    else:
        os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", cache)
