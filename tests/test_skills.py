"""Motion skills (riemannian_motion_skills_paper): vMF mixture, spline geodesics, pullback and ambient metrics, VAEs."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from fabrax.skills import demos, geodesic, metric, spline, vae, vmf

jax.config.update("jax_enable_x64", False)


def _sphere(n, seed=0):
    x = np.random.default_rng(seed).standard_normal((n, 4))
    return jnp.asarray(x / np.linalg.norm(x, axis=1, keepdims=True), jnp.float32)


@pytest.mark.parametrize("kappa", [0.5, 3.0, 10.0])
def test_vmf_mixture_integrates_to_one_and_is_antipodal(kappa):
    q = _sphere(400_000)
    mu = jnp.asarray([0.5, 0.5, -0.5, 0.5])
    area = 2.0 * np.pi**2  # surface of S^3
    mixture = float(jnp.mean(jnp.exp(vmf.log_antipodal(q, mu, kappa)))) * area
    single = float(jnp.mean(jnp.exp(vmf.log_vmf(q, mu, kappa)))) * area
    assert abs(mixture - 1.0) < 0.03 and abs(single - 1.0) < 0.03
    np.testing.assert_allclose(vmf.log_antipodal(q[:100], mu, kappa), vmf.log_antipodal(-q[:100], mu, kappa), rtol=1e-5)


def test_vmf_normaliser_is_stable():
    assert abs(float(vmf.log_normalizer(0.0)) + np.log(2 * np.pi**2)) < 1e-4  # uniform density at kappa -> 0
    big = float(vmf.log_normalizer(5e4))
    asymptotic = np.log(5e4) - 2 * np.log(2 * np.pi) - 5e4 + 0.5 * np.log(2 * np.pi * 5e4)  # I_1(k) ~ e^k / sqrt(2 pi k)
    assert np.isfinite(big) and abs(big - asymptotic) < 0.05


def test_spline_end_points_and_c2_continuity():
    sb = spline.basis(segments=6, points=25)
    rng = np.random.default_rng(1)
    a, b, w = jnp.asarray(rng.standard_normal(3)), jnp.asarray(rng.standard_normal(3)), jnp.asarray(rng.standard_normal((7, 3)))
    c = np.asarray(spline.coefficients(sb, a, b, w), np.float64).reshape(6, 4, 3)  # (segment, power, dim)
    h = 1.0 / 6
    np.testing.assert_allclose(c[0, 0], a, atol=1e-5)
    np.testing.assert_allclose(sum(c[-1, k] * h**k for k in range(4)), b, atol=1e-5)
    for i in range(5):  # segment i at its right end == segment i + 1 at its left end, in value, slope and curvature
        left = c[i]
        assert np.allclose(sum(left[k] * h**k for k in range(4)), c[i + 1, 0], atol=1e-5)
        assert np.allclose(sum(k * left[k] * h ** (k - 1) for k in range(1, 4)), c[i + 1, 1], atol=1e-5)
        assert np.allclose(sum(k * (k - 1) * left[k] * h ** (k - 2) for k in range(2, 4)), 2.0 * c[i + 1, 2], atol=1e-5)
    # the evaluation matrices agree with the coefficients
    ends = np.asarray(spline.evaluate(sb, jnp.asarray(c.reshape(24, 3), jnp.float32), t=np.array([0.0, 1.0])))
    np.testing.assert_allclose(ends, np.stack([a, b]), atol=1e-5)


def _flat_speed2(args, z, v):
    return jnp.sum(v**2)


@pytest.mark.parametrize("method", geodesic.METHODS)
def test_identity_metric_geodesic_is_the_straight_line_and_energy_decreases(method):
    sb = spline.basis(5, 20)
    cfg = geodesic.GeodesicConfig(method=method, rule="gauss", lr=0.05, iters=2000, tol=1e-5)
    a, b = jnp.asarray([-1.0, 0.5]), jnp.asarray([2.0, -1.0])
    w0 = spline.straight(sb, a, b) + 0.3 * jax.random.normal(jax.random.key(0), (6, 2))
    g = geodesic.shortest(_flat_speed2, None, sb, a, b, cfg, w0=w0)
    line = a + sb.t[:, None] * (b - a)
    np.testing.assert_allclose(g.z, line, atol=2e-3)
    assert float(g.energy) < float(g.energy0)
    assert abs(float(g.energy) - float(jnp.sum((b - a) ** 2))) < 1e-3  # constant-speed line: E = |b - a|^2
    trace = np.asarray(g.trace)
    assert np.mean(np.diff(trace) <= 1e-6) > 0.9


def _bump(args, z, v):  # a metric with off-diagonal terms that vary with z
    m = jnp.asarray([[1.0, 0.3], [0.3, 2.0]]) + 0.5 * jnp.sin(z[0]) * jnp.asarray([[0.0, 1.0], [1.0, 0.0]])
    return (v @ m @ v) * (1.0 + args * jnp.exp(-jnp.sum(z * z)))


def test_energy_terms_are_the_energy_its_gradient_and_hessian():
    sb = spline.basis(5, 20)
    a, b = jnp.asarray([-1.0, 0.2]), jnp.asarray([1.0, -0.3])
    w = spline.straight(sb, a, b) + 0.2 * jax.random.normal(jax.random.key(0), (6, 2))
    e, g, h = geodesic.energy_terms(_bump, 4.0, sb, a, b, w)
    energy = lambda w: geodesic.energy(_bump, 4.0, sb, a, b, w)  # noqa: E731
    np.testing.assert_allclose(e, energy(w), rtol=1e-6)
    np.testing.assert_allclose(g, jax.grad(energy)(w), atol=1e-5)
    np.testing.assert_allclose(h, jax.hessian(energy)(w).reshape(12, 12), atol=1e-5)
    np.testing.assert_allclose(h, h.T, atol=1e-6)


def test_a_shrinking_batch_gives_each_pair_its_own_result():
    """Pairs that still run after the others stopped go on as a sub-batch: the same energies and steps as
    one batch that runs every pair to its own stop (shrink=1), and as each pair alone."""
    rng = np.random.default_rng(2)
    starts = jnp.asarray(rng.uniform(-2.0, -0.5, (40, 2)), jnp.float32)
    ends = jnp.asarray(rng.uniform(0.5, 2.0, (40, 2)), jnp.float32)
    cfg = geodesic.GeodesicConfig(iters=60, rule="gauss")
    shrunk = geodesic.solver(_bump, cfg)(jnp.float32(4.0), starts, ends)
    whole = geodesic.solver(_bump, dataclasses.replace(cfg, shrink=1))(jnp.float32(4.0), starts, ends)
    assert len(set(np.asarray(shrunk.iters).tolist())) > 3  # the pairs stop at different steps
    np.testing.assert_array_equal(shrunk.iters, whole.iters)
    np.testing.assert_allclose(shrunk.energy, whole.energy, rtol=1e-5)
    np.testing.assert_allclose(shrunk.trace, whole.trace, rtol=1e-5)
    sb = spline.basis(cfg.segments, cfg.points)
    alone = geodesic.shortest(_bump, jnp.float32(4.0), sb, starts[7], ends[7], cfg)
    np.testing.assert_allclose(alone.energy, shrunk.energy[7], rtol=1e-5)
    assert np.all(np.asarray(shrunk.energy) < np.asarray(shrunk.energy0))


def test_geodesic_config_refuses_an_unknown_method_or_rule():
    with pytest.raises(ValueError, match="geodesic.method"):
        geodesic.GeodesicConfig(method="bfgs")
    with pytest.raises(ValueError, match="geodesic.rule"):
        geodesic.GeodesicConfig(rule="simpson")
    with pytest.raises(ValueError, match="chord2"):  # a bare speed2 has no chords
        geodesic.solver(_bump, geodesic.GeodesicConfig())


class _Step(nnx.Module):
    """z -> (z1, z2, height tanh(z1 / width)): a flat sheet with a step of 2 height across z1 = 0, `width` wide."""

    def __init__(self, height: float, width: float):
        self.height, self.width = height, width

    def embed(self, z):
        return jnp.asarray([z[0], z[1], 0.5])[None], jnp.asarray([z[0], z[1], self.height * jnp.tanh(z[0] / self.width)])[None], jnp.zeros(0)

    def rows(self, z, v):
        return metric.embedding_rows(self.embed, z, v)

    def chord(self, za, zb):
        return metric.embedding_chord(self.embed, za, zb)


def test_chord_energy_bounds_the_curve_energy_from_below_and_sees_a_step_between_points():
    """Chords: N sum |h(z_n+1) - h(z_n)|^2 <= int |dh/dt|^2 dt (Cauchy-Schwarz), rising with every halving of the
    chords; a step of the decoder between two vertices costs its whole jump, where Gauss points just miss it."""
    gd, state = nnx.split(_Step(1.0, 0.2))
    cm, args = metric.curve_metric(gd), (state, metric.NONE)
    a, b = jnp.asarray([-1.0, 0.3]), jnp.asarray([1.0, -0.2])
    sb = spline.basis(5, 20)
    coeffs = spline.coefficients(sb, a, b, spline.straight(sb, a, b) + 0.1 * jax.random.normal(jax.random.key(1), (6, 2)))
    chords = [float(geodesic.curve_energy(cm, args, spline.basis(5, n, "chord"), coeffs)) for n in (10, 20, 40, 80, 160, 2000)]
    true = float(geodesic.curve_energy(cm, args, spline.basis(5, 2000, "gauss"), coeffs))
    assert all(c1 <= c2 * (1 + 1e-5) for c1, c2 in zip(chords, chords[1:]))
    assert chords[-1] <= true * (1 + 1e-4) and chords[-1] > 0.999 * true
    # a step 1e-3 wide across the straight line's midpoint, which no Gauss point of 20 comes near
    gd, state = nnx.split(_Step(1.0, 1e-3))
    cm, args = metric.curve_metric(gd), (state, metric.NONE)
    a, b = jnp.asarray([-1.0, 0.0]), jnp.asarray([1.0, 0.0])
    line = spline.coefficients(sb, a, b, spline.straight(sb, a, b))
    gauss = float(geodesic.curve_energy(cm, args, spline.basis(5, 20, "gauss"), line))
    chord = float(geodesic.curve_energy(cm, args, spline.basis(5, 20, "chord"), line))
    assert gauss < 4.1  # |b - a|^2: the step unseen
    assert chord > 4.0 + 20 * 4.0 / 2 * 0.99  # a jump of 2 over at most two chords (here a vertex sits on it) costs >= 20 (2)^2 / 2


def test_chord2_is_the_squared_speed_over_a_short_chord(task_skill, panda):
    """chord2(z, z + eps v) / eps^2 -> v^T M(z) v, for both VAEs and under an ambient metric."""
    model, log, _, _ = task_skill
    theta = np.asarray(panda.clip(jnp.asarray([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785]))) + 0.2 * np.random.default_rng(0).standard_normal((100, 7))
    joint, _ = vae.fit_joint(panda, theta, vae.VAEConfig(steps=100, rbf_steps=30, centers=8))
    v, eps = jnp.asarray([0.3, -0.7]), 1e-3
    for m, z in ((model, jnp.asarray(log["codes"][3], jnp.float32)), (joint, jnp.asarray([0.3, -0.2]))):
        anchor = m.rows(z, v)[0][-1]
        for obs in (metric.NONE, metric.obstacles([np.asarray(anchor) + 0.05], [0.1], eta=20.0)):
            s2 = float(metric.speed2(m, obs, z, v))
            c2 = float(metric.chord2(m, obs, z - 0.5 * eps * v, z + 0.5 * eps * v)) / eps**2
            assert abs(c2 - s2) < 2e-3 * s2


class _Plane(nnx.Module):
    """A flat 2-D sheet z -> (z1, z2, 0.5) in R^3: its pullback metric is the identity."""

    def rows(self, z, v):
        return jnp.asarray([z[0], z[1], 0.5])[None], jnp.concatenate([v, jnp.zeros(1)])[None], jnp.zeros(0)

    def chord(self, za, zb):
        return jnp.asarray([0.5 * (za[0] + zb[0]), 0.5 * (za[1] + zb[1]), 0.5])[None], jnp.concatenate([zb - za, jnp.zeros(1)])[None], jnp.zeros(0)


@pytest.mark.parametrize("method", geodesic.METHODS)
@pytest.mark.parametrize("rule", spline.RULES)
def test_ambient_metric_increases_clearance_from_an_obstacle_on_the_euclidean_geodesic(method, rule):
    model = _Plane()
    gd, state = nnx.split(model)
    cfg = geodesic.GeodesicConfig(method=method, rule=rule, iters=600, lr=0.02)
    a, b = jnp.asarray([[-1.0, 0.0]]), jnp.asarray([[1.0, 0.05]])
    center = np.array([0.0, 0.025, 0.5])  # on the straight line between a and b
    obs = metric.obstacles([center], [0.3], eta=50.0)
    plain = geodesic.solver(metric.curve_metric(gd), cfg)((state, metric.NONE), a, b)
    shaped = geodesic.solver(metric.curve_metric(gd), cfg)((state, obs), a, b)
    from fabrax.skills.spline import dense

    def clear(g):
        z = np.asarray(dense(g.coeffs[0], 400))
        return float(np.min(np.linalg.norm(np.c_[z, np.full(len(z), 0.5)] - center, axis=1)))

    assert clear(plain) < 0.01
    assert clear(shaped) > clear(plain) + 0.1
    # the check at 10x the points: this smooth metric is resolved
    np.testing.assert_allclose(shaped.resolved, shaped.energy, rtol=0.02)
    # the metric itself: identity away from the obstacle, scaled by 1 + eta at its centre
    np.testing.assert_allclose(metric.metric(model, obs, jnp.asarray([5.0, 5.0])), np.eye(2), atol=1e-5)
    np.testing.assert_allclose(metric.metric(model, obs, jnp.asarray(center[:2])), 51.0 * np.eye(2), rtol=1e-5)


@pytest.fixture(scope="module")
def task_skill():
    x, q = demos.jc(points=40)
    cfg = vae.VAEConfig(steps=1500, rbf_steps=300, centers=24)
    model, log = vae.fit_task(x.reshape(-1, 3), q.reshape(-1, 4), cfg)
    return model, log, cfg, x


def test_task_metric_symmetric_positive_definite_and_matches_speed(task_skill):
    model, log, _, _ = task_skill
    codes = log["codes"]
    zs = jnp.asarray(np.concatenate([codes[::37], codes[::37] + 3.0]), jnp.float32)
    ms = jax.vmap(lambda z: metric.metric(model, metric.NONE, z))(zs)
    np.testing.assert_allclose(ms, jnp.swapaxes(ms, 1, 2), rtol=1e-5, atol=1e-6)
    assert np.all(np.linalg.eigvalsh(np.asarray(ms, np.float64)) > 0)
    v = jnp.asarray([0.3, -0.7])
    vmv = jax.vmap(lambda m: v @ m @ v)(ms)
    s2 = jax.vmap(lambda z: metric.speed2(model, metric.NONE, z, v))(zs)
    np.testing.assert_allclose(vmv, s2, rtol=1e-3)
    # eqs. 21-25 from the decoders' Jacobians directly
    z = zs[0]
    jx, js = jax.jacfwd(model.decode_x)(z), jax.jacfwd(model.std_x)(z)
    jq, jk = jax.jacfwd(model.decode_q)(z), jax.jacfwd(lambda z: jax.lax.rsqrt(model.kappa(z)))(z)
    np.testing.assert_allclose(ms[0], jx.T @ jx + js.T @ js + jq.T @ jq + jnp.outer(jk, jk), rtol=1e-3, atol=1e-6)
    # no NaN at zero velocity, in the value or its gradient
    g = jax.grad(lambda z: metric.speed2(model, metric.NONE, z, jnp.zeros(2)))(z)
    assert float(metric.speed2(model, metric.NONE, z, jnp.zeros(2))) == 0.0 and np.all(np.isfinite(g))


def test_trained_vae_variance_grows_away_from_the_data(task_skill):
    model, log, _, _ = task_skill
    codes = jnp.asarray(log["codes"], jnp.float32)
    far = codes + 6.0 * jnp.sign(codes.mean(0)) + 6.0
    on_data = jax.vmap(model.std_x)(codes).mean()
    off_data = jax.vmap(model.std_x)(far).mean()
    assert float(off_data) > 10.0 * float(on_data)
    assert float(jax.vmap(model.kappa)(far).mean()) < 0.1 * float(jax.vmap(model.kappa)(codes).mean())


@pytest.mark.parametrize("rule", spline.RULES)
def test_energy_gradient_matches_finite_differences(task_skill, rule):
    model, log, _, _ = task_skill
    gd, state = nnx.split(model)
    f = metric.curve_metric(gd)
    sb = spline.basis(4, 20, rule)
    a, b = jnp.asarray(log["codes"][0], jnp.float32), jnp.asarray(log["codes"][-1], jnp.float32)
    w = spline.straight(sb, a, b)
    e = lambda w: geodesic.energy(f, (state, metric.NONE), sb, a, b, w)  # noqa: E731
    g = jax.grad(e)(w)
    d = jax.random.normal(jax.random.key(3), w.shape)
    eps = 1e-2
    fd = (e(w + eps * d) - e(w - eps * d)) / (2 * eps)
    assert abs(float(fd) - float(jnp.sum(g * d))) < 0.05 * abs(float(fd)) + 1e-3
    _, g_terms, h_terms = geodesic.energy_terms(f, (state, metric.NONE), sb, a, b, w)  # Newton's terms, assembled per point
    np.testing.assert_allclose(g_terms, g, rtol=1e-3, atol=1e-4)
    grad = jax.jit(jax.grad(e))
    hd = (grad(w + eps * d) - grad(w - eps * d)).reshape(-1) / (2 * eps)  # Hessian times d, by central differences
    assert float(jnp.linalg.norm(h_terms @ d.reshape(-1) - hd)) < 0.05 * float(jnp.linalg.norm(hd)) + 1e-3


def test_geodesic_follows_the_data_better_than_the_latent_line(task_skill):
    from fabrax.skills.experiment import nearest
    from fabrax.skills.rbf import kmeans
    from fabrax.skills.spline import dense

    model, log, _, x = task_skill
    codes = log["codes"][: x.size // 3].reshape(x.shape[0], x.shape[1], -1)
    gd, state = nnx.split(model)
    nodes = kmeans(codes.reshape(-1, 2), 48)[0]
    a, b = jnp.asarray(codes[:, 0]), jnp.asarray(codes[:, -1])
    cfg = geodesic.GeodesicConfig()
    solve = lambda m: geodesic.solver(metric.curve_metric(gd), dataclasses.replace(cfg, method=m), nodes)((state, metric.NONE), a, b)  # noqa: E731
    g, adam = solve("newton"), solve("adam")
    assert np.all(np.asarray(g.energy) <= np.asarray(g.energy0) + 1e-4)
    assert np.all(np.asarray(g.energy) <= 1.05 * np.asarray(adam.energy) + 1e-3)  # Newton gets at least as low as Adam's 300 steps
    sb = cfg.basis()
    line = jax.vmap(lambda a, b: spline.coefficients(sb, a, b, spline.straight(sb, a, b)))(a, b)
    dec = lambda c: np.asarray(jax.vmap(jax.vmap(model.decode_x))(jax.vmap(dense)(c)))  # noqa: E731
    d_geo, d_line = nearest(dec(g.coeffs), x.reshape(-1, 3)), nearest(dec(line), x.reshape(-1, 3))
    assert d_geo.mean() < d_line.mean()


def test_joint_vae_metric_is_the_fk_pullback(panda):
    theta = np.asarray(panda.clip(jnp.asarray([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785]))) + 0.2 * np.random.default_rng(0).standard_normal((200, 7))
    model, _ = vae.fit_joint(panda, theta, vae.VAEConfig(steps=200, rbf_steps=50, centers=8))
    z = jnp.asarray([0.3, -0.2])
    m = metric.metric(model, metric.NONE, z)

    def fk_flat(t):
        p, r = model.fk(t)
        return jnp.concatenate([p.reshape(-1), r])

    jmu = jax.jacfwd(lambda z: fk_flat(model.decode(z)))(z)
    jsd = jax.jacfwd(fk_flat)(model.decode(z)) @ jax.jacfwd(model.std)(z)
    np.testing.assert_allclose(m, jmu.T @ jmu + jsd.T @ jsd, rtol=2e-3, atol=1e-6)  # eq. 28
    assert np.all(np.linalg.eigvalsh(np.asarray(m, np.float64)) > 0)
    # the multi-limb ambient metric (eq. 32) weighs every FK point: an obstacle at one of them raises M
    p, _ = model.fk(model.decode(z))
    obs = metric.obstacles([np.asarray(p[3])], [0.1], eta=10.0)
    assert float(jnp.trace(metric.metric(model, obs, z))) > float(jnp.trace(m))


def test_skill_save_load_roundtrip(task_skill, tmp_path):
    model, log, cfg, _ = task_skill
    vae.save(tmp_path / "s.msgpack", model, cfg, {"demo": "jc"})
    loaded, head = vae.load(tmp_path / "s.msgpack")
    z = jnp.asarray(log["codes"][5], jnp.float32)
    np.testing.assert_allclose(metric.metric(loaded, metric.NONE, z), metric.metric(model, metric.NONE, z), rtol=1e-6)
    assert head["demo"] == "jc" and head["kind"] == "task"
    (tmp_path / "bad.msgpack").write_bytes(b"not a skill")
    with pytest.raises(ValueError, match="cannot read skill"):
        vae.load(tmp_path / "bad.msgpack")


def test_bad_inputs_fail_clearly():
    x = np.zeros((10, 3))
    x[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        vae.fit_task(x, np.tile([1.0, 0, 0, 0], (10, 1)))
    with pytest.raises(ValueError, match=r"shape \(n, 4\)"):
        vae.fit_task(np.zeros((10, 3)), np.zeros((10, 3)))
    with pytest.raises(ValueError, match="radii"):
        metric.obstacles([[0, 0, 0], [1, 1, 1]], [0.1])
    with pytest.raises(ValueError, match="unknown shape"):
        demos.lasa("NoSuchShape")


def test_hemisphere_puts_a_quaternion_set_on_one_side_or_refuses_it():
    q = np.asarray(_sphere(2000, seed=4))
    near = q[np.abs(q @ np.array([0.6, 0.0, 0.8, 0.0])) > 0.9]  # within 26 degrees of an axis (either sign)
    out = vae.hemisphere(near)
    np.testing.assert_allclose(np.abs(out), np.abs(near), atol=1e-7)  # the same orientations
    assert np.all(out @ out.mean(0) > 0) and len(near) > 5
    with pytest.raises(ValueError, match="antipodal"):  # orientations all over the sphere: no hemisphere holds them
        vae.hemisphere(q)


def test_two_ik_branches_trace_the_same_path(panda):
    x, q = demos.lasa("Sshape", points=30)
    seeds = np.array([[0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785], [1.2, -0.3, -1.2, -2.0, 0.3, 1.8, 0.785]], np.float32)
    theta, residual = demos.two_branches(panda, x[:2], q[:2], seeds)
    assert residual < 2e-3
    a, b = theta[:2], theta[2:]
    assert np.linalg.norm(a - b, axis=-1).mean() > 0.5  # distinct configurations for the same hand path


@pytest.mark.slow
def test_skills_experiment_end_to_end(tmp_path):
    from hydra import compose, initialize_config_dir

    from fabrax import config
    from fabrax.skills.experiment import run

    with initialize_config_dir(config_dir=str(config.config_dir()), version_base=None):
        cfg = config.resolve(compose("skills"))
    cfg.update(points=30, pairs=8, graph_nodes=24, timing={"repeats": 2, "batch": 4})
    cfg["vae"].update(steps=600, rbf_steps=150, centers=16)
    cfg["follow"].update(waypoints=4)
    result = run(cfg, tmp_path)
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["distance_to_demos"]["riemannian"]["mean_m"] == result["distance_to_demos"]["riemannian"]["mean_m"]
    for f in ("results.md", "skill.msgpack", "paths.npz", "latent.png", "paths.png"):
        assert (tmp_path / f).stat().st_size > 0
    o = result["obstacle"]
    assert 0.0 <= o["plain"]["fabric_success_rate"] <= 1.0 and result["timing"]["single_ms"] > 0
