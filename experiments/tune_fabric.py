"""Tune the arm fabric's gains with CMA-ES (evosax) on MotionBenchMaker *train* problems, generated
MπNets-like problems (train seeds) and full-speed sweeps; never on the MBM test split.

Every candidate gain set is rolled out on three sets, compiled once (the gains are traced arrays):

* mbm: problems 1..--mbm per class of the train split (table_under_pick excluded: a local method
  cannot leave its start under the table), aimed at the goal's hand pose with the joint goal as
  posture; success = pose tolerance reached at rest (every joint below --settle rad/s) without a
  collision, averaged over classes.
* generated: --generated problems per MπNets-like class (seed 10_000 + --seed, the bench's train
  split), pose goals with the default posture; success by the thesis' keypoint criterion and by the
  pose tolerance, at rest.
* sweeps: --sweeps full-speed sweeps (`fabrax.problems.sweeps`): the fraction that penetrates.

score = mbm success + 0.5 (generated keypoints + generated pose) / 2 - 5 collisions (both) - 10 penetrations.
Collisions here are the fabric's own per-step clearance (every 0.01 s step); the reports re-check
with the exact checker. The search runs in log space within the bounds of SPACE, starting from the
config's gains; the run checkpoints every generation and resumes (--resume) only with the same settings.

    python experiments/tune_fabric.py --out bench_out/tune --generations 20 --population 16
    python experiments/tune_fabric.py --out bench_out/tune --resume --generations 30   # continue
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import hashlib
import json
import pickle
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import yaml

import fabrax  # noqa: F401  (sets XLA flags before jax compiles anything)
from fabrax import config
from fabrax.fabrics import build_arm_fabric
from fabrax.problems import batch
from fabrax.problems.mbm import CLASSES, load_mbm
from fabrax.problems.procedural import generate
from fabrax.problems.sweeps import sweeps
from fabrax.robot.kinematics import frame_pose, keypoints
from fabrax.rollout import rollout
from fabrax.scene import COMMON_CAPACITY

# (term, parameter): (low, high); searched in log space. ("posture", "default_weight") is the posture
# weight under a pose goal without a joint configuration (the fabric's default_posture_weight).
SPACE = {
    ("ee", "k_force"): (1.0, 20.0),
    ("ee", "alpha_force"): (3.0, 20.0),
    ("ee", "b_goal"): (1.0, 30.0),
    ("ee", "alpha_damping"): (2.0, 20.0),
    ("ee", "k_geometry"): (0.02, 2.0),
    ("ee", "m_hi"): (0.2, 10.0),
    ("ee", "m_lo"): (0.05, 1.0),
    ("posture", "mass"): (0.1, 5.0),
    ("posture", "k_geometry"): (0.2, 10.0),
    ("posture", "alpha_geometry"): (1.0, 10.0),
    ("posture", "k_force"): (0.02, 3.0),
    ("posture", "alpha_force"): (0.5, 5.0),
    ("posture", "b_goal"): (0.01, 5.0),
    ("posture", "default_weight"): (0.01, 1.0),
    ("obstacles", "k_metric"): (0.1, 5.0),
    ("obstacles", "reach"): (0.05, 0.4),
    ("obstacles", "k_barrier"): (0.02, 1.0),
    ("obstacles", "k_slide"): (0.005, 1.0),
    ("self_collision", "k_metric"): (0.05, 2.0),
    ("self_collision", "k_barrier"): (0.02, 1.0),
    ("joint_limits", "reach"): (0.01, 0.3),
    ("joint_limits", "k_barrier"): (0.005, 0.3),
    ("damping", "b"): (0.05, 5.0),
    ("damping", "k_drag"): (0.05, 10.0),
}
TRAIN_CLASSES = tuple(c for c in CLASSES if c != "table_under_pick")


def _padded_batches(problems, size: int):
    padded = [dataclasses.replace(p, scene=p.scene.pad(**COMMON_CAPACITY)) for p in problems]
    padded += [padded[-1]] * (-len(padded) % size)
    return [batch(padded[s : s + size]) for s in range(0, len(padded), size)]


class Sets:
    """The three problem sets and one compiled rollout each; `score(params, default_weight)`."""

    def __init__(self, fabric_cfg: dict, args):
        self.mbm_robot = config.load_robot("panda_mbm")
        self.gen_robot = config.load_robot("panda")
        default_q = jnp.asarray(config.load("robot", "panda")["default_q"], jnp.float32)
        mbm = [p for p in load_mbm(self.mbm_robot, None, TRAIN_CLASSES, "train", args.mbm) if p.valid]
        gen = generate(self.gen_robot, "mpinets_like", None, args.generated, 10_000 + args.seed)
        sw = sweeps(self.mbm_robot, args.sweeps, args.seed, default_q=np.asarray(default_q))
        self.kinds = {"mbm": [p.kind for p in mbm], "generated": [p.kind for p in gen]}
        self.counts = {"mbm": len(mbm), "generated": len(gen), "sweeps": len(sw)}
        steps, settle, dt = int(round(args.t_max / args.dt)), args.settle, args.dt
        fab_m = build_arm_fabric(self.mbm_robot, fabric_cfg, posture=np.asarray(default_q))
        fab_g = build_arm_fabric(self.gen_robot, fabric_cfg, posture=np.asarray(default_q))
        self.fabric = fab_m

        def settled(fab):
            return lambda p, q, qd: fab.reached(p, q, qd) & (jnp.max(jnp.abs(qd)) <= settle)

        def mbm_one(params, b):
            goal = frame_pose(fab_m.robot, b["goal_q"], fab_m.goal_frame)
            p = fab_m.with_pose_goal(params, goal.translation(), goal.rotation().wxyz, b["goal_q"])
            tr = rollout(fab_m, p, b["scene"], b["start_q"], b["start_qd"], settled(fab_m), dt=dt, steps=steps)
            return tr.reached & (tr.min_clearance >= 0.0), tr.min_clearance < 0.0

        def gen_one(params, w, b):
            p = fab_g.with_pose_goal(params, b["goal_pos"], b["goal_quat"], default_q)
            p = fab_g._set(p, "posture", weight=w)
            tr = rollout(fab_g, p, b["scene"], b["start_q"], b["start_qd"], settled(fab_g), dt=dt, steps=steps)
            q = tr.final_q()
            now = keypoints(fab_g.robot, q)
            import jaxlie

            hand = frame_pose(fab_g.robot, q, fab_g.goal_frame)
            goal = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3(b["goal_quat"]), b["goal_pos"])
            kp = jnp.mean(jnp.linalg.norm(now - jax.vmap((goal @ hand.inverse()).apply)(now), axis=-1))
            at_rest = jnp.max(jnp.abs(tr.qd[tr.length - 1])) <= settle
            clean = tr.min_clearance >= 0.0
            return (kp < 0.08) & clean & at_rest, tr.reached & clean, tr.min_clearance < 0.0

        def sweep_one(params, b):
            p = fab_m.with_joint_goal(params, b["goal_q"])
            tr = rollout(fab_m, p, b["scene"], b["start_q"], b["start_qd"], fab_m.reached, dt=dt, steps=int(round(2.0 / dt)), stop_at_goal=False)
            return tr.min_clearance < 0.0

        self._mbm = [(jax.jit(jax.vmap(mbm_one, in_axes=(None, 0))), b) for b in _padded_batches(mbm, args.batch)]
        self._gen = [(jax.jit(jax.vmap(gen_one, in_axes=(None, None, 0))), b) for b in _padded_batches(gen, args.batch)]
        self._sweep = [(jax.jit(jax.vmap(sweep_one, in_axes=(None, 0))), b) for b in _padded_batches(sw, args.batch)]

    def evaluate(self, params, default_weight: float) -> dict:
        def cat(outs, n):
            return [np.concatenate([np.asarray(o[k]) for o in outs])[:n] for k in range(len(outs[0]))]

        m_ok, m_coll = cat([jax.device_get(fn(params, b)) for fn, b in self._mbm], self.counts["mbm"])
        w = jnp.float32(default_weight)
        g_kp, g_pose, g_coll = cat([jax.device_get(fn(params, w, b)) for fn, b in self._gen], self.counts["generated"])
        (pen,) = cat([(jax.device_get(fn(params, b)),) for fn, b in self._sweep], self.counts["sweeps"])
        by_class = {c: float(np.mean(m_ok[np.asarray(self.kinds["mbm"]) == c])) for c in TRAIN_CLASSES}
        gen_class = {c: float(np.mean(g_kp[np.asarray(self.kinds["generated"]) == c])) for c in sorted(set(self.kinds["generated"]))}
        out = {
            "mbm_success": float(np.mean(list(by_class.values()))),
            "mbm_collision": float(np.mean(m_coll)),
            "mbm_by_class": by_class,
            "generated_keypoints": float(np.mean(g_kp)),
            "generated_pose": float(np.mean(g_pose)),
            "generated_collision": float(np.mean(g_coll)),
            "generated_by_class": gen_class,
            "sweep_penetration": float(np.mean(pen)),
        }
        out["score"] = (
            out["mbm_success"]
            + 0.25 * (out["generated_keypoints"] + out["generated_pose"])
            - 5.0 * (out["mbm_collision"] + out["generated_collision"])
            - 10.0 * out["sweep_penetration"]
        )
        return out


def to_unit(values: dict) -> np.ndarray:
    """Gains -> [0, 1] per axis (log scale within the bounds)."""
    return np.array([(np.log(values[k]) - np.log(lo)) / (np.log(hi) - np.log(lo)) for k, (lo, hi) in SPACE.items()])


def from_unit(z: np.ndarray) -> dict:
    z = np.clip(z, 0.0, 1.0)
    return {k: float(np.exp(np.log(lo) + u * (np.log(hi) - np.log(lo)))) for u, (k, (lo, hi)) in zip(z, SPACE.items())}


def current_values(cfg: dict) -> dict:
    out = {}
    for term, key in SPACE:
        if (term, key) == ("posture", "default_weight"):
            out[(term, key)] = float(cfg.get("default_posture_weight", 1.0))
        else:
            out[(term, key)] = float(cfg["terms"][term][key])
    lo_hi = {k: v for k, v in SPACE.items()}
    return {k: float(np.clip(v, *lo_hi[k])) for k, v in out.items()}


def apply(cfg: dict, values: dict) -> dict:
    cfg = copy.deepcopy(cfg)
    for (term, key), v in values.items():
        if (term, key) == ("posture", "default_weight"):
            cfg["default_posture_weight"] = round(float(v), 4)
        else:
            cfg["terms"][term][key] = round(float(v), 4)
    return cfg


def params_of(fabric, values: dict):
    p = {name: dict(v) for name, v in fabric.init().items()}
    for (term, key), v in values.items():
        if key != "default_weight":
            p[term][key] = jnp.broadcast_to(jnp.asarray(v, jnp.float32), p[term][key].shape)
    return p


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fabric", default="panda", help="configs/fabric/<name>.yaml: the structure and the starting gains")
    ap.add_argument("--mbm", type=int, default=30, help="MBM train problems per class (1..N)")
    ap.add_argument("--generated", type=int, default=25, help="MπNets-like problems per class (train seeds)")
    ap.add_argument("--sweeps", type=int, default=60)
    ap.add_argument("--generations", type=int, default=20)
    ap.add_argument("--population", type=int, default=16)
    ap.add_argument("--std", type=float, default=0.15, help="initial CMA-ES step in the unit box")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dt", type=float, default=0.01)
    ap.add_argument("--t-max", type=float, default=7.0)
    ap.add_argument("--settle", type=float, default=0.05)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--out", default="bench_out/tune")
    ap.add_argument("--resume", action="store_true")
    args = ap.parse_args()

    from evosax.algorithms import CMA_ES

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = config.load("fabric", args.fabric)
    settings = {k: v for k, v in vars(args).items() if k not in ("generations", "out", "resume", "batch")}
    settings["space"] = [list(k) + list(v) for k, v in SPACE.items()]
    settings["fabric_config"] = base
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:16]
    ckpt = out / "checkpoint.pkl"

    t0 = time.perf_counter()
    sets = Sets(base, args)
    print(f"sets: {sets.counts} ({time.perf_counter() - t0:.0f} s)", flush=True)
    start = current_values(base)
    es = CMA_ES(population_size=args.population, solution=jnp.zeros(len(SPACE)))
    es_params = es.default_params.replace(std_init=args.std)
    if args.resume:
        if not ckpt.exists():
            raise SystemExit(f"tune_fabric: --resume but {ckpt} does not exist")
        saved = pickle.loads(ckpt.read_bytes())
        if saved["digest"] != digest:
            raise SystemExit(f"tune_fabric: {ckpt} was made with other settings (run without --resume into a new --out)")
        state, history, gen0 = jax.tree.map(jnp.asarray, saved["state"]), saved["history"], saved["generation"]
        key = jnp.asarray(saved["key"])
        print(f"resuming after generation {gen0}", flush=True)
    else:
        key = jax.random.PRNGKey(args.seed)
        state = es.init(key, jnp.asarray(to_unit(start), jnp.float32), es_params)
        row = {"generation": 0, "candidate": 0, "values": {f"{t}.{k}": v for (t, k), v in start.items()}}
        row.update(sets.evaluate(params_of(sets.fabric, start), start[("posture", "default_weight")]))
        history, gen0 = [row], 0
        scores = f"mbm {row['mbm_success']:.3f} gen kp {row['generated_keypoints']:.3f} pen {row['sweep_penetration']:.3f}"
        print(f"start: score {row['score']:.3f} {scores}", flush=True)
    for g in range(gen0 + 1, args.generations + 1):
        key, k_ask, k_tell = jax.random.split(key, 3)
        pop, state = es.ask(k_ask, state, es_params)
        fitness = []
        for c, z in enumerate(np.asarray(pop)):
            values = from_unit(z)
            row = {"generation": g, "candidate": c, "values": {f"{t}.{k}": v for (t, k), v in values.items()}}
            row.update(sets.evaluate(params_of(sets.fabric, values), values[("posture", "default_weight")]))
            history.append(row)
            fitness.append(-row["score"])
        state, _ = es.tell(k_tell, pop, jnp.asarray(fitness, jnp.float32), state, es_params)
        best = max(history, key=lambda r: r["score"])
        print(
            f"generation {g}: best of generation {-min(fitness):.3f}, best so far {best['score']:.3f} "
            f"(mbm {best['mbm_success']:.3f}, gen kp {best['generated_keypoints']:.3f}, pen {best['sweep_penetration']:.3f}) "
            f"{time.perf_counter() - t0:.0f} s",
            flush=True,
        )
        record = {"digest": digest, "generation": g, "state": jax.device_get(state), "history": history, "key": np.asarray(key)}
        ckpt.write_bytes(pickle.dumps(record))
    best = max(history, key=lambda r: r["score"])
    values = {tuple(k.split(".")): v for k, v in best["values"].items()}
    (out / "best_fabric.yaml").write_text(yaml.safe_dump(apply(base, values), sort_keys=False))
    (out / "results.json").write_text(json.dumps({"settings": settings, "counts": sets.counts, "history": history}, indent=1, default=str))
    lines = ["| rank | generation | score | mbm success | mbm coll | gen keypoints | gen pose | gen coll | sweep pen |", "|" + "---:|" * 9]
    for i, r in enumerate(sorted(history, key=lambda r: -r["score"])[:10]):
        lines.append(
            f"| {i + 1} | {r['generation']} | {r['score']:.3f} | {r['mbm_success']:.3f} | {r['mbm_collision']:.3f} | "
            f"{r['generated_keypoints']:.3f} | {r['generated_pose']:.3f} | {r['generated_collision']:.3f} | {r['sweep_penetration']:.3f} |"
        )
    lines += ["", "Best by class (MBM train, pose at rest): " + ", ".join(f"{c} {v:.2f}" for c, v in best["mbm_by_class"].items())]
    lines += ["Best by class (generated, keypoints): " + ", ".join(f"{c} {v:.2f}" for c, v in best["generated_by_class"].items())]
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"best gains: {out / 'best_fabric.yaml'}")


if __name__ == "__main__":
    main()
