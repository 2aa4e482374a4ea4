"""Checks of a fabric config's values (thesis §3.3's gains, masses, lengths, tolerances) before a
robot is loaded or anything compiled: numpy only, so that a command line fails on a bad value in the
time it takes to parse it. `fabrax.fabrics.terms` and `fabrax.fabrics.arm` check with the same rules."""

from __future__ import annotations

from typing import Any

import numpy as np

from fabrax.settings import check_keys


def check_value(term: str, key: str, value, scalar: bool = True) -> None:
    """A term parameter is a finite number >= 0 (gains, masses, lengths, weights) or, where the term
    takes a vector (targets, offsets), finite numbers; else a ValueError naming
    `fabric.terms.<term>.<key>`: a negative barrier gain or a NaN otherwise runs a whole solve."""
    where = f"fabric.terms.{term}.{key}"
    if scalar:
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or np.ndim(value):
            raise ValueError(f"{where} must be a number, got {value!r}")
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"{where} must be a finite number >= 0, got {value!r}")
        return
    try:
        arr = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where} must be numbers, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where} must be finite numbers, got {value!r}")


NOT_GAINS = {"type", "frame", "resolution", "arms_minor", "name", "n"}  # term config keys that are not numbers
VECTORS = {"offsets", "target", "target_pos", "target_quat", "point_weights"}  # term parameters that take several numbers


def check_config(cfg: dict[str, Any]) -> None:
    """One-line ValueErrors, naming the key, for a fabric config's values (before a robot is loaded
    or anything compiled): every term parameter a finite number >= 0 (vectors finite), tolerances
    finite and positive, a known energization."""
    known = {"terms", "goal_tolerance", "goal_frame", "energization", "default_posture_weight"}
    check_keys(cfg, known, "fabric config")
    for name, spec in (cfg.get("terms") or {}).items():
        if not isinstance(spec, dict):
            raise ValueError(f"fabric.terms.{name} must be a mapping of the term's parameters, got {spec!r}")
        for key, value in spec.items():
            if key not in NOT_GAINS:
                check_value(name, key, value, scalar=key not in VECTORS)
    for key, value in (cfg.get("goal_tolerance") or {}).items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
            raise ValueError(f"fabric.goal_tolerance.{key} must be a finite number > 0, got {value!r}")
    w = cfg.get("default_posture_weight", 1.0)
    if isinstance(w, bool) or not isinstance(w, (int, float)) or not np.isfinite(w) or w < 0:
        raise ValueError(f"fabric.default_posture_weight must be a finite number >= 0, got {w!r}")
    if cfg.get("energization", "dissipative") not in ("dissipative", "conservative"):
        raise ValueError(f"fabric.energization must be dissipative or conservative, got {cfg.get('energization')!r}")
