"""VAEs whose decoders define a skill's Riemannian metric (paper §3.1 task space, §3.2 joint space).

Both models share a Gaussian encoder q(z|x) and the standard normal prior;
decoder means are tanh MLPs (smooth, so their Jacobians are), decoder variances
are RBF precision networks (`fabrax.skills.rbf`). Training has two stages, as in
Arvanitidis et al. 2018: (1) encoder and decoder means with a fixed global
variance, (2) the RBF variances alone, centred by k-means on the codes.

Each model gives `rows(z, v)`: the velocities, along a latent velocity v, of
the decoded quantities whose Jacobians form the pullback metric (eqs. 21-25,
28) -- mean and standard deviation of each decoded variable -- split into rows
attached to a 3-D point (reweighted by an ambient metric, eq. 30-32) and free
rows. v^T M(z) v is the summed square of the rows (`fabrax.skills.metric`).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx, serialization

from fabrax.robot.kinematics import frame_transforms
from fabrax.skills import vmf
from fabrax.skills.metric import embedding_chord, embedding_rows
from fabrax.skills.rbf import RBFPrecision, RBFWeight
from fabrax.state_io import from_flat, to_flat


@dataclass(frozen=True)
class VAEConfig:
    latent: int = 2
    hidden: int = 64
    steps: int = 10000  # stage 1: encoder and decoder means
    rbf_steps: int = 1500  # stage 2: RBF variances
    lr: float = 1e-2  # cosine-decayed to 5 %
    rbf_lr: float = 0.03  # stage 2 (log weights)
    clip: float = 10.0  # gradient global-norm clip
    centers: int = 64  # RBF kernels
    bandwidth: float = 1.0  # kernel width in units of its cluster's spread; at 0.5 the variance's walls were thinner than
    # a 20-point curve's spacing on J/C and LASA (docs/results.md "Geodesics that resolve the metric")
    zeta: float = 1e-2  # precision floor far from the data (variance up to 1 / zeta, in data units)
    stage1_std: float = 0.05  # fixed decoder std of stage 1, in data units (a learned one lets the means underfit)
    stage1_kappa: float = 100.0  # fixed vMF concentration of stage 1
    min_std: float = 0.01  # standard-deviation floor in data units: a coordinate the demonstrations hold
    # constant (a drawing plane) would otherwise drive its variance to zero and the likelihood to infinity
    max_kappa: float = 1e4  # vMF concentration ceiling, for the same reason (an orientation held throughout)
    antipodal: bool = True  # the encoder sees every pose with q and -q (§3.1.2's antipodal copies) either way. True: the
    # decoder's likelihood is the antipodal vMF mixture (eq. 17), which leaves its sign free; False: one vMF (eq. 15) of the
    # quaternion on its set's hemisphere. A decoder that flipped its sign inside the data (J/C, 1 of 4 training seeds) made a
    # near-zero quaternion mean there that no curve discretisation resolves (docs/results.md "Geodesics that resolve the metric")
    lambda_x: float = 1.0  # eq. 18 weight of the position likelihood
    lambda_q: float = 1.0  # eq. 18 weight of the orientation likelihood
    seed: int = 0


class MLP(nnx.Module):
    def __init__(self, sizes, *, rngs: nnx.Rngs):
        self.layers = nnx.List([nnx.Linear(a, b, rngs=rngs) for a, b in zip(sizes[:-1], sizes[1:])])

    def __call__(self, x):
        for layer in self.layers[:-1]:
            x = jnp.tanh(layer(x))
        return self.layers[-1](x)


class Encoder(nnx.Module):
    def __init__(self, inputs: int, latent: int, hidden: int, *, rngs: nnx.Rngs):
        self.net = MLP([inputs, hidden, hidden, 2 * latent], rngs=rngs)
        self.latent = latent

    def __call__(self, x):
        h = self.net(x)
        return h[..., : self.latent], jnp.clip(h[..., self.latent :], -12.0, 4.0)


def _kl(m, logv):
    return 0.5 * jnp.sum(jnp.exp(logv) + m**2 - 1.0 - logv, axis=-1)


def _gauss(x, mean, std):
    return jnp.sum(-0.5 * ((x - mean) / std) ** 2 - jnp.log(std) - 0.5 * jnp.log(2 * jnp.pi), axis=-1)


class TaskVAE(nnx.Module):
    """End-effector poses in R^3 x S^3 (§3.1): Gaussian positions, vMF quaternions (eqs. 13-17; antipodal mixture or one
    vMF on a hemisphere, `VAEConfig.antipodal`)."""

    def __init__(self, cfg: VAEConfig, x_mean, x_scale, *, rngs: nnx.Rngs):
        d, h = cfg.latent, cfg.hidden
        self.antipodal = cfg.antipodal
        self.x_mean, self.x_scale = nnx.Variable(jnp.asarray(x_mean, jnp.float32)), nnx.Variable(jnp.asarray(x_scale, jnp.float32))
        self.encoder = Encoder(7, d, h, rngs=rngs)
        self.mean_x, self.mean_q = MLP([d, h, h, 3], rngs=rngs), MLP([d, h, h, 4], rngs=rngs)
        self.prec_x = RBFPrecision(d, 3, cfg.centers, cfg.zeta / float(np.mean(np.asarray(x_scale)) ** 2), rngs=rngs)
        self.prec_q = RBFPrecision(d, 1, cfg.centers, cfg.zeta, rngs=rngs)
        self.std1 = nnx.Variable(cfg.stage1_std * jnp.asarray(x_scale, jnp.float32))
        self.kappa1 = nnx.Variable(jnp.asarray(cfg.stage1_kappa, jnp.float32))
        self.min_var = nnx.Variable((cfg.min_std * jnp.asarray(x_scale, jnp.float32)) ** 2)
        self.max_kappa = nnx.Variable(jnp.asarray(cfg.max_kappa, jnp.float32))
        self.stage = nnx.Variable(jnp.asarray(1))

    def encode(self, x, q):
        return self.encoder(jnp.concatenate([(x - self.x_mean[...]) / self.x_scale[...], q], -1))

    def decode_x(self, z):
        return self.x_mean[...] + self.x_scale[...] * self.mean_x(z)

    def decode_q(self, z):
        m = self.mean_q(z)
        return m / jnp.sqrt(jnp.sum(m**2, axis=-1, keepdims=True) + 1e-6)

    def std_x(self, z):
        """Position standard deviation (m): RBF after stage 2, the global value before; floored by min_std."""
        var = jnp.where(self.stage[...] > 1, 1.0 / self.prec_x(z), self.std1[...] ** 2)
        return jnp.sqrt(var + self.min_var[...])

    def kappa(self, z):
        """vMF concentration: the RBF precision itself (high on the data, zeta far from it), below max_kappa."""
        k = jnp.where(self.stage[...] > 1, self.prec_q(z)[0], self.kappa1[...])
        return 1.0 / (1.0 / k + 1.0 / self.max_kappa[...])

    def rbf_start(self):
        """(RBF network, starting precision) pairs from the first stage's global variances."""
        return [(self.prec_x, self.std1[...] ** -2), (self.prec_q, self.kappa1[...])]

    def uncertainty(self, z):
        """Predictive spread for display (Fig. 3 top): summed position variance (m^2) plus 1 / kappa."""
        return jnp.sum(self.std_x(z) ** 2) + 1.0 / self.kappa(z)

    def log_lik(self, z, x, q):
        """(log p(x|z), log p(q|z)) of one sample, eqs. 14 and 17 (or 15)."""
        log_q = vmf.log_antipodal if self.antipodal else vmf.log_vmf
        return _gauss(x, self.decode_x(z), self.std_x(z)), log_q(q, self.decode_q(z), self.kappa(z))

    def embed(self, z):
        """The decoded quantities whose pullback is the metric (eqs. 21-25): the position mean and std
        (attached to the decoded position) and the quaternion mean and spread kappa^-1/2 (free)."""
        x = self.decode_x(z)
        return x[None], jnp.concatenate([x, self.std_x(z)])[None], jnp.concatenate([self.decode_q(z), jax.lax.rsqrt(self.kappa(z))[None]])

    def rows(self, z, v):
        """Velocities of `embed` along the latent velocity v: (anchors (1, 3), attached (1, 6), free (5,))."""
        return embedding_rows(self.embed, z, v)

    def chord(self, za, zb):
        """Differences of `embed` over the chord za -> zb, anchored at the decoded positions' midpoint."""
        return embedding_chord(self.embed, za, zb)

    def loss(self, data, key, cfg: VAEConfig):
        """Negative weighted ELBO, eq. 18, one reparameterised sample per point: data (x, q the encoder sees, q the
        decoder's target)."""
        x, q, target = data
        m, logv = self.encode(x, q)
        z = m + jnp.exp(0.5 * logv) * jax.random.normal(key, m.shape)
        lx, lq = jax.vmap(self.log_lik)(z, x, target)
        return -jnp.mean(cfg.lambda_x * lx + cfg.lambda_q * lq - _kl(m, logv))


def fk_points(robot, tcp: str, orient_scale: float):
    """The FK layer of §3.2: joint origins along the arm and the TCP position (K, 3), and the TCP
    orientation as its rotation matrix times `orient_scale` metres (9,), smooth everywhere."""
    fr, local = robot.frame_point(tcp)

    def f(theta):
        r, t = frame_transforms(robot, theta)
        ee = r[fr] @ local + t[fr]
        return jnp.concatenate([t[1:], ee[None]]), orient_scale * r[fr].reshape(-1)

    return f


class JointVAE(nnx.Module):
    """Joint configurations (§3.2) with a forward-kinematics layer (eqs. 26-28)."""

    def __init__(self, cfg: VAEConfig, robot, theta_mean, theta_scale, tcp: str = "panda_tcp", orient_scale: float = 0.1, *, rngs: nnx.Rngs):
        d, h, n = cfg.latent, cfg.hidden, robot.dof
        self.fk = fk_points(robot, tcp, orient_scale)  # a static closure: the robot is not a parameter
        self.t_mean, self.t_scale = nnx.Variable(jnp.asarray(theta_mean, jnp.float32)), nnx.Variable(jnp.asarray(theta_scale, jnp.float32))
        self.encoder = Encoder(n, d, h, rngs=rngs)
        self.mean = MLP([d, h, h, n], rngs=rngs)
        self.prec = RBFPrecision(d, n, cfg.centers, cfg.zeta / float(np.mean(np.asarray(theta_scale)) ** 2), rngs=rngs)
        self.std1 = nnx.Variable(cfg.stage1_std * jnp.asarray(theta_scale, jnp.float32))
        self.min_var = nnx.Variable((cfg.min_std * jnp.asarray(theta_scale, jnp.float32)) ** 2)
        self.stage = nnx.Variable(jnp.asarray(1))

    def encode(self, theta):
        return self.encoder((theta - self.t_mean[...]) / self.t_scale[...])

    def decode(self, z):
        return self.t_mean[...] + self.t_scale[...] * self.mean(z)

    def std(self, z):
        """Joint standard deviation (rad): RBF after stage 2, the global value before; floored by min_std."""
        var = jnp.where(self.stage[...] > 1, 1.0 / self.prec(z), self.std1[...] ** 2)
        return jnp.sqrt(var + self.min_var[...])

    def rbf_start(self):
        return [(self.prec, self.std1[...] ** -2)]

    def uncertainty(self, z):
        """Predictive spread for display (Fig. 5 middle): summed joint variance (rad^2)."""
        return jnp.sum(self.std(z) ** 2)

    def log_volume(self, theta):
        """log V of eq. 27: 0.5 log det(J^T J) of the full FK layer's Jacobian (all points, TCP orientation)."""
        jac = jax.jacfwd(lambda t: jnp.concatenate([a.reshape(-1) for a in self.fk(t)]))(theta)
        return 0.5 * jnp.linalg.slogdet(jac.T @ jac + 1e-9 * jnp.eye(jac.shape[1]))[1]

    def rows(self, z, v):
        """Eq. 28: the FK layer's velocities along J_mu v and along J_sigma v; per-point rows attached to
        the decoded points (the multi-limb ambient metric reweights each), orientation rows free."""
        theta, dth = jax.jvp(self.decode, (z,), (v,))
        _, dsd = jax.jvp(self.std, (z,), (v,))
        (p, _), (dp_m, do_m) = jax.jvp(self.fk, (theta,), (dth,))
        _, (dp_s, do_s) = jax.jvp(self.fk, (theta,), (dsd,))
        return p, jnp.concatenate([dp_m, dp_s], -1), jnp.concatenate([do_m, do_s])

    def chord(self, za, zb):
        """`rows` over the chord za -> zb: the FK layer's point and orientation differences between the decoded
        means, and the std difference through the FK Jacobian at the means' midpoint (eq. 28's J_fk J_sigma),
        anchored at the points' midpoints."""
        ta, tb = self.decode(za), self.decode(zb)
        (pa, oa), (pb, ob) = self.fk(ta), self.fk(tb)
        _, (dp_s, do_s) = jax.jvp(self.fk, (0.5 * (ta + tb),), (self.std(zb) - self.std(za),))
        return 0.5 * (pa + pb), jnp.concatenate([pb - pa, dp_s], -1), jnp.concatenate([ob - oa, do_s])

    def loss(self, data, key, cfg: VAEConfig):
        """Negative ELBO of eq. 26: log p(theta|z) - log V(mu(z)) - KL."""
        (theta,) = data
        m, logv = self.encode(theta)
        z = m + jnp.exp(0.5 * logv) * jax.random.normal(key, m.shape)
        mu = jax.vmap(self.decode)(z)
        ll = _gauss(theta, mu, jax.vmap(self.std)(z)) - jax.vmap(self.log_volume)(mu)
        return -jnp.mean(ll - _kl(m, logv))


def _train(model, wrt, data, cfg: VAEConfig, steps: int, lr: float, key) -> np.ndarray:
    """Full-batch Adam on the parameters selected by `wrt`, all steps in one `lax.scan`; the loss per step."""
    graphdef, train, rest = nnx.split(model, wrt, ...)
    opt = optax.chain(optax.clip_by_global_norm(cfg.clip), optax.adam(optax.cosine_decay_schedule(lr, steps, alpha=0.05)))

    def step(carry, k):
        p, st = carry
        loss, g = jax.value_and_grad(lambda p: nnx.merge(graphdef, p, rest).loss(data, k, cfg))(p)
        upd, st = opt.update(g, st, p)
        return (optax.apply_updates(p, upd), st), loss

    run = jax.jit(lambda p, keys: jax.lax.scan(step, (p, opt.init(p)), keys))
    (train, _), losses = run(train, jax.random.split(key, steps))
    nnx.update(model, train)
    return np.asarray(losses)


def fit(model, data, cfg: VAEConfig, codes_of) -> dict[str, np.ndarray]:
    """Both training stages; `codes_of(model)` gives the latent means (n, d) of the training data."""
    k1, k2 = jax.random.split(jax.random.key(cfg.seed))
    stage1 = _train(model, nnx.All(nnx.Param, nnx.Not(RBFWeight)), data, cfg, cfg.steps, cfg.lr, k1)
    codes = np.asarray(codes_of(model))
    for rbf, precision in model.rbf_start():
        rbf.place(codes, cfg.bandwidth, precision, cfg.seed)
    model.stage[...] = jnp.asarray(2)
    stage2 = _train(model, RBFWeight, data, cfg, cfg.rbf_steps, cfg.rbf_lr, k2)
    return {"stage1": stage1, "stage2": stage2, "codes": codes}


def fit_task(x: np.ndarray, q: np.ndarray, cfg: VAEConfig = VAEConfig()) -> tuple[TaskVAE, dict]:
    """Train a task-space VAE on positions (n, 3) and unit quaternions (n, 4) plus their antipodal copies (§3.1.2); the
    decoder's target is each copy itself (cfg.antipodal, eq. 17) or the quaternion on its set's hemisphere (eq. 15)."""
    x, q = np.asarray(x, np.float32), np.asarray(q, np.float32)
    _check(x, "positions", 3), _check(q, "quaternions", 4)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    if not cfg.antipodal:
        q = hemisphere(q)
    x2, q2 = np.concatenate([x, x]), np.concatenate([q, -q])
    target = q2 if cfg.antipodal else np.concatenate([q, q])
    model = TaskVAE(cfg, x.mean(0), np.full(3, x.std(0).max() + 1e-6), rngs=nnx.Rngs(cfg.seed))
    log = fit(model, (jnp.asarray(x2), jnp.asarray(q2), jnp.asarray(target)), cfg, lambda m: m.encode(x2, q2)[0])
    return model, log


def fit_joint(robot, theta: np.ndarray, cfg: VAEConfig = VAEConfig(), tcp: str = "panda_tcp") -> tuple[JointVAE, dict]:
    """Train a joint-space VAE with the robot's FK layer on configurations (n, dof)."""
    theta = np.asarray(theta, np.float32)
    _check(theta, "configurations", robot.dof)
    model = JointVAE(cfg, robot, theta.mean(0), theta.std(0) + 1e-3, tcp, rngs=nnx.Rngs(cfg.seed))
    log = fit(model, (jnp.asarray(theta),), cfg, lambda m: m.encode(theta)[0])
    return model, log


def hemisphere(q: np.ndarray, limit_deg: float = 80.0) -> np.ndarray:
    """Unit quaternions (n, 4) with the sign that puts them on the hemisphere of their principal axis (the leading
    eigenvector of sum q q^T, the mean orientation). Refuses a set with a quaternion more than `limit_deg` from that
    axis (a rotation beyond 2 limit_deg from the mean), which no hemisphere holds away from its rim."""
    axis = _principal_axis(q)
    dots = q @ axis
    if np.min(np.abs(dots)) < np.cos(np.deg2rad(limit_deg)):
        raise ValueError(
            f"quaternions: orientations spread more than {2 * limit_deg:.0f} degrees of rotation from their mean; "
            "train with vae.antipodal=true (the antipodal vMF mixture)"
        )
    return np.where(dots[:, None] < 0, -q, q).astype(np.float32)


def _principal_axis(q: np.ndarray) -> np.ndarray:
    """The leading eigenvector of sum q q^T, signed towards the set's majority."""
    axis = np.linalg.eigh(q.T.astype(np.float64) @ q)[1][:, -1]
    return axis if np.sum(q @ axis) >= 0 else -axis


def _check(a: np.ndarray, what: str, width: int) -> None:
    if a.ndim != 2 or a.shape[1] != width:
        raise ValueError(f"{what}: expected an array of shape (n, {width}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: contains NaN or inf")


def save(path: str | Path, model, cfg: VAEConfig, meta: dict | None = None) -> None:
    """Write a trained skill (its whole state and how to rebuild it) to one msgpack file."""
    kind = "joint" if isinstance(model, JointVAE) else "task"
    head = {"kind": kind, "cfg": dataclasses.asdict(cfg), **(meta or {})}
    data = {"head": json.dumps(head), "state": to_flat(nnx.to_pure_dict(nnx.state(model)))}
    Path(path).write_bytes(serialization.msgpack_serialize(data))


def load(path: str | Path, robot=None):
    """(model, head) from `save`; a joint-space skill needs the robot it was trained on (head["robot"])."""
    try:
        data = serialization.msgpack_restore(Path(path).read_bytes())
        head = json.loads(data["head"])
    except (OSError, ValueError, KeyError) as e:
        raise ValueError(f"cannot read skill file {path}: {e}") from e
    cfg = VAEConfig(**head["cfg"])
    if head["kind"] == "joint":
        if robot is None:
            raise ValueError(f"{path} holds a joint-space skill: pass the robot ({head.get('robot', 'unknown')})")
        n = robot.dof
        model = JointVAE(cfg, robot, np.zeros(n), np.ones(n), head.get("frame", "panda_tcp"), rngs=nnx.Rngs(0))
    else:
        model = TaskVAE(cfg, np.zeros(3), np.ones(3), rngs=nnx.Rngs(0))
    state = nnx.state(model)
    nnx.replace_by_pure_dict(state, from_flat(data["state"]))
    nnx.update(model, state)
    return model, head
