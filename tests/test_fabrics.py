"""The fabric maths, tested as maths (thesis §2.1, §3.3)."""

import dataclasses

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from fabrax import config
from fabrax import scene as sc
from fabrax.fabrics import energies as E
from fabrax.fabrics import energize, eom, pullback, unforced
from fabrax.fabrics.lagrangian import eom_elementwise, hd2_geometry
from fabrax.fabrics.spec import Spec
from fabrax.fabrics.terms import TermInputs
from fabrax.robot import point_kinematics
from fabrax.rollout import integrate

READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
GOAL = [1.0, 0.2, 0.3, -1.5, 0.2, 1.8, 0.5]
BAR = {"obstacles": [{"type": "cuboid", "center": [0.45, 0.0, 0.45], "size": [0.1, 0.4, 0.1]}]}
V0 = [0.6, 0.4, -0.3, 0.5, 0.2, -0.4, 0.3]


@pytest.fixture(scope="module")
def fabric(panda):
    return config.load_fabric(panda)


def f64(tree):
    return jax.tree.map(lambda a: jnp.asarray(a, jnp.float64) if jnp.issubdtype(jnp.asarray(a).dtype, jnp.floating) else a, tree)


def geometry_params(fab, params, sigma=None):
    """Both attractors' geometry on, every forcing and damping off."""
    p = fab.with_pose_goal(params, jnp.asarray([0.5, 0.2, 0.4]), jnp.asarray([0.0, 1.0, 0.0, 0.0]))
    p = fab._set(p, "goal", target=jnp.asarray(GOAL), weight=1.0)
    p = unforced(p, fab)
    if sigma is not None:
        for t in ("obstacles", "self_collision", "joint_limits"):
            p = fab._set(p, t, sigma=sigma)
    return f64(p)


def integrate_scan(fab, p, scene, q0, qd0, dt, steps, integrator="rk4"):
    def body(c, _):
        q, qd = c
        qn, qdn, _, clearance = integrate(fab, p, scene, q, qd, dt, integrator, limits=False)
        return (qn, qdn), (qn, qdn, fab.evaluate(p, scene, qn, qdn).energy, clearance)

    return jax.jit(lambda q, qd: jax.lax.scan(body, (q, qd), None, length=steps)[1])(q0, qd0)


def test_energy_conservation_unforced(fabric):
    """An unforced, undamped fabric energized by eq. 2.26 conserves its energy H_e (eq. 2.29), here next to an obstacle."""
    fab, params = fabric
    fab = dataclasses.replace(fab, energization="conservative")
    with jax.enable_x64(True):
        p = geometry_params(fab, params)
        scene = f64(sc.from_dict(BAR))
        q0, qd0 = jnp.asarray(READY, jnp.float64), jnp.asarray(V0, jnp.float64)
        _, _, energy, clearance = integrate_scan(fab, p, scene, q0, qd0, 1e-3, 1000)
        e0 = fab.evaluate(p, scene, q0, qd0).energy
        assert float(clearance.min()) < 0.1, "the repulsion terms should be active in this check"
        assert float(jnp.max(jnp.abs(energy - e0)) / e0) <= 1e-3


def test_dissipative_energization_never_adds_energy(fabric):
    """max(alpha, 0): the unforced, undamped fabric's H_e never increases, and it does fall where the
    geometry brakes (a fast approach toward the bar), where eq. 2.26 would give the energy back."""
    fab, params = fabric
    assert fab.energization == "dissipative"  # the configured default
    with jax.enable_x64(True):
        p = geometry_params(fab, params)
        scene = f64(sc.from_dict(BAR))
        q0, qd0 = jnp.asarray(READY, jnp.float64), 3.0 * jnp.asarray(V0, jnp.float64)
        _, _, energy, _ = integrate_scan(fab, p, scene, q0, qd0, 1e-3, 1000)
        energy = np.concatenate([[float(fab.evaluate(p, scene, q0, qd0).energy)], np.asarray(energy)])
        # rises only by integration error where a velocity-gated barrier switches within a step
        assert np.sum(np.clip(np.diff(energy), 0.0, None)) <= 1e-4 * energy[0]
        assert energy[-1] < 0.99 * energy[0]
        cons = dataclasses.replace(fab, energization="conservative")
        e_cons = np.asarray(integrate_scan(cons, p, scene, q0, qd0, 1e-3, 1000)[2])
        assert abs(e_cons[-1] - energy[0]) < 1e-3 * energy[0]


@pytest.mark.parametrize("energization", ["dissipative", "conservative"])
def test_path_consistency(fabric, energization):
    """Same start, same velocity direction, two speeds: the same path (geometry generator, §2.1.6);
    max(alpha, 0) is HD1 in qd like alpha, so the dissipative fabric keeps the paths too."""
    fab, params = fabric
    fab = dataclasses.replace(fab, energization=energization)
    with jax.enable_x64(True):
        p = geometry_params(fab, params, sigma=1e-6)  # the velocity gate is HD2 outside |xd| < sigma
        scene = f64(sc.from_dict(BAR))
        q0, v = jnp.asarray(READY, jnp.float64), jnp.asarray(V0, jnp.float64)
        slow = np.asarray(integrate_scan(fab, p, scene, q0, v, 1e-3, 1000)[0])
        fast = np.asarray(integrate_scan(fab, p, scene, q0, 2.0 * v, 5e-4, 1000)[0])

    def resample(path):
        path = np.concatenate([np.asarray(READY)[None], path])
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        grid = np.linspace(0.0, 1.0, 200)
        return np.stack([np.interp(grid, s, path[:, j]) for j in range(path.shape[1])], 1), s[-1]

    a, la = resample(slow)
    b, lb = resample(fast)
    assert abs(la - lb) < 1e-4 and la > 0.5
    # RK4 loses order where the velocity gate and max(alpha, 0) switch: 6.5e-5 measured on a 0.5+ rad path
    assert np.abs(a - b).max() < 2e-4


def test_pullback_commutes_with_energization(panda):
    """pull[energize_Le (I, h2)] = energize_{pull Le}[pull (M_e, M_e h2)]  (eq. 2.52)."""
    with jax.enable_x64(True):
        rng = np.random.default_rng(0)
        q, qd = jnp.asarray(rng.uniform(panda.lower, panda.upper)), jnp.asarray(rng.normal(size=7))
        frame, local = jnp.asarray([7]), jnp.asarray([[0.0, 0.05, 0.2]])
        kin = point_kinematics(panda, q, qd, frame, local)
        x, xd, jac, jdqd = kin.x[:, 0], kin.xd[:, 0], kin.jac[:, :, 0], kin.jdqd[:, 0]
        target = jnp.asarray([0.3, 0.2, 0.5])
        energy = lambda x_, xd_: E.attractor_energy(x_ - target, xd_, 3.0, 0.5, 4.0)  # noqa: E731
        h2 = hd2_geometry(lambda x_: E.attractor_potential(x_ - target, 2.0, 5.0))(x, xd)
        M, fe, _ = eom(energy, x, xd)
        # energize in X, then pull back
        lhs = pullback(energize(M, M @ h2, fe, xd), jac, jdqd)
        # pull back geometry and energy, then energize in Q
        geom = pullback(Spec(M, M @ h2), jac, jdqd)
        fe_q = pullback(Spec(M, fe), jac, jdqd).f
        rhs = energize(geom.M, geom.f, fe_q, qd)
        assert jnp.allclose(lhs.M, rhs.M, atol=1e-10)
        assert jnp.allclose(lhs.f, rhs.f, atol=1e-9)
        # and the pulled-back energy's EOM is the pullback of the EOM (eq. 2.51)
        pulled = lambda q_, qd_: energy(*(lambda k: (k.x[:, 0], k.xd[:, 0]))(point_kinematics(panda, q_, qd_, frame, local)))  # noqa: E731
        Mq, fq, _ = eom(pulled, q, qd)
        assert jnp.allclose(Mq, lhs.M, atol=1e-9)
        assert jnp.allclose(fq, fe_q, atol=1e-8)


def test_metrics_symmetric_positive_definite(fabric):
    fab, params = fabric
    scene = sc.from_dict(BAR)
    rng = np.random.default_rng(1)
    lo, hi = np.asarray(fab.robot.lower), np.asarray(fab.robot.upper)
    qs = jnp.asarray(rng.uniform(lo, hi, (64, 7)), jnp.float32)
    qds = jnp.asarray(rng.normal(size=(64, 7)), jnp.float32)
    metric = jax.jit(jax.vmap(lambda q, qd: fab.evaluate(params, scene, q, qd).metric))(qs, qds)
    assert jnp.allclose(metric, jnp.swapaxes(metric, 1, 2), atol=1e-5)
    assert float(jnp.linalg.eigvalsh(metric).min()) > 0.0
    # per-distance metrics of the gated barrier energy are >= 0 for every rate
    x = jnp.linspace(-0.01, 0.4, 50)[:, None] + jnp.zeros((1, 50))
    xd = jnp.zeros((50, 1)) + jnp.linspace(-3, 3, 50)[None]
    m, _, _ = eom_elementwise(lambda a, b: E.gated_barrier_energy(a, b, 0.5, 0.02, 0.25, 2e-3), x, xd)
    assert float(m.min()) >= 0.0


@pytest.mark.parametrize(
    "energy",
    [
        lambda x, xd: E.attractor_energy(x - jnp.asarray([0.1, -0.2, 0.3]), xd, 2.0, 0.2, 10.0),
        lambda x, xd: jnp.sum(E.gated_barrier_energy(x, xd, 0.5, 0.02, 0.25, 2e-3)),
    ],
)
def test_autodiff_forces_against_finite_differences(energy):
    """f = (d/dx dL/dxd) xd - dL/dx and M = d2L/dxd2 against central differences."""
    with jax.enable_x64(True):
        rng = np.random.default_rng(2)
        x, xd = jnp.asarray(rng.uniform(0.05, 0.2, 3)), jnp.asarray(rng.normal(size=3) * 0.3)
        M, f, H = eom(energy, x, xd)
        h = 1e-6
        grad_xd = jax.grad(energy, 1)
        fd_M = jnp.stack([(grad_xd(x, xd + h * e) - grad_xd(x, xd - h * e)) / (2 * h) for e in jnp.eye(3)], 1)
        fd_mixed = jnp.stack([(grad_xd(x + h * e, xd) - grad_xd(x - h * e, xd)) / (2 * h) for e in jnp.eye(3)], 1)
        fd_dx = jnp.asarray([(energy(x + h * e, xd) - energy(x - h * e, xd)) / (2 * h) for e in jnp.eye(3)])
        assert jnp.allclose(M, fd_M, atol=1e-6)
        assert jnp.allclose(f, fd_mixed @ xd - fd_dx, atol=1e-6)
        assert jnp.allclose(H, grad_xd(x, xd) @ xd - energy(x, xd))
        # the elementwise form used for distance terms gives the same numbers
        if energy.__code__.co_names.count("gated_barrier_energy"):
            me, fe_, he = eom_elementwise(lambda a, b: E.gated_barrier_energy(a, b, 0.5, 0.02, 0.25, 2e-3), x, xd)
            assert jnp.allclose(jnp.diag(M), me) and jnp.allclose(f, fe_) and jnp.allclose(H, he.sum())


def test_no_nan_at_singular_states(fabric):
    """Zero velocity, exactly at the goal, at the joint limits, 1 mm from an obstacle, inside it."""
    fab, params = fabric
    robot = fab.robot
    goal = jnp.asarray(GOAL)
    p = fab.with_joint_goal(params, goal)
    pose = fab.with_pose_goal(params, jnp.asarray([0.4, 0.1, 0.5]), jnp.asarray([0.0, 1.0, 0.0, 0.0]))
    # an obstacle whose face is 1 mm from the surface of one collision sphere at READY
    x = point_kinematics(robot, jnp.asarray(READY), jnp.zeros(7), robot.collision.frame, robot.collision.local).x
    c, r = x[:, 30], robot.collision.radius[30]
    near = sc.from_dict(
        {"obstacles": [{"type": "cuboid", "center": [float(c[0]) + float(r) + 0.001 + 0.05, float(c[1]), float(c[2])], "size": [0.1, 0.1, 0.1]}]}
    )
    inside = sc.from_dict({"obstacles": [{"type": "sphere", "center": [float(v) for v in c], "radius": 0.05}]})
    free = sc.empty(cuboids=1)
    cases = [
        (p, free, READY, np.zeros(7)),
        (p, free, GOAL, np.zeros(7)),
        (pose, free, READY, np.zeros(7)),
        (p, free, np.asarray(robot.lower), np.zeros(7)),
        (p, free, np.asarray(robot.upper), -0.5 * np.ones(7)),
        (p, near, READY, np.zeros(7)),
        (p, near, READY, np.asarray(V0)),
        (p, inside, READY, np.asarray(V0)),
    ]
    acc = jax.jit(lambda pp, s, q, qd: integrate(fab, pp, s, q, qd, 0.01)[2])
    for pp, s, q, qd in cases:
        out = acc(pp, s, jnp.asarray(q, jnp.float32), jnp.asarray(qd, jnp.float32))
        assert bool(jnp.all(jnp.isfinite(out))), (q, qd)
    ev = jax.jit(fab.evaluate)(p, free, goal, jnp.zeros(7))
    assert bool(jnp.all(jnp.isfinite(ev.spec.f))) and float(jnp.abs(ev.alpha)) < 1e-3


def test_resolutions_agree_where_they_coincide(fabric, panda):
    """With one obstacle the scene distance is that obstacle's; link self-collision is the closest pair of each link pair."""
    from fabrax.fabrics.terms import TermInputs, obstacle_repulsion, self_collision

    fab, params = fabric
    scene = sc.from_dict(BAR)
    q, qd = jnp.asarray(READY), jnp.asarray(V0, jnp.float32)
    kin = point_kinematics(panda, q, qd, panda.collision.frame, panda.collision.local)
    inputs = TermInputs(q, qd, kin, scene, panda)
    a = obstacle_repulsion(resolution="scene")
    b = obstacle_repulsion(resolution="primitive")
    ca, cb = a.apply(a.init(), inputs), b.apply(b.init(), inputs)
    assert float(ca.clearance) < 0.25  # active
    for f in ("M", "f_geom", "f_energy", "f_force"):
        assert jnp.allclose(getattr(ca, f), getattr(cb, f), rtol=1e-4, atol=1e-5), f
    # link resolution = the sphere resolution over each link pair's closest sphere pair
    x = np.asarray(kin.x)
    i, j = np.asarray(panda.collision.pair_i), np.asarray(panda.collision.pair_j)
    r = np.asarray(panda.collision.radius)
    gap = np.linalg.norm(x[:, i] - x[:, j], axis=0) - r[i] - r[j]
    link = np.asarray(panda.collision.link)
    key = link[i] * 100 + link[j]
    closest = np.asarray([np.nonzero(key == k)[0][np.argmin(gap[key == k])] for k in np.unique(key)])
    reduced = panda.replace(collision=panda.collision.replace(pair_i=jnp.asarray(i[closest]), pair_j=jnp.asarray(j[closest])))
    s1, s2 = self_collision(resolution="link"), self_collision(resolution="sphere")
    c1 = s1.apply(s1.init(), inputs)
    c2 = s2.apply(s2.init(), TermInputs(q, qd, kin, scene, reduced))
    assert float(c1.clearance) < 0.15  # active
    for f in ("M", "f_geom", "f_energy", "f_force"):
        assert jnp.allclose(getattr(c1, f), getattr(c2, f), rtol=1e-4, atol=1e-5), f
    with pytest.raises(ValueError, match="resolution"):
        obstacle_repulsion(resolution="link")


@pytest.mark.parametrize("resolution", ["scene", "primitive"])
def test_sphere_padding_changes_nothing(fabric, panda, monkeypatch, resolution):
    """The spheres' point set padded to a multiple of SPHERE_LANES (60 -> 64 here, with copies of
    sphere 0) gives the fabric of the unpadded set: the padding is masked out of the obstacle term,
    and self-collision never indexes it. The spheres are rotated so that sphere 0 is on the hand,
    near the obstacle (a base sphere would contribute nothing even unmasked)."""
    from fabrax.fabrics import terms as T

    fab, params = fabric
    n = panda.n_spheres
    assert n % T.SPHERE_LANES  # the padding is exercised
    roll = lambda a: jnp.roll(a, 1, axis=0)  # noqa: E731
    c = panda.collision
    robot = panda.replace(
        collision=c.replace(
            frame=roll(c.frame),
            local=roll(c.local),
            radius=roll(c.radius),
            link=roll(c.link),
            pair_i=(c.pair_i + 1) % n,
            pair_j=(c.pair_j + 1) % n,
        )
    )
    terms = tuple(T.obstacle_repulsion(resolution=resolution) if t.name == "obstacles" else t for t in fab.terms)
    fab = dataclasses.replace(fab, robot=robot, terms=terms)
    with jax.enable_x64(True):
        p = f64(fab.with_joint_goal(params, jnp.asarray(GOAL)))
        scene, q, qd = f64((sc.from_dict(BAR), jnp.asarray(READY), jnp.asarray(V0)))
        padded = fab.evaluate(p, scene, q, qd)
        monkeypatch.setattr(T.base, "SPHERE_LANES", 1)
        plain = fab.evaluate(p, scene, q, qd)
    assert T.base._spheres(robot)[1].shape[0] == n
    assert float(plain.terms.clearance) < 0.25  # the obstacle term is active
    for a, b in ((padded.spec.M, plain.spec.M), (padded.spec.f, plain.spec.f), (padded.terms.clearance, plain.terms.clearance)):
        assert np.allclose(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("resolution,arms_minor", [("link", None), ("sphere", None), ("link", False)])
def test_self_collision_batched_equals_per_arm(panda, resolution, arms_minor):
    """Under `jax.vmap` the self-collision term runs with the arms as the minor axis (its own batching
    rule; `arms_minor=None` picks it on the CPU, False keeps vmap's layout); the contributions equal
    the term applied arm by arm, with shared and with per-arm parameters, and with a vmap of a vmap;
    so do its gradients. A bad `arms_minor` is refused by name."""
    from fabrax.fabrics.terms import self_collision

    with pytest.raises(ValueError, match="arms_minor must be true, false or null"):
        self_collision(arms_minor="yes")
    term = self_collision(resolution=resolution, reach=0.5, arms_minor=arms_minor)  # long range: most pairs active
    rng = np.random.default_rng(2)
    qs = jnp.asarray(rng.uniform(panda.lower, panda.upper, (6, 7)), jnp.float32)
    qds = jnp.asarray(rng.normal(size=(6, 7)), jnp.float32)

    def apply(p, q, qd):
        kin = point_kinematics(panda, q, qd, panda.collision.frame, panda.collision.local)
        return term.apply(p, TermInputs(q, qd, kin, None, panda))

    p = term.init()
    ps = jax.tree.map(lambda a: a * jnp.linspace(0.5, 1.5, 6, dtype=a.dtype), p)
    one = [jax.jit(apply)(jax.tree.map(lambda a: a[k], ps), qs[k], qds[k]) for k in range(6)]
    shared = [jax.jit(apply)(p, qs[k], qds[k]) for k in range(6)]
    nested = jax.jit(jax.vmap(jax.vmap(apply, in_axes=(None, 0, 0)), in_axes=(None, 0, 0)))(p, qs.reshape(2, 3, 7), qds.reshape(2, 3, 7))
    for got, want in (
        (jax.jit(jax.vmap(apply))(ps, qs, qds), one),
        (jax.jit(jax.vmap(apply, in_axes=(None, 0, 0)))(p, qs, qds), shared),
        (jax.tree.map(lambda a: a.reshape((6,) + a.shape[2:]), nested), shared),
    ):
        assert float(jnp.min(got.clearance)) < 0.5  # active
        for f in ("M", "f_geom", "f_energy", "f_force", "energy", "potential", "clearance"):
            w = jnp.stack([getattr(c, f) for c in want])
            assert jnp.allclose(getattr(got, f), w, rtol=1e-5, atol=1e-5 * float(jnp.abs(w).max())), f
    if resolution == "sphere":
        return
    # derivatives (the per-arm code's): reverse mode under vmap and of a vmap
    energy = lambda q, qd: apply(p, q, qd).energy  # noqa: E731
    grad = jax.jit(jax.grad(energy))
    want = jnp.stack([grad(qs[k], qds[k]) for k in range(6)])
    for got in (jax.jit(jax.vmap(jax.grad(energy)))(qs, qds), jax.jit(jax.grad(lambda q: jax.vmap(energy)(q, qds).sum()))(qs)):
        assert jnp.allclose(got, want, rtol=1e-5, atol=1e-5 * float(jnp.abs(want).max()))


def test_ee_attractor_is_the_sum_of_its_points_pullbacks(fabric, panda):
    """The end-effector attractor's contribution equals the sum over its points of each point's
    spec pulled back by `spec.pullback` (eq. 2.6) and J^T of its forcing gradient and damping,
    with unequal point weights."""
    fab, params = fabric
    term = fab.term("ee")
    p = fab.with_pose_goal(params, jnp.asarray([0.45, 0.15, 0.5]), jnp.asarray([0.0, 1.0, 0.0, 0.0]))["ee"]
    p = {**p, "point_weights": jnp.asarray([1.0, 0.5, 0.2])}
    _, frame, local = term.points(panda)
    q, qd = jnp.asarray(READY), jnp.asarray(V0, jnp.float32)
    kin = point_kinematics(panda, q, qd, frame, local)
    got = term.apply(p, TermInputs(q, qd, kin, None, panda))
    offsets = (local - panda.frame_offset_t[panda.frame_index("panda_hand")]) @ panda.frame_offset_r[panda.frame_index("panda_hand")]
    quat = p["target_quat"] / jnp.linalg.norm(p["target_quat"])
    target = jaxlie.SO3(quat).apply(offsets) + p["target_pos"]
    w = p["weight"] * p["point_weights"]
    want = {k: 0.0 for k in ("M", "f_geom", "f_energy", "f_force", "damping")}
    for k in range(3):
        J, jdqd, r, rd = kin.jac[:, :, k], kin.jdqd[:, k], kin.x[:, k] - target[k], kin.xd[:, k]
        Mk, fe, _ = eom(lambda r_, rd_: E.attractor_energy(r_, rd_, p["m_hi"], p["m_lo"], p["alpha_mass"]), r, rd)
        h2 = hd2_geometry(lambda r_: E.attractor_potential(r_, p["k_geometry"], p["alpha_geometry"]))(r, rd)
        dpsi = jax.grad(E.attractor_potential)(r, p["k_force"], p["alpha_force"])
        b = p["b_goal"] * (1.0 - jnp.tanh(p["alpha_damping"] * E.safe_norm(r)))
        geom, en = pullback(Spec(Mk, Mk @ h2), J, jdqd), pullback(Spec(Mk, fe), J, jdqd)
        want["M"] += geom.M
        want["f_geom"] += w[k] * geom.f
        want["f_energy"] += en.f
        want["f_force"] += w[k] * J.T @ dpsi
        want["damping"] += w[k] * b * J.T @ J
    for f, v in want.items():
        np.testing.assert_allclose(np.asarray(getattr(got, f)), np.asarray(v), rtol=1e-4, atol=1e-5, err_msg=f)


def test_box_solve_is_the_metric_projection(fabric):
    """solve_in_box = argmin 1/2 a^T M a + f^T a over the box: in the box, no worse than scipy's
    L-BFGS-B (rel. 1e-3) on fabric states and random ill-conditioned systems, the free solution when
    that fits, and a large-metric direction keeps its acceleration where eq. 3.9 shrinks it."""
    from scipy.optimize import minimize

    from fabrax.fabrics import acceleration_box, solve_in_box, solve_shrinking

    fab, params = fabric
    rng = np.random.default_rng(3)
    lo_q, hi_q = np.asarray(fab.robot.lower), np.asarray(fab.robot.upper)
    p = fab.with_joint_goal(params, jnp.asarray(GOAL))
    scene = sc.from_dict(BAR)
    cases = []
    for k in range(40):
        q = jnp.asarray(rng.uniform(lo_q + 0.1, hi_q - 0.1), jnp.float32)
        qd = jnp.asarray(rng.normal(size=7) * 1.5, jnp.float32)
        spec = fab.evaluate(p, scene, q, qd).spec
        lo, hi = acceleration_box(fab.robot, q, qd, 0.01)
        cases.append((np.asarray(spec.M, np.float64), np.asarray(spec.f, np.float64), np.asarray(lo, np.float64), np.asarray(hi, np.float64)))
    for k in range(160):
        a = rng.normal(size=(7, 7))
        M = a @ a.T + 0.05 * np.eye(7) + (300.0 * np.outer(*(2 * [rng.normal(size=7)])) if k % 2 else 0.0)
        cases.append((M, rng.normal(size=7) * 10, -rng.uniform(0.5, 3, 7), rng.uniform(0.5, 3, 7)))
    solve = jax.jit(jax.vmap(lambda M, f, lo, hi: solve_in_box(Spec(M, f), lo, hi)))
    M, f, lo, hi = (jnp.asarray(np.stack(c), jnp.float32) for c in zip(*cases))
    got = np.asarray(solve(M, f, lo, hi), np.float64)
    worse = 0
    for a, (Mk, fk, lk, hk) in zip(got, cases):
        assert np.all(a >= lk - 1e-5) and np.all(a <= hk + 1e-5)
        cost = lambda x: 0.5 * x @ Mk @ x + fk @ x  # noqa: E731
        ref = minimize(cost, np.clip(-np.linalg.solve(Mk, fk), lk, hk), jac=lambda x: Mk @ x + fk, bounds=list(zip(lk, hk)), method="L-BFGS-B",
                       options=dict(ftol=1e-15, gtol=1e-12, maxiter=5000)).x  # fmt: skip
        worse += cost(a) > cost(ref) + 1e-3 * max(1.0, abs(cost(ref)))
    assert worse <= 2, f"{worse} of {len(cases)} box solves are worse than L-BFGS-B"
    # inside the box: the unconstrained solution
    Mi = jnp.asarray(np.diag([1.0, 2, 3, 4, 5, 6, 7]), jnp.float32)
    fi = jnp.asarray([0.5, -0.5, 0.3, 0.2, -0.1, 0.4, 0.0], jnp.float32)
    box = jnp.full(7, 10.0)
    assert jnp.allclose(solve_in_box(Spec(Mi, fi), -box, box), -fi / jnp.diag(Mi), atol=1e-6)
    # a barrier-like direction u (metric 1e3) asks for +2 along u while joint 0 wants far outside its bound
    u = jnp.asarray([0.0, 0.6, 0.8, 0.0, 0.0, 0.0, 0.0])
    Mb = jnp.eye(7) + 1e3 * jnp.outer(u, u)
    want = 2.0 * u + jnp.asarray([50.0, 0, 0, 0, 0, 0, 0])
    fb = -Mb @ want
    a_metric, a_shrink = solve_in_box(Spec(Mb, fb), -box, box), solve_shrinking(Spec(Mb, fb), -box, box)
    # the metric projection keeps the barrier's +2 along u and saturates joint 0; shrinking loses part of it
    assert float(u @ a_metric) > 1.99 and abs(float(a_metric[0]) - 10.0) < 1e-4 and float(u @ a_shrink) < 1.98


def _box_rounds(M, f, lo, hi, rounds):
    """Reference: the primal-dual active-set rounds of `solve_in_box`, `rounds` of them with no early stop."""
    from fabrax.fabrics.linalg import cholesky_solve

    cost = lambda a: 0.5 * a @ (M @ a) + f @ a  # noqa: E731
    a = jnp.clip(-cholesky_solve(M, f), lo, hi)
    best, best_cost, at_lo, at_hi = a, cost(a), a <= lo, a >= hi
    for _ in range(rounds):
        free = ~(at_lo | at_hi)
        b = jnp.where(at_lo, lo, jnp.where(at_hi, hi, 0.0))
        a = cholesky_solve(jnp.where(free[:, None] & free[None, :], M, 0.0) + jnp.diag(jnp.where(free, 0.0, 1.0)), jnp.where(free, -(f + M @ b), b))
        grad = M @ a + f
        at_lo, at_hi = (at_lo & (grad >= 0.0)) | (free & (a < lo)), (at_hi & (grad <= 0.0)) | (free & (a > hi))
        c = cost(jnp.clip(a, lo, hi))
        best, best_cost = jnp.where(c < best_cost, jnp.clip(a, lo, hi), best), jnp.minimum(c, best_cost)
    return best


def test_box_solve_stops_when_the_active_sets_repeat():
    """solve_in_box leaves its loop once a round repeats the active sets; the result equals all 8 rounds
    run (float rounding aside), also on systems that need several rounds and on free solutions."""
    from fabrax.fabrics import solve_in_box

    rng = np.random.default_rng(7)
    cases = []
    for k in range(400):
        a = rng.normal(size=(7, 7))
        M = a @ a.T + 0.05 * np.eye(7) + (300.0 * np.outer(*(2 * [rng.normal(size=7)])) if k % 2 else 0.0)
        scale = 10.0 if k % 4 < 2 else 0.1  # 0.1: mostly inside the box
        cases.append((M, rng.normal(size=7) * scale, -rng.uniform(0.5, 3, 7), rng.uniform(0.5, 3, 7)))
    # float64: the metrics' condition numbers reach 2e4, where float32 rounding alone moved two of
    # the 400 solutions by 4e-5 on one CPU (the same objective to 1e-9) and not on another
    with jax.enable_x64(True):
        M, f, lo, hi = (jnp.asarray(np.stack(c), jnp.float64) for c in zip(*cases))
        got = jax.jit(jax.vmap(lambda M, f, lo, hi: solve_in_box(Spec(M, f), lo, hi)))(M, f, lo, hi)
        want = jax.jit(jax.vmap(lambda M, f, lo, hi: _box_rounds(M, f, lo, hi, 8)))(M, f, lo, hi)
        assert jnp.allclose(got, want, rtol=1e-9, atol=1e-9)
        one = jax.jit(jax.vmap(lambda M, f, lo, hi: _box_rounds(M, f, lo, hi, 1)))(M, f, lo, hi)
        assert not jnp.allclose(one, want, rtol=1e-5, atol=1e-5)  # some systems need more than one round
