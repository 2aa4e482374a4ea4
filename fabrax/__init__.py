"""fabrax: geometric fabrics for robot motion generation in JAX."""

import logging as _logging
import os as _os

# XLA's CPU fusion emitters compile long chains of small ops (kinematics,
# per-sphere terms) exponentially slowly. XLA reads the flag when its backend
# starts (the first computation), so importing fabrax any time before that works.
_flags = _os.environ.get("XLA_FLAGS", "")
if "xla_cpu_use_fusion_emitters" not in _flags:
    _flags = _os.environ["XLA_FLAGS"] = (_flags + " --xla_cpu_use_fusion_emitters=false").strip()
# FABRAX_CPU_DEVICES=N: N XLA host devices, so that batches shard over N cores (fabrax.sharding).
_cpu_devices = _os.environ.get("FABRAX_CPU_DEVICES", "")
if _cpu_devices and "xla_force_host_platform_device_count" not in _flags:
    if not _cpu_devices.isdigit() or int(_cpu_devices) < 1:
        raise ValueError(f"FABRAX_CPU_DEVICES must be a positive integer, got '{_cpu_devices}'")
    _os.environ["XLA_FLAGS"] = f"{_flags} --xla_force_host_platform_device_count={_cpu_devices}"

# jax logs "Unable to initialize backend 'tpu'" at INFO on every machine without one; hydra apps log
# INFO to the console and the run's log file, where that line only misleads.
_logging.getLogger("jax._src.xla_bridge").setLevel(_logging.WARNING)

__version__ = "0.1.0"
