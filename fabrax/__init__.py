"""fabrax: geometric fabrics for robot motion generation in JAX."""

import os as _os
import sys as _sys

# XLA's CPU fusion emitters compile long chains of small ops (kinematics,
# per-sphere terms) exponentially slowly; the flag must be set before jax loads.
if "jax" not in _sys.modules:
    _flags = _os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" not in _flags:
        _os.environ["XLA_FLAGS"] = (_flags + " --xla_cpu_use_fusion_emitters=false").strip()

__version__ = "0.1.0"
