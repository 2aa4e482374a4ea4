"""Repulsion between the robot's own links (thesis §3.3.3), batched with the arms minor on CPUs."""

from __future__ import annotations

import functools
from typing import Callable

import jax
import jax.numpy as jnp

from fabrax.fabrics.terms.base import Contribution, Term, TermInputs, _params, _spheres
from fabrax.fabrics.terms.distance import _check_resolution, _distance_defaults, _pulled_pairs
from fabrax.robot.collision import closest_minor, closest_one, search_tables
from fabrax.soa import batch_minor, cross0, dot0


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


def use_arms_minor(option: bool | None) -> bool:
    """Whether batched self-collision runs with the arms as the minor axis (`_self_collision_fn`),
    read at trace time: the term's `arms_minor` option, or where it is None, on the CPU backend only
    (the layout is for XLA's CPU vectorisation; it is not measured on a GPU or TPU)."""
    return jax.default_backend() == "cpu" if option is None else bool(option)


@functools.lru_cache(maxsize=None)
def _self_collision_fn(revolute: tuple, link: bool, arms_minor: bool | None = None):
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
        i, j = closest_one(jax.lax.stop_gradient(x), radius, pi, pj, groups, gmask, lgroups, lgmask) if link else (pi, pj)
        rows = lambda n: [dot0(jac[:, a][:, i] - jac[:, a][:, j], n) for a in range(jac.shape[1])]  # noqa: E731
        return _pairs_contribution(p, x[:, i], x[:, j], xd[:, i] - xd[:, j], jdqd[:, i] - jdqd[:, j], radius[i] + radius[j], rows)

    def minor(p, x, xd, jdqd, axes, origins, jac, radius, pi, pj, groups, gmask, lgroups, lgmask, ancestors, fi, fj):
        xt = batch_minor(x)  # (3, S, B)
        if link:
            i, j = closest_minor(jax.lax.stop_gradient(xt), radius, pi, pj, groups, gmask, lgroups, lgmask)  # (P, B)
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
        if not use_arms_minor(arms_minor) or any(batched[7:]) or not any(batched[1:7]):  # off, robots batched, or only the parameters: per arm
            axes = (jax.tree.map(lambda b: 0 if b else None, batched[0]),) + tuple(0 if b else None for b in batched[1:])
            out = jax.vmap(one, in_axes=axes, axis_size=axis_size)(p, *arrays)
        else:
            kin = [a if b else jnp.broadcast_to(a, (axis_size,) + a.shape) for a, b in zip(arrays[:6], batched[1:7])]
            out = minor(p, *kin, *arrays[6:])
        return out, jax.tree.map(lambda _: True, out)

    return fn


def self_collision(name: str = "self_collision", resolution: str = "link", arms_minor: bool | None = None, **overrides) -> Term:
    """Repulsion between the robot's own links (thesis §3.3.3), x = |p_i - p_j| - r_i - r_j.

    resolution="link": one distance per pair of links, the thesis' link-to-link
    distance, measured by their closest checked sphere pair
    (`closest_link_pairs`); "sphere": every checked sphere pair. Each distance
    pulls back through both spheres: u = J_i^T n - J_j^T n, M = sum m u u^T (`_pair_rows`).
    `arms_minor` (static): the batched layout of `_self_collision_fn`; None picks it by backend
    (experiments/bench_arms_minor.py measures both).
    """
    if arms_minor not in (None, True, False):
        raise ValueError(f"fabric term '{name}': arms_minor must be true, false or null, got {arms_minor!r}")
    _check_resolution(resolution, name)
    init = _params(_distance_defaults(), overrides, name)

    def apply(p, inp: TermInputs) -> Contribution:
        kin, robot = inp.points, inp.robot
        link = resolution == "link" and robot.collision.pair_i.shape[0] > 0
        fi, fj = robot.collision.frame[robot.collision.pair_i], robot.collision.frame[robot.collision.pair_j]  # every row's two frames
        if link:  # one row per link pair: the frames of any of its pairs
            first = robot.collision.pair_groups[robot.collision.link_pair_groups[:, 0], 0]
            fi, fj = fi[first], fj[first]
        fn = _self_collision_fn(robot.joint_revolute, link, arms_minor)
        return fn(p, kin.x, kin.xd, kin.jdqd, kin.axes, kin.origins, kin.jac, *search_tables(robot.collision), robot.ancestors, fi, fj)

    return Term(name, init, apply, _spheres)
