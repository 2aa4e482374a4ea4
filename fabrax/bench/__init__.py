"""Benchmark harness: the exact checker, metrics and reports.

The checker's names are imported on first use (PEP 562), so that `fabrax bench` can refuse a bad
command line before jax and the checker load."""

import importlib

_EXPORTS = {
    "RESOLUTION": "fabrax.check.checker",
    "CheckResult": "fabrax.check.checker",
    "check_path": "fabrax.check.checker",
    "densify": "fabrax.check.checker",
    "state_clearances": "fabrax.check.clearance",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'fabrax.bench' has no attribute '{name}'")
