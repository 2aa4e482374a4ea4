"""fabrax: geometric fabrics for robot motion generation in JAX."""

import logging as _logging

from fabrax import _environment

# XLA flags, FABRAX_CPU_DEVICES and the persistent compile cache, before jax starts (fabrax/_environment.py)
_environment.prepare()

# jax logs "Unable to initialize backend 'tpu'" at INFO on every machine without one; hydra apps log
# INFO to the console and the run's log file, where that line only misleads.
_logging.getLogger("jax._src.xla_bridge").setLevel(_logging.WARNING)

__version__ = "0.1.0"
