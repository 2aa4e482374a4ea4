"""The fabric term library for arms (thesis §3.3; gfcs_paper §III).

A `Term` is a pair of pure functions in the spirit of an optax transform:
`init()` gives its default parameters (a pytree of arrays) and
`apply(params, inputs)` its `Contribution` in configuration space. Each term
may ask for task points (collision spheres, end-effector keypoints); the
fabric computes the kinematics of all requested points in one pass.

Every term follows the transform-tree recipe (eqs. 2.55-2.59): a Finsler
energy L_e and an HD2 geometry h2 in the term's task space are pulled back as
(J^T M_e J, J^T M_e (h2 + Jdot qd)) together with the pulled-back energy force
J^T (f_e + M_e Jdot qd); forcing potentials enter as J^T dpsi/dx (eq. 2.60).
Distance terms reduce all obstacles of a sphere to a 3x3 metric and a
3-vector before one pullback per sphere.
"""

from __future__ import annotations

import functools
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct

from fabrax.fabrics import energies as E
from fabrax.fabrics.lagrangian import eom, eom_elementwise, hd2_geometry
from fabrax.gains import check_value
from fabrax.robot.kinematics import PointKinematics
from fabrax.robot.robot import Robot
from fabrax.scene import FAR, Scene, distance_kinematics
from fabrax.scene.sdf import argmin_packed, min_packed, nearest_distance
from fabrax.soa import batch_minor, cross0, dot0, matvec, matvec0


@struct.dataclass
class Contribution:
    """A term's share of the configuration-space fabric."""

    M: jax.Array  # (n, n) pulled-back metric of the term's Finsler energy
    f_geom: jax.Array  # (n,) J^T M_e (h2 + Jdot qd)           eq. 2.55
    f_energy: jax.Array  # (n,) J^T (f_e + M_e Jdot qd)        eq. 2.51
    f_force: jax.Array  # (n,) J^T dpsi/dx of forcing potentials  eq. 2.60
    damping: jax.Array  # (n, n) B
    energy: jax.Array  # () Hamiltonian of L_e (eq. 2.11)
    potential: jax.Array  # () forcing potential psi
    clearance: jax.Array = FAR  # () smallest distance a repulsion term saw (m)

    @staticmethod
    def zeros(n: int, dtype=jnp.float32) -> "Contribution":
        z = jnp.zeros((), dtype)
        return Contribution(
            jnp.zeros((n, n), dtype), jnp.zeros(n, dtype), jnp.zeros(n, dtype), jnp.zeros(n, dtype), jnp.zeros((n, n), dtype), z, z, z + FAR
        )

    def __add__(self, other: "Contribution") -> "Contribution":
        total = jax.tree.map(jnp.add, self, other)
        return total.replace(clearance=jnp.minimum(self.clearance, other.clearance))


class TermInputs(NamedTuple):
    q: jax.Array
    qd: jax.Array
    points: PointKinematics | None  # kinematics of the points the term asked for
    scene: Scene
    robot: Robot


class Term(NamedTuple):
    name: str
    init: Callable[[], dict[str, Any]]
    apply: Callable[[dict[str, Any], TermInputs], Contribution]
    points: Callable[[Robot], tuple[str, jax.Array, jax.Array]] | None = None  # (key, frame (N,), local (N, 3))


def _params(defaults: dict[str, Any], overrides: dict[str, Any], name: str) -> Callable[[], dict[str, Any]]:
    unknown = set(overrides) - set(defaults)
    if unknown:
        raise ValueError(f"fabric term '{name}': unknown parameters {sorted(unknown)} (known: {sorted(defaults)})")
    for key, value in overrides.items():
        check_value(name, key, value, scalar=np.ndim(defaults[key]) == 0)
    merged = {**defaults, **overrides}
    return lambda: {k: jnp.asarray(v, jnp.float32) for k, v in merged.items()}


SPHERE_LANES = 16  # the spheres' point set is padded to a multiple of this many points (`_spheres`)


def _spheres(robot: Robot):
    """The collision spheres as a point set, padded to a multiple of SPHERE_LANES with copies of
    sphere 0 that the obstacle term masks (`_sphere_gaps`). XLA on CPU vectorises the per-sphere
    arithmetic (the scene search, the pullbacks) along the spheres, 16 float32 lanes at a time, and
    runs a remainder as scalar code, which the padding avoids."""
    extra = -robot.n_spheres % SPHERE_LANES if robot.n_spheres else 0
    pad = lambda a: jnp.concatenate([a, jnp.broadcast_to(a[:1], (extra,) + a.shape[1:])])  # noqa: E731
    return "spheres", pad(robot.sphere_frame), pad(robot.sphere_local)


def _sphere_gaps(robot: Robot, d: jax.Array, margin: jax.Array) -> jax.Array:
    """d - r - margin for distances d (..., N) of the padded sphere set (`_spheres`); FAR for the
    padding, beyond every term's reach, so that its metric, forces and energies are exactly 0."""
    n = robot.n_spheres
    radius = jnp.concatenate([robot.sphere_radius, jnp.zeros(d.shape[-1] - n, d.dtype)])
    return jnp.where(jnp.arange(d.shape[-1]) < n, d - radius - margin, FAR)


# ---------------------------------------------------------------------------- joint space


def joint_attractor(name: str = "joint_attractor", n: int = 7, **overrides) -> Term:
    """Joint-space attractor (thesis §3.3.2): geometry qdd = -|qd|^2 dpsi_g/dq, energy m(q)/2 |qd|^2,
    forcing psi = k_force log cosh(alpha_force |q - q_d|) and extra damping near the target.

    The isotropic mass is `mass` at the target and `mass_far` far from it (the tanh profile of the
    end-effector attractor's energy, §3.3.1; default mass_far = mass, the thesis' constant m). A
    posture with mass_far > mass leads the arm's shape from afar and hands over near its target.
    `weight` (0 or 1) switches the attraction (geometry, forcing, damping) while the mass stays,
    so the fabric's metric keeps full rank. `target` is the goal or command q_d (GFCS) or a posture.
    """
    overrides.setdefault("mass_far", overrides.get("mass", 1.0))
    defaults = dict(
        target=np.zeros(n),
        weight=1.0,
        mass=1.0,
        mass_far=1.0,
        alpha_mass=1.0,
        k_geometry=2.0,
        alpha_geometry=5.0,
        k_force=10.0,
        alpha_force=5.0,
        b_goal=5.0,
        alpha_damping=5.0,
    )
    init = _params(defaults, overrides, name)

    def apply(p, inp: TermInputs) -> Contribution:
        r = inp.q - p["target"]
        energy = lambda r_, rd: E.attractor_energy(r_, rd, p["mass"], p["mass_far"], p["alpha_mass"])  # noqa: E731
        M, fe, H = eom(energy, r, inp.qd)
        h2 = hd2_geometry(lambda r_: E.attractor_potential(r_, p["k_geometry"], p["alpha_geometry"]))(r, inp.qd)
        psi, dpsi = jax.value_and_grad(E.attractor_potential)(r, p["k_force"], p["alpha_force"])
        b = p["b_goal"] * (1.0 - jnp.tanh(p["alpha_damping"] * E.safe_norm(r)))
        w = p["weight"]
        return Contribution(M, w * matvec(M, h2), fe, w * dpsi, w * b * jnp.eye(r.shape[0], dtype=r.dtype), H, w * psi)

    return Term(name, init, apply)


def joint_limits(name: str = "joint_limits", **overrides) -> Term:
    """Distance-space repulsion from both limits of every joint (thesis §3.3.3, x = q - lower, upper - q)."""
    defaults = dict(
        k_metric=0.2, sigma=0.05, reach=0.3, k_barrier=0.5, k_soft=0.5, soft_width=0.03, x0=0.05, floor=1e-3, k_force=0.05, force_reach=0.1
    )
    init = _params(defaults, overrides, name)

    def apply(p, inp: TermInputs) -> Contribution:
        lo, hi = inp.robot.lower, inp.robot.upper
        finite = jnp.isfinite(lo) & jnp.isfinite(hi)
        x = jnp.stack([inp.q - jnp.where(finite, lo, -1e3), jnp.where(finite, hi, 1e3) - inp.q])  # (2, n)
        sign = jnp.array([1.0, -1.0], inp.q.dtype)[:, None]
        xd = sign * inp.qd
        m, fe, h, h2, dpsi, psi = _distance_terms(p, x, xd)
        m, fe, h2 = m * finite, fe * finite, h2 * finite
        diag = jnp.sum(m, 0)
        return Contribution(
            jnp.diag(diag),
            jnp.sum(sign * m * h2, 0),
            jnp.sum(sign * fe, 0),
            jnp.sum(sign * dpsi * finite, 0),
            jnp.zeros((inp.q.shape[0],) * 2, inp.q.dtype),
            jnp.sum(h * finite),
            jnp.sum(psi * finite),
        )

    return Term(name, init, apply)


def damping(name: str = "damping", **overrides) -> Term:
    """Damping B qd with speed control: B = (b + k_drag |qd|^2) I plus a brake on every joint above eta of its velocity limit.

    The quadratic drag bounds the cruise speed (terminal speed ~ (force / k_drag)^(1/3))
    without slowing the final approach, where the attractors' own near-goal
    damping settles the arm; a large constant b would make convergence crawl
    along directions the task barely moves.
    """
    defaults = dict(b=0.5, k_drag=4.0, k_speed=20.0, eta=0.8, sharpness=20.0)
    init = _params(defaults, overrides, name)

    def apply(p, inp: TermInputs) -> Contribution:
        ratio = jnp.abs(inp.qd) / inp.robot.velocity
        brake = p["k_speed"] * jax.nn.softplus(p["sharpness"] * (ratio - p["eta"])) / p["sharpness"]
        c = Contribution.zeros(inp.q.shape[0], inp.q.dtype)
        return c.replace(damping=jnp.diag(p["b"] + p["k_drag"] * jnp.sum(inp.qd * inp.qd) + brake))

    return Term(name, init, apply)


# ---------------------------------------------------------------------------- task-space points


def ee_attractor(name: str = "ee_attractor", frame: str = "panda_hand", offsets=((0, 0, 0.1), (0.1, 0, 0.1), (0, 0.1, 0.1)), **overrides) -> Term:
    """End-effector pose attractor on three non-collinear points of `frame` (thesis §3.3.1).

    Per point: geometry xdd = -|xd|^2 dpsi_g/dx, energy 1/2 m(x)|xd|^2 with the
    tanh-shaped mass, forcing psi = k_force log cosh(alpha_force |x - x_d|). Targets are the
    same points on the goal pose (`target_pos`, `target_quat` wxyz). `point_weights`
    selects points: (1, 0, 0) attracts position only.
    """
    offsets = np.asarray(offsets, np.float32)
    defaults = dict(
        target_pos=np.zeros(3),
        target_quat=np.array([1.0, 0, 0, 0]),
        weight=1.0,
        point_weights=np.ones(len(offsets)),
        m_hi=2.0,
        m_lo=0.2,
        alpha_mass=10.0,
        k_geometry=5.0,
        alpha_geometry=10.0,
        k_force=10.0,
        alpha_force=10.0,
        b_goal=5.0,
        alpha_damping=10.0,
    )
    init = _params(defaults, overrides, name)

    def points(robot: Robot):
        i = robot.frame_index(frame)
        local = jnp.asarray(offsets) @ robot.frame_offset_r[i].T + robot.frame_offset_t[i]
        return f"{name}:{frame}", jnp.full((len(offsets),), robot.frame_parent[i]), local

    def apply(p, inp: TermInputs) -> Contribution:
        kin = inp.points
        target = jaxlie.SO3(p["target_quat"] / jnp.linalg.norm(p["target_quat"])).apply(jnp.asarray(offsets)) + p["target_pos"]
        x, xd, jac, jdqd = kin.x.T, kin.xd.T, kin.jac.transpose(2, 0, 1), kin.jdqd.T  # few points: (K, 3), (K, 3, n)
        r = x - target
        w = p["weight"] * p["point_weights"]
        energy = lambda r_, rd: E.attractor_energy(r_, rd, p["m_hi"], p["m_lo"], p["alpha_mass"])  # noqa: E731
        M, fe, H = jax.vmap(lambda r_, rd: eom(energy, r_, rd))(r, xd)
        h2 = jax.vmap(hd2_geometry(lambda r_: E.attractor_potential(r_, p["k_geometry"], p["alpha_geometry"])))(r, xd)
        psi, dpsi = jax.vmap(jax.value_and_grad(E.attractor_potential), in_axes=(0, None, None))(r, p["k_force"], p["alpha_force"])
        b = p["b_goal"] * (1.0 - jnp.tanh(p["alpha_damping"] * E.safe_norm(r)))  # (K,)
        # contractions as broadcasts and sums over the few (point, axis) rows: XLA fuses them, where
        # einsums became a small matrix product each
        mj = sum(M[:, :, c, None] * jac[:, None, c] for c in range(3))  # (K, 3, n): M J per point
        ma = sum(M[:, :, c] * jdqd[:, c, None] for c in range(3))  # (K, 3)
        rows = jac.reshape(-1, jac.shape[-1])  # (3K, n)

        def pull(v):  # J^T v over all points, v (K, 3)
            return jnp.sum(rows * v.reshape(-1, 1), axis=0)

        return Contribution(
            jnp.sum(rows[:, :, None] * mj.reshape(rows.shape)[:, None, :], axis=0),
            pull(w[:, None] * (sum(M[:, :, c] * h2[:, c, None] for c in range(3)) + ma)),
            pull(fe + ma),
            pull(w[:, None] * dpsi),
            jnp.sum((jnp.repeat(w * b, 3)[:, None] * rows)[:, :, None] * rows[:, None, :], axis=0),
            jnp.sum(H),
            jnp.sum(w * psi),
        )

    return Term(name, init, apply, points)


# ---------------------------------------------------------------------------- distance space


def _distance_terms(p, x, xd, vt2=None):
    """Elementwise over distances x with rates xd and squared tangential speeds vt2: metric m, energy
    force f_e, energy H, geometry h2, forcing dpsi_f/dx and psi_f (thesis §3.3.3).

    The geometry is xdd = -(xd^2 + k_slide vt2) dpsi/dx: the thesis' xd^2 dpsi/dx plus a push
    by the speed along the surface, so that a body point sliding past an obstacle is pushed
    off it too (vt2 = |v|^2 - xd^2 of the body point, HD2 in qd like xd^2; None for 1-D distances)."""
    energy = lambda x_, xd_: E.gated_barrier_energy(x_, xd_, p["k_metric"], p["sigma"], p["reach"], p["floor"])  # noqa: E731
    m, fe, h = eom_elementwise(energy, x, xd)
    geometry = lambda x_: E.barrier_potential(x_, p["k_barrier"], p["k_soft"], p["soft_width"], p["x0"], p["reach"], p["floor"])  # noqa: E731
    dpsi_g = jax.grad(lambda x_: jnp.sum(geometry(x_)))(x)
    # the forcing copy of the barrier (thesis: "weighted significantly less") is also shorter-ranged,
    # so that it only acts where the geometry alone would let the arm touch
    forcing = lambda x_: p["k_force"] * E.barrier_potential(x_, p["k_barrier"], 0.0, p["soft_width"], p["x0"], p["force_reach"], p["floor"])  # noqa: E731
    psi, dpsi = forcing(x), jax.grad(lambda x_: jnp.sum(forcing(x_)))(x)
    speed2 = xd * xd if vt2 is None else xd * xd + p["k_slide"] * vt2
    return m, fe, h, speed2 * dpsi_g, dpsi, psi


def _distance_defaults():
    return dict(
        margin=0.0,
        k_metric=0.5,
        sigma=0.02,
        reach=0.25,
        k_barrier=0.2,
        k_soft=0.5,
        soft_width=0.025,
        x0=0.03,
        floor=2e-3,
        k_force=0.1,
        force_reach=0.05,
        k_slide=0.0,
    )


_SYM3 = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]


def _reduce(sums: list[jax.Array], mins: list[jax.Array] = (), axis: int = 0) -> tuple[list, list]:
    """Sums and minima of equally shaped arrays over one axis, in a single variadic reduction.

    One reduce shares the arithmetic that produces its operands (per-pair
    distances and energies) among all outputs; separate reductions would each
    fuse, and so recompute, that arithmetic.
    """
    ops = tuple(sums) + tuple(mins)
    k = len(sums)
    init = tuple(jnp.zeros((), o.dtype) for o in sums) + tuple(jnp.full((), FAR, o.dtype) for o in mins)

    def combine(a, b):
        return tuple(x + y for x, y in zip(a[:k], b[:k])) + tuple(jnp.minimum(x, y) for x, y in zip(a[k:], b[k:]))

    out = jax.lax.reduce(ops, init, combine, (axis % ops[0].ndim,))
    return list(out[:k]), list(out[k:])


def _unpack_metric(d: int, values: list[jax.Array]) -> jax.Array:
    upper = [(a, b) for a in range(d) for b in range(a, d)]
    metric = [[None] * d for _ in range(d)]
    for (a, b), val in zip(upper, values):
        metric[a][b] = metric[b][a] = val
    return jnp.stack([jnp.stack(row) for row in metric])


def _metric_products(u: list[jax.Array], weight: jax.Array) -> list[jax.Array]:
    """weight u_a u_b for the upper triangle (a <= b) of a metric sum_k weight_k u_k u_k^T."""
    wu = [weight * ua for ua in u]
    return [wu[a] * u[b] for a in range(len(u)) for b in range(a, len(u))]


def _pull_spheres(kin: PointKinematics, m3, g3, e3, f3) -> tuple:
    """One pullback per sphere of its reduced 3-D spec (eq. 2.6); m3 (3, 3, N), vectors (3, N)."""
    mj = jnp.stack([sum(m3[c, d][None] * kin.jac[d] for d in range(3)) for c in range(3)])  # (3, n, N): M3 J per sphere
    ma = matvec0(m3, kin.jdqd)  # (3, N)
    n = kin.jac.shape[1]
    upper = [(a, b) for a in range(n) for b in range(a, n)]
    jt_m_j = [dot0(kin.jac[:, a], mj[:, b]) for a, b in upper]  # (N,) each
    pulled = [dot0(kin.jac[:, a], v) for v in (g3 + ma, e3 + ma, f3) for a in range(n)]
    sums, _ = _reduce(jt_m_j + pulled, axis=-1)
    rest = sums[len(upper) :]
    return _unpack_metric(n, sums[: len(upper)]), jnp.stack(rest[:n]), jnp.stack(rest[n : 2 * n]), jnp.stack(rest[2 * n :])


def _pulled_pairs(p, x, rate, curv, u: list[jax.Array], vt2: jax.Array) -> Contribution:
    """1-D distance specs x with rate, curvature term and squared tangential speed, pulled back through
    u_k = J_x^T (one vector per distance, as rows u[a] over the pairs): M = sum m u u^T,
    f = sum u (m (h2 + curv)), ...  (eqs. 2.55, 2.60)."""
    m, fe, h, h2, dpsi, psi = _distance_terms(p, x, rate, vt2)
    vectors = [m * (h2 + curv), fe + m * curv, dpsi]
    sums, (clear,) = _reduce(_metric_products(u, m) + [ua * v for v in vectors for ua in u] + [h, psi], [x + p["margin"]])
    d = len(u)
    nm = d * (d + 1) // 2
    M = _unpack_metric(d, sums[:nm])
    fg, fen, ff = (jnp.stack(sums[nm + k * d : nm + (k + 1) * d]) for k in range(3))
    return Contribution(M, fg, fen, ff, jnp.zeros_like(M), sums[-2], sums[-1], clear)


RESOLUTIONS = ("link", "sphere")


def _check_resolution(resolution: str, name: str) -> None:
    if resolution not in RESOLUTIONS:
        raise ValueError(f"fabric term '{name}': resolution must be one of {RESOLUTIONS}, got '{resolution}'")


def obstacle_repulsion(name: str = "obstacles", resolution: str = "scene", **overrides) -> Term:
    """Repulsion of every collision sphere from the scene (thesis §3.3.3).

    resolution="scene": one distance per sphere, to the scene as a whole (the
    signed distance of the union of primitives = the min over them); every
    (sphere, primitive) distance is evaluated, the energy and one pullback run
    per sphere through its Jacobian from the one kinematics pass.
    resolution="primitive": one distance per (sphere, primitive); the 1-D specs
    are reduced per sphere to a 3x3 metric and 3-vectors (sum n m n^T,
    sum n m (h2 + pd^T H pd), ...), then pulled back once per sphere. Several
    obstacles near one sphere all push, and nothing switches where two are
    equidistant, at several times the cost.
    """
    if resolution not in ("scene", "primitive"):
        raise ValueError(f"fabric term '{name}': resolution must be 'scene' or 'primitive', got '{resolution}'")
    init = _params(_distance_defaults(), overrides, name)

    def apply_sphere(p, inp: TermInputs) -> Contribution:
        kin = inp.points
        pd = distance_kinematics(inp.scene, kin.x, kin.xd)
        x = _sphere_gaps(inp.robot, pd.d, p["margin"])  # (K, N)
        m, fe, h, h2, dpsi, psi = _distance_terms(p, x, pd.rate, jnp.maximum(dot0(kin.xd, kin.xd)[None] - pd.rate * pd.rate, 0.0))
        n = pd.n
        wg, we = m * (h2 + pd.curv), fe + m * pd.curv
        per_pair = _metric_products([n[0], n[1], n[2]], m) + [n[c] * w for w in (wg, we, dpsi) for c in range(3)]
        sums, (clear,) = _reduce(per_pair + [h, psi], [x + p["margin"]])
        m3 = _unpack_metric(3, sums[:6])  # (3, 3, N)
        g3, e3, f3 = jnp.stack(sums[6:9]), jnp.stack(sums[9:12]), jnp.stack(sums[12:15])
        M, fg, fen, ff = _pull_spheres(kin, m3, g3, e3, f3)
        return Contribution(M, fg, fen, ff, jnp.zeros_like(M), jnp.sum(sums[15]), jnp.sum(sums[16]), jnp.min(clear))

    def apply_scene(p, inp: TermInputs) -> Contribution:
        kin, robot = inp.points, inp.robot
        near = nearest_distance(inp.scene, kin.x, kin.xd)
        x = _sphere_gaps(robot, near.d, p["margin"])
        curv = near.curv + dot0(near.n, kin.jdqd)  # Jdot qd of x: pd^T H pd + n . (Jdot qd)_sphere
        u = [dot0(kin.jac[:, a], near.n) for a in range(kin.jac.shape[1])]
        return _pulled_pairs(p, x, near.rate, curv, u, jnp.maximum(dot0(kin.xd, kin.xd) - near.rate * near.rate, 0.0))

    return Term(name, init, apply_scene if resolution == "scene" else apply_sphere, _spheres)


def closest_link_pairs(robot: Robot, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The closest checked sphere pair (i, j) of every checked pair of links, for sphere centres x (3, S).

    The checked pairs' gaps, grouped into chunks of at most 16 pairs of one link pair
    (`robot.pair_groups`): the closest pair of each chunk, then the closest chunk of each link pair,
    both by packed argmins (`scene.sdf.min_packed`, whose keys also give each chunk's minimum: a
    gather of it made XLA recompute the gaps). The gaps are computed in the chunks' layout
    (sphere indices composed at trace time): gathering per-pair gaps into chunks made XLA recompute
    each gap through two levels of indices. The work grows with the checked pairs alone: a dense
    search over all spheres of both links was slower, as XLA fused its minima into a gather that
    recomputed them per link pair. The self-collision term runs the same search arms-minor under
    `jax.vmap` (`_closest_minor`).
    """
    if robot.pair_i.shape[0] == 0:
        return robot.pair_i, robot.pair_j
    return _closest_one(jax.lax.stop_gradient(x), *_search_tables(robot))


def _search_tables(robot: Robot) -> tuple:
    return (
        robot.sphere_radius,
        robot.pair_i,
        robot.pair_j,
        robot.pair_groups,
        robot.pair_groups_mask,
        robot.link_pair_groups,
        robot.link_pair_groups_mask,
    )


def _closest_one(x, radius, i, j, groups, groups_mask, link_groups, link_groups_mask):
    gi, gj = i[groups], j[groups]  # (G, Q): the chunks' spheres, constants
    rel = x[:, gi] - x[:, gj]
    gap = jnp.sqrt(dot0(rel, rel)) - radius[gi] - radius[gj]
    grouped = jnp.where(groups_mask, gap, FAR)
    slot, smallest = min_packed(grouped)
    best = jnp.take_along_axis(groups, slot[:, None], -1)[:, 0]
    chunk_gap = jnp.where(link_groups_mask, smallest[link_groups], FAR)
    best = best[jnp.take_along_axis(link_groups, argmin_packed(chunk_gap)[:, None], -1)[:, 0]]
    return i[best], j[best]


def _closest_minor(xt, radius, i, j, groups, groups_mask, link_groups, link_groups_mask):
    """`_closest_one` of arms xt (3, S, B), the arms minor: the same operations and values, so the same
    pairs, as (LP, B) indices."""
    gi, gj = i[groups], j[groups]
    rel = xt[:, gi] - xt[:, gj]  # (3, G, Q, B): rows of arms
    gap = jnp.sqrt(dot0(rel, rel)) - (radius[gi] + radius[gj])[..., None]
    grouped = jnp.where(groups_mask[..., None], gap, FAR)
    slot, smallest = min_packed(grouped, axis=1, unroll=True)  # (G, B) each: rows of arms, minima of slices
    best = jnp.take_along_axis(jnp.broadcast_to(groups[..., None], grouped.shape), slot[:, None], 1)[:, 0]  # (G, B)
    chunk_gap = jnp.where(link_groups_mask[..., None], smallest[link_groups], FAR)  # (LP, C, B)
    rows = min_packed(chunk_gap, axis=1, unroll=True)[0][:, None]
    rows = jnp.take_along_axis(jnp.broadcast_to(link_groups[..., None], chunk_gap.shape), rows, 1)[:, 0]  # (LP, B)
    best = jnp.take_along_axis(best, rows, 0)
    return i[best], j[best]


def _pair_rows(revolute: tuple, only_i, only_j, z, zo, xi, xj, n) -> list[jax.Array]:
    """u_a = (J_i - J_j)[:, a]^T n of sphere pairs with centres xi, xj (3, P, ...) and unit normal n
    along x_i - x_j, one row per joint a, from the world joint axes z and z_a x o_a (3, n, ...) alone;
    only_i[a] / only_j[a]: joint a moves sphere i but not j / j but not i.

    A joint that moves both spheres moves them rigidly: z_a x (x_i - x_j) and z_a - z_a are normal
    to n, so its row is 0. Otherwise u_a = (z_a x (x_i - o_a)) . n = z_a . (x_i x n) - (z_a x o_a) . n
    for a revolute joint and z_a . n for a prismatic one (minus the same for j): no Jacobian
    columns gathered per pair."""
    xin, xjn = cross0(xi, n), cross0(xj, n)
    rows = []
    for a, rev in enumerate(revolute):
        za = z[:, a]
        if rev:
            t = dot0(zo[:, a], n)
            wi, wj = dot0(za, xin) - t, dot0(za, xjn) - t
        else:
            wi = wj = dot0(za, n)
        rows.append(jnp.where(only_i[a], wi, 0.0) - jnp.where(only_j[a], wj, 0.0))
    return rows


def _pairs_contribution(p, xi, xj, vij, aij, rij, rows: Callable[[jax.Array], list[jax.Array]]) -> Contribution:
    """The self-collision contribution of sphere pairs: centres xi, xj, relative velocity vij and
    curvature term aij (3, P, ...), radius sums rij (P, ...), rows(n) the pullback rows u_a (P, ...)
    for normals n; any trailing axes are batch axes."""
    rel = xi - xj
    dist = jnp.sqrt(dot0(rel, rel) + 1e-18)
    nrm = rel / dist
    rate = dot0(nrm, vij)
    curv = (dot0(vij, vij) - rate * rate) / dist + dot0(nrm, aij)
    return _pulled_pairs(p, dist - rij - p["margin"], rate, curv, rows(nrm), jnp.maximum(dot0(vij, vij) - rate * rate, 0.0))


ARMS_MINOR: bool | None = None  # self-collision under vmap with the arms minor: None = on the CPU backend only


def arms_minor() -> bool:
    """Whether batched self-collision runs with the arms as the minor axis (`_self_collision_fn`), read
    at trace time: `ARMS_MINOR`, or where it is None, on the CPU backend only (the layout is for XLA's
    CPU vectorisation; it is not measured on a GPU or TPU)."""
    return jax.default_backend() == "cpu" if ARMS_MINOR is None else bool(ARMS_MINOR)


@functools.lru_cache(maxsize=None)
def _self_collision_fn(revolute: tuple, link: bool):
    """The self-collision contribution of one arm, f(p, x, xd, jdqd, axes, origins, jac, *tables), whose
    `jax.vmap` runs with the arms as the minor axis (`jax.custom_batching.custom_vmap`).

    XLA on CPU vectorises along the minor axis, and `vmap` puts the arms major: per arm, the
    search gathered single floats and the pullback's sums over the pairs ran as scalar code.
    With the arms minor (centres transposed once, `soa.batch_minor`) the search gathers whole rows
    of arms, the sums add rows, and the rows u_a come from the joint axes (`_pair_rows`) rather
    than from Jacobian columns gathered per pair (experiments/bench_arms_minor.py measures both
    layouts). One arm, and derivatives (a custom_vmap
    has no reverse mode), keep the per-arm code.
    """

    def one(p, x, xd, jdqd, axes, origins, jac, radius, pi, pj, groups, gmask, lgroups, lgmask, ancestors, fi, fj):
        i, j = _closest_one(jax.lax.stop_gradient(x), radius, pi, pj, groups, gmask, lgroups, lgmask) if link else (pi, pj)
        rows = lambda n: [dot0(jac[:, a][:, i] - jac[:, a][:, j], n) for a in range(jac.shape[1])]  # noqa: E731
        return _pairs_contribution(p, x[:, i], x[:, j], xd[:, i] - xd[:, j], jdqd[:, i] - jdqd[:, j], radius[i] + radius[j], rows)

    def minor(p, x, xd, jdqd, axes, origins, jac, radius, pi, pj, groups, gmask, lgroups, lgmask, ancestors, fi, fj):
        xt = batch_minor(x)  # (3, S, B)
        if link:
            i, j = _closest_minor(jax.lax.stop_gradient(xt), radius, pi, pj, groups, gmask, lgroups, lgmask)  # (P, B)
        else:
            i, j = jnp.broadcast_to(pi[:, None], (pi.shape[0], x.shape[0])), jnp.broadcast_to(pj[:, None], (pj.shape[0], x.shape[0]))
        arm = jnp.arange(x.shape[0])

        def take(a, k):  # a (B, 3, S) at k (P, B) -> (3, P, B), gathered from the arms-major array: XLA
            return jnp.moveaxis(a[arm, :, k], -1, 0)  # then computes a (e.g. Jdot qd) only at the picked spheres

        mi, mj = ancestors[fi].T[..., None], ancestors[fj].T[..., None]  # (n, P, 1)
        z = batch_minor(axes)[:, :, None]  # (3, n, 1, B)
        zo = batch_minor(jnp.cross(axes, origins, axis=1))[:, :, None]
        xi, xj = take(x, i), take(x, j)
        rows = lambda n: _pair_rows(revolute, mi & ~mj, mj & ~mi, z, zo, xi, xj, n)  # noqa: E731
        c = _pairs_contribution(p, xi, xj, take(xd, i) - take(xd, j), take(jdqd, i) - take(jdqd, j), radius[i] + radius[j], rows)
        return jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0), c)  # the arms back to the front

    fast = jax.custom_batching.custom_vmap(one)
    fn = jax.custom_jvp(fast)
    fn.defjvp(lambda primals, tangents: jax.jvp(one, primals, tangents))  # derivatives: the per-arm code

    @fast.def_vmap
    def _(axis_size, batched, p, *arrays):
        if not arms_minor() or any(batched[7:]) or not any(batched[1:7]):  # off, robots batched, or only the parameters: per arm
            axes = (jax.tree.map(lambda b: 0 if b else None, batched[0]),) + tuple(0 if b else None for b in batched[1:])
            out = jax.vmap(one, in_axes=axes, axis_size=axis_size)(p, *arrays)
        else:
            kin = [a if b else jnp.broadcast_to(a, (axis_size,) + a.shape) for a, b in zip(arrays[:6], batched[1:7])]
            out = minor(p, *kin, *arrays[6:])
        return out, jax.tree.map(lambda _: True, out)

    return fn


def self_collision(name: str = "self_collision", resolution: str = "link", **overrides) -> Term:
    """Repulsion between the robot's own links (thesis §3.3.3), x = |p_i - p_j| - r_i - r_j.

    resolution="link": one distance per pair of links, the thesis' link-to-link
    distance, measured by their closest checked sphere pair
    (`closest_link_pairs`); "sphere": every checked sphere pair. Each distance
    pulls back through both spheres: u = J_i^T n - J_j^T n, M = sum m u u^T (`_pair_rows`).
    """
    _check_resolution(resolution, name)
    init = _params(_distance_defaults(), overrides, name)

    def apply(p, inp: TermInputs) -> Contribution:
        kin, robot = inp.points, inp.robot
        link = resolution == "link" and robot.pair_i.shape[0] > 0
        fi, fj = robot.sphere_frame[robot.pair_i], robot.sphere_frame[robot.pair_j]  # every row's two frames
        if link:  # one row per link pair: the frames of any of its pairs
            first = robot.pair_groups[robot.link_pair_groups[:, 0], 0]
            fi, fj = fi[first], fj[first]
        fn = _self_collision_fn(robot.joint_revolute, link)
        return fn(p, kin.x, kin.xd, kin.jdqd, kin.axes, kin.origins, kin.jac, *_search_tables(robot), robot.ancestors, fi, fj)

    return Term(name, init, apply, _spheres)


TERMS = {
    "joint_attractor": joint_attractor,
    "joint_limits": joint_limits,
    "damping": damping,
    "ee_attractor": ee_attractor,
    "obstacle_repulsion": obstacle_repulsion,
    "self_collision": self_collision,
}
