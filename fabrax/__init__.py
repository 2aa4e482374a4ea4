"""fabrax: geometric fabrics for robot motion generation in JAX."""

import os as _os

# XLA's CPU fusion emitters compile long chains of small ops (kinematics,
# per-sphere terms) exponentially slowly. XLA reads the flag when its backend
# starts (the first computation), so importing fabrax any time before that works.
_flags = _os.environ.get("XLA_FLAGS", "")
if "xla_cpu_use_fusion_emitters" not in _flags:
    _os.environ["XLA_FLAGS"] = (_flags + " --xla_cpu_use_fusion_emitters=false").strip()

__version__ = "0.1.0"
