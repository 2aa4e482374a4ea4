import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from fabrax import scene as sc

SCENE = {
    "obstacles": [
        {"type": "cuboid", "center": [0.5, 0.1, 0.3], "quat_wxyz": [0.9, 0.1, 0.3, 0.2], "size": [0.3, 0.1, 0.2]},
        {"type": "cylinder", "center": [-0.2, 0.4, 0.5], "quat_wxyz": [0.7, 0.5, 0.1, 0.0], "radius": 0.08, "length": 0.4},
        {"type": "sphere", "center": [0.0, -0.5, 0.6], "radius": 0.12},
    ]
}


def meshes():
    out = []
    for o in SCENE["obstacles"]:
        if o["type"] == "cuboid":
            m = trimesh.creation.box(extents=o["size"])
        elif o["type"] == "cylinder":
            m = trimesh.creation.cylinder(radius=o["radius"], height=o["length"], sections=256)
        else:
            m = trimesh.creation.icosphere(subdivisions=5, radius=o["radius"])
        t = np.eye(4)
        if "quat_wxyz" in o:
            t[:3, :3] = trimesh.transformations.quaternion_matrix(np.asarray(o["quat_wxyz"]) / np.linalg.norm(o["quat_wxyz"]))[:3, :3]
        t[:3, 3] = o["center"]
        m.apply_transform(t)
        out.append(m)
    return out


def test_signed_distance_matches_brute_force():
    scene = sc.from_dict(SCENE, capacity={"cuboids": 3, "spheres": 2})
    rng = np.random.default_rng(0)
    pts = rng.uniform([-0.6, -0.9, -0.1], [1.0, 0.8, 1.0], (400, 3))
    ours = np.asarray(sc.signed_distances(scene, jnp.asarray(pts, jnp.float32)))
    mask = np.asarray(sc.primitive_mask(scene))
    ours = ours[:, mask]
    for k, m in enumerate(meshes()):
        brute = cKDTree(m.sample(300_000, seed=k)).query(pts)[0]
        sign = np.where(m.contains(pts), -1.0, 1.0)
        assert np.allclose(ours[:, k], sign * brute, atol=3e-3), k
    assert np.all(np.asarray(sc.signed_distances(scene, jnp.zeros((2, 3))))[:, ~mask] == sc.FAR)


def test_distance_gradient_and_curvature_against_finite_differences():
    with jax.enable_x64(True):
        scene = jax.tree.map(lambda a: a.astype(jnp.float64) if a.dtype == jnp.float32 else a, sc.from_dict(SCENE))
        rng = np.random.default_rng(1)
        p = jnp.asarray(rng.uniform([-0.6, -0.9, -0.1], [1.0, 0.8, 1.0], (50, 3)))
        pd = jnp.asarray(rng.normal(size=(50, 3)))
        d, n, dd, curv, mask = sc.distance_kinematics(scene, p.T, pd.T)
        f = lambda x: sc.signed_distances(scene, x).T  # noqa: E731  (K, N)
        h = 1e-6
        fd_grad = jnp.stack([(f(p + h * e) - f(p - h * e)) / (2 * h) for e in jnp.eye(3)])
        assert jnp.allclose(d, f(p))
        assert jnp.allclose(n, fd_grad, atol=1e-6)
        assert jnp.allclose(dd, jnp.einsum("ckn,nc->kn", n, pd))
        h = 1e-4
        fd_curv = (f(p + h * pd) - 2 * f(p) + f(p - h * pd)) / h**2
        assert jnp.allclose(curv, fd_curv, atol=1e-3)
        # inside points too (negative distances)
        inside = jnp.asarray([[0.5, 0.12, 0.31], [-0.2, 0.41, 0.52], [0.02, -0.48, 0.6]])
        assert jnp.all(jnp.diag(sc.signed_distances(scene, inside)) < 0)


def test_padding_and_stacking():
    a = sc.from_dict(SCENE)
    b = sc.from_dict({"obstacles": [SCENE["obstacles"][0]] * 4, "points": [[0, 0, 2.0], [0, 0, 3.0]]})
    batch = sc.stack([a, b])
    assert batch.capacity == {"cuboids": 4, "cylinders": 1, "spheres": 1, "points": 2}
    pts = jnp.asarray([[0.5, 0.1, 0.8], [0.0, 0.0, 1.8]])
    d = jax.vmap(sc.distance, in_axes=(0, None))(batch, pts)
    assert np.allclose(d[0], sc.distance(a, pts), atol=1e-6)
    assert np.allclose(d[1], sc.distance(b, pts), atol=1e-6)
    assert np.isclose(d[1, 1], 0.2, atol=1e-6)  # nearest cloud point
    assert sc.to_dict(a)["obstacles"][1]["type"] == "cylinder"
    round_trip = sc.from_dict(sc.to_dict(a))
    assert np.allclose(sc.distance(round_trip, pts), sc.distance(a, pts), atol=1e-6)


@pytest.mark.parametrize(
    "bad, field",
    [
        ({"type": "cuboid", "center": [0, 0, 0], "size": [0.1, -0.2, 0.1]}, r"obstacles\[0\]\.size"),
        ({"type": "sphere", "center": [0, float("nan"), 0], "radius": 0.1}, r"obstacles\[0\]\.center"),
        ({"type": "cylinder", "center": [0, 0, 0], "radius": 0.1}, "length"),
        ({"type": "cone", "center": [0, 0, 0]}, "type"),
    ],
)
def test_bad_scene_raises_named_field(bad, field):
    with pytest.raises(ValueError, match=field):
        sc.from_dict({"obstacles": [bad]})


def test_capacity_overflow_raises():
    with pytest.raises(ValueError, match="capacity"):
        sc.from_dict({"obstacles": SCENE["obstacles"] * 2}, capacity={"cuboids": 1})


@pytest.mark.parametrize("boxes", [1, 11])
def test_argmin_packed_and_nearest_distance(boxes):
    """The nearest primitive and its derivatives equal the min over every pair's; slot counts that are
    not a multiple of `sdf.LANES` (4 cuboid slots with 1 or 11 in use, 1 cylinder, 13 cloud points)
    are padded inside nearest_distance and must not change the answer."""
    rng = np.random.default_rng(4)
    v = jnp.asarray(rng.uniform(-0.5, 5.0, (40, 23)), jnp.float32)
    assert np.array_equal(np.asarray(sc.sdf.argmin_packed(v)), np.asarray(jnp.argmin(v, -1)))
    idx, low = sc.sdf.min_packed(v, axis=0, unroll=True)  # longer than UNROLL_MAX: a plain reduction
    assert np.array_equal(np.asarray(idx), np.asarray(jnp.argmin(v, 0))) and np.allclose(low, v.min(0), atol=1e-4)
    v3 = v.reshape(5, 8, 23)
    for axis in (0, 1, -1):
        assert np.array_equal(np.asarray(sc.sdf.argmin_packed(v3, axis=axis)), np.asarray(jnp.argmin(v3, axis)))
        # the minimum read back from the key, within the packing's resolution; unrolled alike
        for unroll in (False, True):
            idx, low = sc.sdf.min_packed(v3, axis=axis, unroll=unroll)
            assert np.array_equal(np.asarray(idx), np.asarray(jnp.argmin(v3, axis)))
            true = np.asarray(v3.min(axis))
            assert np.allclose(low, true, rtol=0, atol=(true + 2.0) * 2.0**-16)
    with jax.enable_x64(True):  # float64 values: the keys stay int32, the minimum float64
        idx, low = sc.sdf.min_packed(jnp.asarray(v3, jnp.float64), axis=1, unroll=True)
        assert idx.dtype == jnp.int32 and low.dtype == jnp.float64 and low.shape == (5, 23)
        assert np.array_equal(np.asarray(idx), np.asarray(jnp.argmin(v3, 1)))
    quats = rng.normal(size=(boxes - 1, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    extra = [
        {"type": "cuboid", "center": rng.uniform(-0.5, 0.8, 3).tolist(), "size": rng.uniform(0.05, 0.3, 3).tolist(), "quat_wxyz": q.tolist()}
        for q in quats
    ]
    cloud = rng.uniform(-0.5, 1.0, (13, 3)).tolist()
    scene = sc.from_dict({"obstacles": SCENE["obstacles"] + extra, "points": cloud}, capacity={"cuboids": max(4, boxes)})
    pts = jnp.asarray(rng.uniform(-0.6, 1.0, (3, 64)), jnp.float32)
    vel = jnp.asarray(rng.normal(size=(3, 64)), jnp.float32)
    near = sc.sdf.nearest_distance(scene, pts, vel)
    every = sc.distance_kinematics(scene, pts, vel)
    k = jnp.argmin(every.d, 0)
    pick = lambda a: jnp.take_along_axis(a, k[None], 0)[0]  # noqa: E731
    assert len(set(np.asarray(k).tolist())) > 3  # several slots are nearest somewhere
    assert np.allclose(near.d, every.d.min(0), atol=1e-6)
    assert np.array_equal(np.asarray(near.slot), np.asarray(k))
    assert np.allclose(near.n, jnp.stack([pick(every.n[c]) for c in range(3)]), atol=1e-5)
    assert np.allclose(near.rate, pick(every.rate), atol=1e-5) and np.allclose(near.curv, pick(every.curv), atol=1e-4)


@pytest.mark.parametrize("boxes", [1, 11])
def test_nearest_distance_skipping_empty_slots_is_exact(boxes):
    """`skip_empty` (blocks of slots without an obstacle skipped under `lax.cond`) answers exactly as
    the full pass, on a scene padded far past its obstacles (32 cuboid slots, 8 empty sphere slots),
    called alone and under `vmap` over scenes (where the conds become selects)."""
    rng = np.random.default_rng(5)
    extra = [{"type": "cuboid", "center": rng.uniform(-0.5, 0.8, 3).tolist(), "size": rng.uniform(0.05, 0.3, 3).tolist()} for _ in range(boxes - 1)]
    scene = sc.from_dict({"obstacles": SCENE["obstacles"] + extra}, capacity={"cuboids": 32, "cylinders": 16, "spheres": 8})
    pts = jnp.asarray(rng.uniform(-0.6, 1.0, (3, 200)), jnp.float32)
    vel = jnp.asarray(rng.normal(size=(3, 200)), jnp.float32)
    full = jax.jit(lambda s: sc.sdf.nearest_distance(s, pts, vel))
    skip = jax.jit(lambda s: sc.sdf.nearest_distance(s, pts, vel, skip_empty=True))
    for a, b in zip(full(scene), skip(scene)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    two = jax.tree.map(lambda a: jnp.stack([a, a]), scene)
    for a, b in zip(jax.vmap(full)(two), jax.vmap(skip)(two)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_rounded_scene_keeps_its_primitives():
    scene = sc.from_dict(SCENE, capacity={"cuboids": 9})
    r = scene.rounded()
    assert r.capacity == {"cuboids": 16, "cylinders": 8, "spheres": 8, "points": 0}
    pts = np.random.default_rng(0).uniform(-0.6, 1.0, (20, 3))
    assert np.allclose(sc.distance(r, pts), sc.distance(scene, pts))
    assert scene.rounded(at_least=8).capacity == {"cuboids": 16, "cylinders": 8, "spheres": 8, "points": 0}
    one_box = sc.from_dict({"obstacles": SCENE["obstacles"][:1]})
    assert one_box.capacity["cylinders"] == 0
    assert one_box.rounded(at_least=8).capacity == {"cuboids": 8, "cylinders": 8, "spheres": 8, "points": 0}


def test_padding_on_the_host_equals_padding_under_jit():
    scene = sc.from_dict(SCENE)
    host = scene.pad(cuboids=5, cylinders=3, spheres=2)
    traced = jax.jit(lambda s: s.pad(cuboids=5, cylinders=3, spheres=2))(scene)
    assert host.capacity == traced.capacity == {"cuboids": 5, "cylinders": 3, "spheres": 2, "points": 0}
    for a, b in zip(jax.tree.leaves(host), jax.tree.leaves(traced), strict=True):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert np.allclose(np.linalg.norm(np.asarray(host.cuboids.quat), axis=-1), 1.0)  # padded slots: the identity
    assert scene.pad(cuboids=1) is scene  # nothing to grow
