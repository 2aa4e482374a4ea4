"""The motion-skills experiment behind experiments/skills.py (riemannian_motion_skills_paper §4-5).

`run(cfg, out)`: demonstrations -> VAE -> Riemannian and Euclidean geodesics between
demonstration starts and ends -> an obstacle on the demonstrated path reshapes the
metric (eq. 30-32) -> the fabric executes the decoded geodesics with that obstacle in
its scene. Every figure in results.json is measured on this run's data.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from fabrax.check.checker import check_path
from fabrax.fabrics import build_arm_fabric
from fabrax.robot import build_robot
from fabrax.robot.kinematics import frame_path
from fabrax.scene.primitives import empty, from_dict
from fabrax.settings import from_mapping
from fabrax.skills import demos, execute, geodesic, metric, spline, vae
from fabrax.skills.rbf import kmeans


class Demos(NamedTuple):
    x: np.ndarray  # (D, T, 3) end-effector positions
    q: np.ndarray  # (D, T, 4) end-effector quaternions wxyz
    theta: np.ndarray | None  # (D, T, n) joint configurations (joint-space skills)
    group: np.ndarray  # (D,) IK branch of each demonstration (0 for task-space skills)


def load_demos(cfg: dict, robot) -> Demos:
    kind = cfg["demo"]
    if kind == "jc":
        x, q = demos.jc(points=cfg["points"], seed=cfg["seed"])
        return Demos(x, q, None, np.zeros(len(x), int))
    if kind not in ("lasa", "joint"):
        raise ValueError(f"demo: unknown demonstration set '{kind}' (jc, lasa, joint)")
    x, q = demos.lasa(cfg["lasa_shape"], points=cfg["points"])
    if kind == "lasa":
        return Demos(x, q, None, np.zeros(len(x), int))
    seeds = np.asarray(cfg["ik_seeds"], np.float32)
    theta, residual = demos.two_branches(robot, x, q, seeds, cfg["frame"])
    if residual > 2e-3:
        raise RuntimeError(f"joint demonstrations: IK residual {residual:.4f} m; the path leaves the workspace of a branch")
    b = len(seeds)
    return Demos(np.tile(x, (b, 1, 1)), np.tile(q, (b, 1, 1)), theta, np.repeat(np.arange(b), len(x)))


def demo_pairs(d: Demos, n: int, seed: int) -> np.ndarray:
    """(n, 2) demonstration indices (start of a, end of b): each demonstration's own start and end first,
    then random pairs within one IK branch."""
    rng = np.random.default_rng(seed)
    out = [(i, i) for i in range(len(d.group))]
    while len(out) < n:
        a = rng.integers(len(d.group))
        out.append((a, rng.choice(np.flatnonzero(d.group == d.group[a]))))
    return np.asarray(out[: max(n, 1)])


def nearest(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Distance from each point (..., M, k) to its nearest reference point (R, k)."""
    p = np.asarray(points)
    d2 = np.sum(p**2, -1)[..., None] - 2.0 * p @ reference.T + np.sum(reference**2, -1)
    return np.sqrt(np.maximum(np.min(d2, -1), 0.0))


def run(cfg: dict, out: Path) -> dict:
    """The experiment of a composed configs/skills.yaml (`robot` and `fabric` as config mappings,
    as experiments/skills.py composes them); writes results.json and its figures under `out`."""
    for key in ("robot", "fabric"):
        if not isinstance(cfg.get(key), dict):
            raise ValueError(f"skills config: {key} must be a {key} config mapping, got {cfg.get(key)!r}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    robot = build_robot(cfg["robot"])  # the composed robot and fabric configs (experiments/skills.py)
    fabric = build_arm_fabric(robot, cfg["fabric"])
    params = fabric.init()
    t_start = time.perf_counter()
    d = load_demos(cfg, robot)
    vcfg = from_mapping(vae.VAEConfig, {**cfg["vae"], "seed": cfg["seed"]}, "vae")
    t0 = time.perf_counter()
    if d.theta is None:
        model, log = vae.fit_task(d.x.reshape(-1, 3), d.q.reshape(-1, 4), vcfg)
        codes = np.asarray(model.encode(jnp.asarray(d.x, jnp.float32), jnp.asarray(d.q, jnp.float32))[0])
    else:
        model, log = vae.fit_joint(robot, d.theta.reshape(-1, robot.dof), vcfg, tcp=cfg["frame"])
        codes = np.asarray(model.encode(jnp.asarray(d.theta, jnp.float32))[0])
    train_s = time.perf_counter() - t0
    vae.save(out / "skill.msgpack", model, vcfg, {"robot": cfg["robot"], "frame": cfg["frame"], "demo": cfg["demo"]})

    fk = jax.jit(jax.vmap(vae.fk_points(robot, cfg["frame"], 0.1)))
    seed_q = jnp.asarray(cfg["ik_seeds"][0], jnp.float32)
    graphdef, state = nnx.split(model)
    gcfg = from_mapping(geodesic.GeodesicConfig, cfg["geodesic"], "geodesic")
    nodes = kmeans(codes.reshape(-1, codes.shape[-1]), cfg["graph_nodes"], cfg["seed"])[0] if cfg["graph_nodes"] else None
    curve_metric = metric.curve_metric(graphdef)
    solve = geodesic.solver(curve_metric, gcfg, nodes)
    sb = gcfg.basis()
    straight = jax.jit(jax.vmap(lambda a, b: spline.coefficients(sb, a, b, spline.straight(sb, a, b))))
    densify = jax.jit(jax.vmap(spline.dense))

    @jax.jit
    def joint_paths(zs):  # (B, T, d) -> (B, T, n)
        return jax.vmap(lambda z: execute.decode_path(model, z, robot, cfg["frame"], seed_q))(zs)

    def ee_pose(zs, qs=None):  # decoded end-effector positions (B, T, 3) and quaternions (B, T, 4)
        if d.theta is None:
            return np.asarray(jax.vmap(jax.vmap(model.decode_x))(zs)), np.asarray(jax.vmap(jax.vmap(model.decode_q))(zs))
        pos, quat = frame_path(robot, jnp.asarray(qs).reshape(-1, robot.dof), cfg["frame"])
        return np.asarray(pos).reshape(*zs.shape[:2], 3), np.asarray(quat).reshape(*zs.shape[:2], 4)

    # --- geodesics between demonstration starts and ends: Riemannian vs Euclidean (straight latent line)
    pairs = demo_pairs(d, cfg["pairs"], cfg["seed"])
    starts, ends = jnp.asarray(codes[pairs[:, 0], 0]), jnp.asarray(codes[pairs[:, 1], -1])
    geo = solve((state, metric.NONE), starts, ends)
    z_riem, z_eucl = densify(geo.coeffs), densify(straight(starts, ends))
    demo_pts, demo_q = d.x.reshape(-1, 3), d.q.reshape(-1, 4)
    fig = {}
    decoded = {}
    for name, z in (("riemannian", z_riem), ("euclidean", z_eucl)):
        qs = None if d.theta is None else np.asarray(joint_paths(z))  # task-space IK only where the arm is needed
        decoded[name] = ee_pose(z, qs)[0]
        dist = nearest(decoded[name], demo_pts)
        ang = np.rad2deg(2.0 * np.arccos(np.clip(np.abs(ee_pose(z, qs)[1] @ demo_q.T).max(-1), 0.0, 1.0)))  # to the nearest demo orientation
        fig[name] = {
            "mean_m": float(dist.mean()),
            "max_m": float(dist.max()),
            "per_pair_max_m": [round(float(v), 4) for v in dist.max(1)],
            "orientation_mean_deg": float(ang.mean()),
            "orientation_max_deg": float(ang.max()),
        }
        if qs is not None:
            dj = nearest(qs, d.theta.reshape(-1, robot.dof))
            fig[name].update(joint_mean_rad=float(dj.mean()), joint_max_rad=float(dj.max()))
    fig["riemannian"].update(energy=float(jnp.mean(geo.energy)), initial_energy=float(jnp.mean(geo.energy0)), iters=float(jnp.mean(geo.iters)))
    # the same curves' energy at 10x the points by both rules, the larger taken: near 1 where the solver's points
    # resolved the metric (a quadrature misses walls between its points, chords miss what a chord's ends do not show)
    resolved = np.asarray(resolved_energy(curve_metric, (state, metric.NONE), gcfg.segments, 10 * gcfg.points, geo.coeffs))
    ratio = resolved / np.maximum(np.asarray(geo.energy), 1e-12)
    fig["riemannian"].update(
        resolved_energy=float(resolved.mean()), resolved_ratio_median=float(np.median(ratio)), resolved_ratio_max=float(ratio.max())
    )
    e_line = jax.vmap(lambda a, b: geodesic.energy(curve_metric, (state, metric.NONE), sb, a, b, spline.straight(sb, a, b)))
    fig["euclidean"]["energy"] = float(jnp.mean(e_line(starts, ends)))  # the latent line's energy under the learned metric

    # --- an obstacle on the demonstrated path, unseen in training
    oc = cfg["obstacle"]
    idx = int(round(oc["at"] * (d.x.shape[1] - 1)))
    first = np.flatnonzero(d.group == 0)
    medoid = first[np.argmin(np.linalg.norm(d.x[first] - d.x[first].mean(0), axis=-1).mean(-1))]  # the most typical demonstration
    if oc["point"] == -1:
        center = d.x[medoid, idx]
    else:
        if d.theta is None:
            raise ValueError("obstacle.point: arm points need joint-space demonstrations (demo=joint); use -1")
        center = np.asarray(fk(jnp.asarray(d.theta[medoid, idx][None]))[0][0, oc["point"]])
    obs = metric.obstacles([center], [oc["radius"] + oc["influence"]], oc["eta"])
    own = (pairs[:, 0] == pairs[:, 1]) & (d.group[pairs[:, 0]] == 0)  # own start and end, demonstrations the obstacle is on
    geo_obs = solve((state, obs), starts[own], ends[own])
    z_obs = densify(geo_obs.coeffs)
    scene = from_dict({"obstacles": [{"type": "sphere", "center": center.tolist(), "radius": oc["radius"]}]})
    free = empty(spheres=1)  # same shapes as `scene`: one compiled follower serves both
    follow = execute.follower(fabric, params, from_mapping(execute.FollowConfig, cfg["follow"], "follow"))
    c_obs, r_obs = jnp.asarray(center[None], jnp.float32), jnp.asarray([oc["radius"]], jnp.float32)
    obstacle = {
        "center": center.tolist(),
        "point": oc["point"],
        "pairs": int(own.sum()),
        "radius": oc["radius"],
        "metric_length_scale": oc["radius"] + oc["influence"],
        "eta": oc["eta"],
    }
    paths = {}
    clearance = jax.vmap(execute.sphere_clearance, in_axes=(None, 0, None, None))
    for name, z in (("plain", z_riem[own]), ("reshaped", z_obs)):
        qp = np.asarray(joint_paths(z))
        start_clear = float(jnp.min(clearance(robot, jnp.asarray(qp[:, :1]), c_obs, r_obs)))
        if start_clear < 0.0:
            raise ValueError(
                f"obstacle: the sphere at {np.round(center, 3).tolist()} overlaps the arm at a start configuration "
                f"({100 * start_clear:.1f} cm); move it (obstacle.at, obstacle.point) or shrink it (obstacle.radius)"
            )
        pts = np.asarray(fk(jnp.asarray(qp.reshape(-1, robot.dof)))[0]).reshape(qp.shape[0], qp.shape[1], -1, 3)
        ee_path = pts[:, :, -1]  # the FK layer's last point is the TCP
        ee_clear = np.linalg.norm(ee_path - center, axis=-1).min(1) - oc["radius"]
        arm_clear = np.linalg.norm(pts - center, axis=-1).min((1, 2)) - oc["radius"]
        sph_clear = np.asarray(clearance(robot, jnp.asarray(qp), c_obs, r_obs))
        replay = [check_path(robot, scene, p) for p in qp]
        runs = {"obstacle": [], "free": []}
        for sc_name, sc in (("obstacle", scene), ("free", free)):
            tr = follow(jnp.asarray(qp), sc)  # every path in one batched rollout
            for k, e_skill in enumerate(ee_path):
                qs = np.asarray(tr.q[k, : int(tr.length[k])])
                chk = check_path(robot, sc, qs)
                track = nearest(np.asarray(fk(jnp.asarray(qs))[0][:, -1]), e_skill)
                runs[sc_name].append(
                    {"reached": bool(tr.reached[k]), "collision": chk.collision, "clearance": chk.min_clearance, "track": float(track.mean())}
                )
        obstacle[name] = {
            "ee_clearance_mean_m": float(ee_clear.mean()),
            "ee_clearance_min_m": float(ee_clear.min()),
            "arm_points_clearance_mean_m": float(arm_clear.mean()),
            "arm_points_clearance_min_m": float(arm_clear.min()),
            "spheres_clearance_mean_m": float(sph_clear.mean()),
            "replay_collision_rate": float(np.mean([r.collision for r in replay])),
            "fabric_success_rate": float(np.mean([r["reached"] and not r["collision"] for r in runs["obstacle"]])),
            "fabric_collision_rate": float(np.mean([r["collision"] for r in runs["obstacle"]])),
            "fabric_min_clearance_m": float(np.min([r["clearance"] for r in runs["obstacle"]])),
            "fabric_tracking_m": float(np.mean([r["track"] for r in runs["obstacle"]])),
            "free_success_rate": float(np.mean([r["reached"] and not r["collision"] for r in runs["free"]])),
            "free_tracking_m": float(np.mean([r["track"] for r in runs["free"]])),
        }
        paths[name] = qp
    paths_ee = ee_path  # the reshaped geodesics' end-effector paths, from the FK of their joint paths

    timing = time_geodesics(solve, state, obs, codes, cfg["timing"], cfg["seed"])
    result = {
        "demo": cfg["demo"] if cfg["demo"] != "lasa" else f"lasa:{cfg['lasa_shape']}",
        "space": "task" if d.theta is None else "joint",
        "latent": vcfg.latent,
        "demonstrations": int(len(d.x)),
        "points": int(d.x.shape[1]),
        "train_s": round(train_s, 2),
        "elbo_final": float(np.mean(log["stage2"][-50:])),
        "pairs": int(len(pairs)),
        "distance_to_demos": fig,
        "obstacle": obstacle,
        "timing": timing,
        "config": cfg,
        "wall_s": round(time.perf_counter() - t_start, 1),
        "versions": {"python": platform.python_version(), "jax": jax.__version__},
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
    }
    (out / "results.json").write_text(json.dumps(result, indent=1))
    (out / "results.md").write_text(table([result]))
    np.savez(out / "paths.npz", codes=codes, z_riemannian=np.asarray(z_riem), z_euclidean=np.asarray(z_eucl), z_obstacle=np.asarray(z_obs), **paths)
    if cfg["figures"] and vcfg.latent == 2:
        from fabrax.skills.plots import latent_maps, task_paths

        latent_maps(model, codes, {"Riemannian": z_riem, "Euclidean": z_eucl, "with obstacle": z_obs}, obs, out / "latent.png")
        curves = {"Riemannian": decoded["riemannian"], "Euclidean": decoded["euclidean"], "with obstacle": paths_ee}
        task_paths(d.x, curves, obstacle, out / "paths.png")
    print(table([result]))
    print(f"results: {out / 'results.json'}")
    return result


def resolved_energy(curve_metric, args, segments: int, points: int, coeffs):
    """Energies of the splines coeffs (B, 4S, d) at `points` by the chord and the Gauss rules, the larger of the two:
    each rule can under-read a feature between its points, so the larger is the better estimate of the true energy."""
    rules = [spline.basis(segments, points, rule) for rule in spline.RULES]
    return jax.jit(jax.vmap(lambda c: jnp.max(jnp.stack([geodesic.curve_energy(curve_metric, args, sb, c) for sb in rules]))))(coeffs)


def time_geodesics(solve, state, obs, codes: np.ndarray, tcfg: dict, seed: int) -> dict:
    """Wall time of one geodesic and of a batch (compilation excluded; median of repeats), without and
    with the obstacle metric; endpoints are random pairs of demonstration codes."""
    rng = np.random.default_rng(seed)
    flat = codes.reshape(-1, codes.shape[-1])
    out = {}
    for label, b, reps in (("single", 1, tcfg["repeats"]), ("batch", tcfg["batch"], max(3, tcfg["repeats"] // 4))):
        a, z = (jnp.asarray(flat[rng.integers(len(flat), size=b)]) for _ in range(2))
        for name, args in (("", (state, metric.NONE)), ("_obstacle", (state, obs))):
            jax.block_until_ready(solve(args, a, z))
            times, iters = [], []
            for _ in range(reps):
                t = time.perf_counter()
                g = jax.block_until_ready(solve(args, a, z))
                times.append(time.perf_counter() - t)
                iters.append(float(jnp.max(g.iters)))
            out[f"{label}{name}_ms"] = round(1e3 * float(np.median(times)), 2)
            out[f"{label}{name}_iters"] = float(np.median(iters))
    out["batch"] = tcfg["batch"]
    return out


def table(results: list[dict]) -> str:
    """Markdown: one row per run."""
    head = (
        "| demo | space | latent | obstacle on | dist. to demos Riem. mean / max (cm) | Eucl. mean / max (cm) | EE clearance plain / reshaped (cm) "
        "| arm-point clearance plain / reshaped (cm) | replay collisions plain / reshaped | fabric success plain / reshaped "
        "| fabric collisions plain / reshaped | geodesic ms (1 / batch) | energy at 10x points / solved, median / max |\n|" + "---|" * 13 + "\n"
    )
    rows = []
    for r in results:
        g, o, t = r["distance_to_demos"], r["obstacle"], r["timing"]
        p, s = o["plain"], o["reshaped"]
        rows.append(
            f"| {r['demo']} | {r['space']} | {r['latent']} | {'end effector' if o.get('point', -1) == -1 else 'FK point ' + str(o['point'])} "
            f"| {100 * g['riemannian']['mean_m']:.1f} / {100 * g['riemannian']['max_m']:.1f} "
            f"| {100 * g['euclidean']['mean_m']:.1f} / {100 * g['euclidean']['max_m']:.1f} "
            f"| {100 * p['ee_clearance_min_m']:.1f} / {100 * s['ee_clearance_min_m']:.1f} "
            f"| {100 * p['arm_points_clearance_min_m']:.1f} / {100 * s['arm_points_clearance_min_m']:.1f} "
            f"| {p['replay_collision_rate']:.0%} / {s['replay_collision_rate']:.0%} "
            f"| {p['fabric_success_rate']:.0%} / {s['fabric_success_rate']:.0%} "
            f"| {p['fabric_collision_rate']:.0%} / {s['fabric_collision_rate']:.0%} "
            f"| {t['single_ms']} / {t['batch_ms']} ({t['batch']}) "
            f"| {g['riemannian'].get('resolved_ratio_median', float('nan')):.3g} / {g['riemannian'].get('resolved_ratio_max', float('nan')):.3g} |"
        )
    return head + "\n".join(rows) + "\n"
