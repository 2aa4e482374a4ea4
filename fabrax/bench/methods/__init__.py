"""The bench's methods, one module each, behind one registry: a method config's `type` names its
module, whose `build(method, run_config, robot)` makes it (a `ValueError` names a bad setting).

A new method is a module with a class following `Method` and a `build`, and a line in `REGISTRY`.
"""

from __future__ import annotations

import importlib

from fabrax.bench.methods.base import Method, Solution, planned, zlib_hash

REGISTRY = {
    "fabric": "fabrax.bench.methods.fabric",
    "gfcs": "fabrax.bench.methods.gfcs",
    "rl_guide": "fabrax.bench.methods.rl_guide",
    "ompl": "fabrax.bench.methods.ompl",
    "vamp": "fabrax.bench.methods.vamp",
}

_CLASSES = {
    "FabricMethod": "fabric",
    "GFCSMethod": "gfcs",
    "RLGuideMethod": "rl_guide",
    "OMPLMethod": "ompl",
    "VAMPMethod": "vamp",
}
__all__ = ["REGISTRY", "Method", "Solution", "make_method", "planned", "zlib_hash", *_CLASSES]


def make_method(cfg: dict, robot) -> Method:
    """The run's method from its config (`cfg["method"]`, with its `type`) and the run's settings."""
    m = dict(cfg["method"])
    kind = m.pop("type")
    if kind not in REGISTRY:
        raise ValueError(f"unknown method type {kind!r} (one of {', '.join(REGISTRY)})")
    return importlib.import_module(REGISTRY[kind]).build(m, cfg, robot)


def __getattr__(name: str):
    if name in _CLASSES:
        return getattr(importlib.import_module(REGISTRY[_CLASSES[name]]), name)
    raise AttributeError(f"module 'fabrax.bench.methods' has no attribute '{name}'")
