"""Collision spheres: automatic fitting from a URDF's collision geometry, or a file.

Fitting works for any URDF: sample each link's collision surfaces, take
interior candidate centres along the inward normals, and cover every sample
with as few candidate spheres as a global overshoot bound allows (see
`fit_spheres`). Fits are cached on disk.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from fabrax.robot.urdf import CollisionGeometry, KinematicTree

CACHE_VERSION = 4  # 4: containment tests made deterministic (`_contains`)


def geometry_mesh(g: CollisionGeometry) -> trimesh.Trimesh:
    """A collision element as a triangle mesh in its link frame."""
    if g.kind == "mesh":
        mesh = trimesh.load(g.mesh_path, force="mesh")
        mesh.apply_scale(np.asarray(g.mesh_scale))
    elif g.kind == "box":
        mesh = trimesh.creation.box(extents=g.size)
    elif g.kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=g.size[0], height=g.size[1], sections=48)
    elif g.kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=g.size[0])
    else:
        raise ValueError(f"unknown collision geometry kind '{g.kind}'")
    mesh.apply_transform(g.origin)
    return mesh


def link_meshes(tree: KinematicTree) -> dict[str, list[trimesh.Trimesh]]:
    """The collision meshes of every link that has collision geometry."""
    per_link: dict[str, list] = {}
    for g in tree.collisions:
        per_link.setdefault(g.link, []).append(geometry_mesh(g))
    return per_link


def sample_surface(meshes: list[trimesh.Trimesh], spacing: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Surface samples about `spacing` apart over a link's meshes, with outward normals."""
    pts, normals = [], []
    for i, mesh in enumerate(meshes):
        count = int(np.clip(mesh.area / spacing**2, 50, 20000))
        p, face = trimesh.sample.sample_surface(mesh, count, seed=seed + i)
        pts.append(np.asarray(p))
        normals.append(np.asarray(mesh.face_normals[face]))
    return np.concatenate(pts), np.concatenate(normals)


def _contains(mesh: trimesh.Trimesh, points: np.ndarray, seed: int) -> np.ndarray:
    """`mesh.contains`, deterministic: trimesh re-casts the rays whose two directions disagree in a
    direction drawn from its shared, entropy-seeded generator, so the same fit could differ between
    processes; that generator is swapped for a seeded one during the call."""
    util = trimesh.util
    if not hasattr(util, "_RANDOM_DEFAULT"):  # another trimesh layout: its own behaviour
        return mesh.contains(points)
    shared = util._RANDOM_DEFAULT
    util._RANDOM_DEFAULT = np.random.default_rng(seed)
    try:
        return mesh.contains(points)
    finally:
        util._RANDOM_DEFAULT = shared


def _candidates(meshes, pts, normals, rng, max_candidates: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Interior points along inward normals and their depth (distance to the nearest surface sample)."""
    depths = np.geomspace(0.002, 0.15, 12)
    cand = (pts[:, None] - normals[:, None] * depths[None, :, None]).reshape(-1, 3)
    inside = np.zeros(len(cand), bool)
    for mesh in meshes:
        inside |= _contains(mesh, cand, seed) if mesh.is_watertight else False
    cand = cand[inside] if inside.any() else pts.copy()
    if len(cand) > max_candidates:
        cand = cand[rng.choice(len(cand), max_candidates, replace=False)]
    depth = cKDTree(pts).query(cand)[0]
    return cand, depth


def _greedy_cover(dist: np.ndarray, radius: np.ndarray, tolerance: float) -> list[int]:
    """Candidates chosen greedily until every sample lies within radius + tolerance of one."""
    cover = dist <= (radius + tolerance)[:, None]
    uncovered = np.ones(dist.shape[1], bool)
    chosen = []
    while uncovered.any():
        gain = cover[:, uncovered].sum(1)
        best = int(gain.argmax())
        if gain[best] == 0:  # cannot happen with radius >= depth, kept as a guard
            raise RuntimeError("sphere cover stalled")
        chosen.append(best)
        uncovered &= ~cover[best]
    return chosen


def fit_spheres(tree: KinematicTree, budget: int, tolerance: float = 0.001, spacing: float = 0.004, seed: int = 0, max_samples: int = 2500) -> dict:
    """Fit at most `budget` spheres over all links with collision geometry.

    Sphere centres are interior points (offsets along inward surface normals);
    a centre at depth rho gets radius rho + delta, so delta is how far any
    sphere may reach beyond the surface. For a given delta each link takes the
    fewest spheres (greedy set cover) that cover all its surface samples; delta
    is the smallest value (bisection) whose total count fits the budget, so every
    link gets the same bound on overshoot. Radii then shrink to the farthest
    sample each sphere is responsible for.
    Returns {link: [{"center": [x, y, z], "radius": r}, ...]} in link frames.
    """
    meshes = link_meshes(tree)
    if not meshes:
        raise ValueError(f"robot '{tree.name}' has no collision geometry to fit spheres to")
    if budget < len(meshes):
        raise ValueError(f"sphere budget {budget} is smaller than the {len(meshes)} links with collision geometry")
    rng = np.random.default_rng(seed)
    data = {}
    for name, ms in meshes.items():
        pts, normals = sample_surface(ms, spacing, seed)
        if len(pts) > max_samples:
            keep = rng.choice(len(pts), max_samples, replace=False)
            pts, normals = pts[keep], normals[keep]
        cand, depth = _candidates(ms, pts, normals, rng, 2 * max_samples, seed)
        dist = np.sqrt(((cand[:, None] - pts[None]) ** 2).sum(-1))
        data[name] = (pts, cand, depth, dist)

    def cover(delta):
        return {n: _greedy_cover(d[3], d[2] + delta, tolerance) for n, d in data.items()}

    lo, hi = 0.0, 0.3
    best = cover(hi)
    for _ in range(16):
        mid = 0.5 * (lo + hi)
        picks = cover(mid)
        if sum(map(len, picks.values())) <= budget:
            hi, best = mid, picks
        else:
            lo = mid
    out = {}
    for name in tree.link_names:
        if name not in best:
            continue
        pts, cand, depth, dist = data[name]
        idx = np.asarray(best[name])
        owner = np.argmin(dist[idx] - (depth[idx] + hi)[:, None], 0)  # sphere each sample sits deepest in
        r = np.zeros(len(idx))
        np.maximum.at(r, owner, dist[idx[owner], np.arange(len(pts))])
        r = np.maximum(r - tolerance, 1e-3)
        out[name] = [{"center": cand[i].tolist(), "radius": float(rad)} for i, rad in zip(idx, r)]
    return out


def _cache_key(tree: KinematicTree, budget: int, tolerance: float, spacing: float, seed: int) -> str:
    h = hashlib.sha256(f"{CACHE_VERSION}|{tree.name}|{budget}|{tolerance}|{spacing}|{seed}|{sorted(tree.held.items())}".encode())
    for g in tree.collisions:
        h.update(f"{g.link}|{g.kind}|{g.size}|{g.origin.round(9).tolist()}|{g.mesh_scale}".encode())
        if g.mesh_path:
            h.update(Path(g.mesh_path).read_bytes())
    return h.hexdigest()[:20]


def fitted_spheres(tree: KinematicTree, budget: int, tolerance: float = 0.001, spacing: float = 0.004, seed: int = 0) -> dict:
    """`fit_spheres`, cached on disk under $FABRAX_CACHE (default ~/.cache/fabrax)."""
    cache = Path(os.environ.get("FABRAX_CACHE", Path.home() / ".cache" / "fabrax"))
    path = cache / f"spheres-{tree.name}-{_cache_key(tree, budget, tolerance, spacing, seed)}.json"
    if path.exists():
        return json.loads(path.read_text())
    spheres = fit_spheres(tree, budget, tolerance, spacing, seed)
    try:
        cache.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")  # parallel test workers fit the same set
        tmp.write_text(json.dumps(spheres))
        tmp.replace(path)
    except OSError:
        pass  # a read-only home only costs a refit next time
    return spheres


def load_sphere_file(path: str | Path, set_name: str | None = None) -> dict:
    """Spheres from JSON: {link: [{center, radius}]}, {"spheres": {...}} or a file of named sets."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"sphere file not found: {path}")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"malformed sphere file {path}: {e}") from e
    if "sets" in data:
        name = set_name or data.get("primary")
        if name not in data["sets"]:
            raise ValueError(f"sphere set '{name}' not in {path} (sets: {', '.join(data['sets'])})")
        data = data["sets"][name]
    if "spheres" in data:
        data = data["spheres"]
    for link, spheres in data.items():
        for s in spheres:
            if len(s.get("center", ())) != 3 or not float(s.get("radius", -1)) > 0:
                raise ValueError(f"malformed sphere on link '{link}' in {path}: {s}")
    return data
