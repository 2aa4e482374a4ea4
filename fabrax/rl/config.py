"""Settings of the fabric-guided arm environment (thesis §3.4), validated before anything is traced.

`env_config(mapping)` turns a config mapping (configs/rl/env/*.yaml, or a dict) into an
`EnvConfig`; an unknown key or a value out of range raises a one-line `ValueError` naming it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from fabrax.robot.goal import TOLERANCE
from fabrax.settings import check_keys

BACKENDS = ("kinematic", "mjx")
THESIS_BOUNDS = ((-0.75, -1.0, -0.1), (1.5, 1.0, 1.25))  # thesis eq. 3.15: the BPS grid's corners (m)
GENERATED = ("cuboid_forest", "shelves", "flying_cuboids")


@dataclasses.dataclass(frozen=True)
class ScenesConfig:
    """The training scenes (§3.4.1): MotionBenchMaker train problems and generated scenes."""

    mbm_classes: tuple[str, ...] = ()  # MBM classes whose train split (problems 1-50) is used; needs FABRAX_DATA
    mbm_limit: int = 50  # problems per class (from problem 1)
    generated: tuple[tuple[str, int], ...] = (("cuboid_forest", 4), ("shelves", 4), ("flying_cuboids", 4))
    procedural: tuple[tuple[str, int], ...] = ()  # (class, count) of fabrax.problems.procedural (MBM-like, MPiNets-like) problems
    procedural_seed: int = 10_000  # their generator seed: 10000 is `fabrax bench split=train`'s; the test split (seed 0) is never trained on
    mpinets: int = 0  # MπNets-faithful problems (fabrax.problems.mpinets, all families and types) drawn with procedural_seed
    configs_per_scene: int = 8  # collision-free configurations sampled per scene for the sampled start/goal modes
    margin: float = 0.02  # m: clearance of sampled configurations
    modes: tuple[float, float, float, float] = (0.55, 0.15, 0.15, 0.15)  # Table 3.1: (pre, pre), (pre, sampled), (sampled, pre), (sampled, sampled)
    capacity: tuple[tuple[str, int], ...] = (("cuboids", 48), ("cylinders", 4), ("spheres", 4))
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    backend: str = "kinematic"  # kinematic: the arm follows the fabric exactly | mjx: MuJoCo MJX tracks it (eq. 3.12)
    sim_steps: int = 2  # mjx: physics steps per fabric step (120 Hz physics under the 60 Hz fabric)
    kp: float = 400.0  # mjx: PD gains of eq. 3.12's tracking controller (1/s^2, 1/s)
    kd: float = 40.0
    substeps: int = 30  # fabric steps per policy step (60 Hz fabric, 2 Hz policy)
    fabric_dt: float = 1.0 / 60.0
    episode_s: float = 20.0
    integrator: str = "second_order"  # thesis eqs. 3.13-3.14
    ee_translation: float = 0.15  # m: relative hand translation at |action| = 1
    ee_rotation: float = 0.5  # rad: relative hand rotation (axis-angle) at |action| = 1
    switch_threshold: float = 0.5  # the fabric switch latches once its action reads at least this
    success_distance: float = TOLERANCE.keypoints  # m: mean keypoint distance of a success (Table 3.5)
    sparse_reward: float = 50.0
    intrinsic_weight: float = 0.3
    collision_penalty: float = 10.0
    bps_cells: int = 16
    bps_clip: float = 2.0  # m: longest BPS vector (scenes without an obstacle in reach)
    map_cells: int = 20
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]] = THESIS_BOUNDS  # BPS grid and exploration map
    scenes: ScenesConfig = ScenesConfig()

    @property
    def policy_dt(self) -> float:
        return self.substeps * self.fabric_dt

    @property
    def episode_steps(self) -> int:
        return max(1, int(round(self.episode_s / self.policy_dt)))


def _positive(name: str, value, integer: bool = False):
    ok = isinstance(value, int) and not isinstance(value, bool) if integer else isinstance(value, (int, float)) and not isinstance(value, bool)
    if not ok or value <= 0:
        raise ValueError(f"{name} must be a positive {'integer' if integer else 'number'}, got {value!r}")
    return value


def _counts(value, known, where: str, what: str) -> tuple[tuple[str, int], ...]:
    """A mapping (or pairs) of names in `known` to counts >= 0, checked."""
    counts = dict(value or {})
    bad = set(counts) - set(known)
    if bad:
        raise ValueError(f"unknown {where} {what} {sorted(bad)} ({what}: {', '.join(known)})")
    return tuple((k, _count(f"{where}.{k}", n)) for k, n in counts.items())


def _count(name: str, n):
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        raise ValueError(f"{name} must be a count >= 0, got {n!r}")
    return n


def scenes_config(cfg: dict[str, Any] | None) -> ScenesConfig:
    cfg = dict(cfg or {})
    check_keys(cfg, [f.name for f in dataclasses.fields(ScenesConfig)], "rl env.scenes")
    out = {}
    if "mbm_classes" in cfg:
        out["mbm_classes"] = tuple(cfg["mbm_classes"] or ())
    if "mbm_limit" in cfg:
        out["mbm_limit"] = _positive("env.scenes.mbm_limit", cfg["mbm_limit"], integer=True)
    if "generated" in cfg:
        out["generated"] = _counts(cfg["generated"], GENERATED, "env.scenes.generated", "kinds")
    if "procedural" in cfg:
        from fabrax.problems.procedural import MBM_LIKE, MPINETS_LIKE

        out["procedural"] = _counts(cfg["procedural"], MBM_LIKE + MPINETS_LIKE, "env.scenes.procedural", "classes")
    if "mpinets" in cfg:
        out["mpinets"] = _count("env.scenes.mpinets", cfg["mpinets"])
    if "procedural_seed" in cfg:
        out["procedural_seed"] = int(cfg["procedural_seed"])
        if out["procedural_seed"] == 0:
            raise ValueError("env.scenes.procedural_seed 0 is the benchmark's test split: train on another seed (10000 is the train split)")
    if "configs_per_scene" in cfg:
        out["configs_per_scene"] = _positive("env.scenes.configs_per_scene", cfg["configs_per_scene"], integer=True)
        if out["configs_per_scene"] < 2:
            raise ValueError("env.scenes.configs_per_scene must be at least 2 (a start and a goal)")
    if "margin" in cfg:
        out["margin"] = float(cfg["margin"])
    if "modes" in cfg:
        modes = tuple(float(m) for m in cfg["modes"])
        if len(modes) != 4 or min(modes) < 0 or sum(modes) <= 0:
            raise ValueError(f"env.scenes.modes must be 4 non-negative probabilities (Table 3.1), got {list(modes)}")
        out["modes"] = tuple(m / sum(modes) for m in modes)
    if "capacity" in cfg:
        cap = _counts(cfg["capacity"], ("cuboids", "cylinders", "spheres"), "env.scenes.capacity", "kinds")
        out["capacity"] = tuple({**dict(ScenesConfig.capacity), **dict(cap)}.items())
    if "seed" in cfg:
        out["seed"] = int(cfg["seed"])
    sc = ScenesConfig(**out)
    if not sc.mbm_classes and not sc.mpinets and not any(n for _, n in sc.generated + sc.procedural):
        raise ValueError("env.scenes has no scene: give mbm_classes, mpinets or a generated or procedural count > 0")
    return sc


def env_config(cfg: dict[str, Any] | None = None) -> EnvConfig:
    """An `EnvConfig` from a mapping; every value is checked here, before any jit."""
    cfg = dict(cfg or {})
    check_keys(cfg, [f.name for f in dataclasses.fields(EnvConfig)], "rl env")
    out: dict[str, Any] = {}
    for key in ("backend", "integrator"):
        if key in cfg:
            out[key] = str(cfg[key])
    if out.get("backend", "kinematic") not in BACKENDS:
        raise ValueError(f"env.backend must be one of {BACKENDS}, got '{out['backend']}'")
    if out.get("integrator", "second_order") not in ("euler", "second_order"):
        raise ValueError(f"env.integrator must be 'euler' or 'second_order', got '{out['integrator']}'")
    for key in ("substeps", "bps_cells", "map_cells", "sim_steps"):
        if key in cfg:
            out[key] = _positive(f"env.{key}", cfg[key], integer=True)
    for key in ("fabric_dt", "episode_s", "ee_translation", "ee_rotation", "success_distance", "bps_clip", "kp", "kd"):
        if key in cfg:
            out[key] = float(_positive(f"env.{key}", cfg[key]))
    for key in ("switch_threshold", "sparse_reward", "intrinsic_weight", "collision_penalty"):
        if key in cfg:
            v = cfg[key]
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                raise ValueError(f"env.{key} must be a number, got {v!r}")
            out[key] = float(v)
    if "bounds" in cfg:
        lo, hi = (tuple(float(x) for x in b) for b in cfg["bounds"])
        if len(lo) != 3 or len(hi) != 3 or not all(a < b for a, b in zip(lo, hi)):
            raise ValueError(f"env.bounds must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min < max, got {cfg['bounds']}")
        out["bounds"] = (lo, hi)
    out["scenes"] = scenes_config(cfg.get("scenes"))
    return EnvConfig(**out)
