"""The exact checker's state clearances compiled by numba, for callers that check one state or one
edge at a time (OMPL's validity callbacks), where a JAX dispatch per call would cost more than the
check itself.

The same collision spheres, self-collision pairs, primitives and joint limits as
`fabrax.check.clearance.state_clearances` (tested equal on random states):
forward kinematics by the same joint-by-joint composition (Rodrigues' formula
for revolute joints), then each sphere's signed distance to every primitive
(box: |max(q, 0)| + min(max q, 0) with q = |R^T (x - c)| - h; solid cylinder:
the same in (rho - r, |z| - h); sphere and cloud point: |x - c| - r) minus its
radius, and every self pair's centre distance minus both radii.
"""

from __future__ import annotations

import numba
import numpy as np

from fabrax.robot.robot import Robot
from fabrax.scene import Scene
from fabrax.scene.sdf import FAR


@numba.njit(cache=True)
def _one(q, robot, scene, tol, scratch, early):
    """(env clearance, self clearance, within limits) of one configuration (scratch: `_scratch`).
    early: only the signs matter, so the first collision ends the check (its clearance -1) and
    primitives whose bounding sphere a collision sphere clears are skipped."""
    axis, origin_r, origin_t, revolute, parent, frame, local, radius, pair_i, pair_j, lower, upper = robot
    bc, br, bh, bb, cc, cr, crad, ch, cb, sc, srad = scene
    rs, ts, x, m, lr, k, mt, lt = scratch
    n = q.shape[0]
    ok = True
    for i in range(n):
        ok = ok and lower[i] - tol <= q[i] <= upper[i] + tol
    if early and not ok:
        return -1.0, -1.0, False
    rs[0] = np.eye(3)
    ts[0] = 0.0
    for i in range(n):
        a = axis[i]
        if revolute[i]:
            s, c = np.sin(q[i]), np.cos(q[i])
            aa = a[0] * a[0] + a[1] * a[1] + a[2] * a[2]
            k[0, 1], k[0, 2], k[1, 0], k[1, 2], k[2, 0], k[2, 1] = -a[2], a[1], a[2], -a[0], -a[1], a[0]  # the skew matrix of a
            for r in range(3):
                for col in range(3):
                    kk = a[r] * a[col] - (aa if r == col else 0.0)  # K K = a a^T - |a|^2 I
                    m[r, col] = (1.0 if r == col else 0.0) + s * k[r, col] + (1.0 - c) * kk
                mt[r] = 0.0
        else:
            for r in range(3):
                for col in range(3):
                    m[r, col] = 1.0 if r == col else 0.0
                mt[r] = a[r] * q[i]
        for r in range(3):
            for col in range(3):
                lr[r, col] = origin_r[i, r, 0] * m[0, col] + origin_r[i, r, 1] * m[1, col] + origin_r[i, r, 2] * m[2, col]
            lt[r] = origin_r[i, r, 0] * mt[0] + origin_r[i, r, 1] * mt[1] + origin_r[i, r, 2] * mt[2] + origin_t[i, r]
        p = parent[i] + 1
        for r in range(3):
            for col in range(3):
                rs[i + 1, r, col] = rs[p, r, 0] * lr[0, col] + rs[p, r, 1] * lr[1, col] + rs[p, r, 2] * lr[2, col]
            ts[i + 1, r] = rs[p, r, 0] * lt[0] + rs[p, r, 1] * lt[1] + rs[p, r, 2] * lt[2] + ts[p, r]
    for j in range(frame.shape[0]):
        f = frame[j]
        for r in range(3):
            x[j, r] = rs[f, r, 0] * local[j, 0] + rs[f, r, 1] * local[j, 1] + rs[f, r, 2] * local[j, 2] + ts[f, r]
    env = np.inf
    for j in range(frame.shape[0]):
        d = FAR
        for b in range(bc.shape[0]):
            if early:
                dx, dy, dz = x[j, 0] - bc[b, 0], x[j, 1] - bc[b, 1], x[j, 2] - bc[b, 2]
                if dx * dx + dy * dy + dz * dz > (bb[b] + radius[j]) ** 2:
                    continue
            qmax, out = -np.inf, 0.0
            for i in range(3):
                pl = br[b, 0, i] * (x[j, 0] - bc[b, 0]) + br[b, 1, i] * (x[j, 1] - bc[b, 1]) + br[b, 2, i] * (x[j, 2] - bc[b, 2])
                qi = abs(pl) - bh[b, i]
                qmax = max(qmax, qi)
                out += max(qi, 0.0) ** 2
            d = min(d, np.sqrt(out) + min(qmax, 0.0))
        for b in range(cc.shape[0]):
            if early:
                dx, dy, dz = x[j, 0] - cc[b, 0], x[j, 1] - cc[b, 1], x[j, 2] - cc[b, 2]
                if dx * dx + dy * dy + dz * dz > (cb[b] + radius[j]) ** 2:
                    continue
            pl0 = cr[b, 0, 0] * (x[j, 0] - cc[b, 0]) + cr[b, 1, 0] * (x[j, 1] - cc[b, 1]) + cr[b, 2, 0] * (x[j, 2] - cc[b, 2])
            pl1 = cr[b, 0, 1] * (x[j, 0] - cc[b, 0]) + cr[b, 1, 1] * (x[j, 1] - cc[b, 1]) + cr[b, 2, 1] * (x[j, 2] - cc[b, 2])
            pl2 = cr[b, 0, 2] * (x[j, 0] - cc[b, 0]) + cr[b, 1, 2] * (x[j, 1] - cc[b, 1]) + cr[b, 2, 2] * (x[j, 2] - cc[b, 2])
            ra = np.sqrt(pl0 * pl0 + pl1 * pl1) - crad[b]
            rb = abs(pl2) - ch[b]
            d = min(d, np.sqrt(max(ra, 0.0) ** 2 + max(rb, 0.0) ** 2) + min(max(ra, rb), 0.0))
        for b in range(sc.shape[0]):
            dx, dy, dz = x[j, 0] - sc[b, 0], x[j, 1] - sc[b, 1], x[j, 2] - sc[b, 2]
            d = min(d, np.sqrt(dx * dx + dy * dy + dz * dz) - srad[b])
        env = min(env, d - radius[j])
        if early and env < 0.0:
            return -1.0, -1.0, ok
    slf = np.inf
    for k in range(pair_i.shape[0]):
        i, j = pair_i[k], pair_j[k]
        dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
        slf = min(slf, np.sqrt(dx * dx + dy * dy + dz * dz) - radius[i] - radius[j])
        if early and slf < 0.0:
            return env, -1.0, ok
    return env, slf, ok


@numba.njit(cache=True)
def _unpack(rf, ri, sf, si):
    """The robot and scene arrays back from the flat ones `NativeChecker` packs (one array each to
    unbox per call, instead of twenty-odd)."""
    n, ns, npairs = ri[0], ri[1], ri[2]
    o = 0
    axis = rf[o : o + 3 * n].reshape(n, 3)
    o += 3 * n
    origin_r = rf[o : o + 9 * n].reshape(n, 3, 3)
    o += 9 * n
    origin_t = rf[o : o + 3 * n].reshape(n, 3)
    o += 3 * n
    local = rf[o : o + 3 * ns].reshape(ns, 3)
    o += 3 * ns
    radius = rf[o : o + ns]
    o += ns
    lower, upper = rf[o : o + n], rf[o + n : o + 2 * n]
    k = 3
    revolute = ri[k : k + n] != 0
    parent = ri[k + n : k + 2 * n]
    frame = ri[k + 2 * n : k + 2 * n + ns]
    pair_i = ri[k + 2 * n + ns : k + 2 * n + ns + npairs]
    pair_j = ri[k + 2 * n + ns + npairs : k + 2 * n + ns + 2 * npairs]
    nb, nc, nsph = si[0], si[1], si[2]
    o = 0
    bc = sf[o : o + 3 * nb].reshape(nb, 3)
    o += 3 * nb
    br = sf[o : o + 9 * nb].reshape(nb, 3, 3)
    o += 9 * nb
    bh = sf[o : o + 3 * nb].reshape(nb, 3)
    o += 3 * nb
    bb = sf[o : o + nb]
    o += nb
    cc = sf[o : o + 3 * nc].reshape(nc, 3)
    o += 3 * nc
    cr = sf[o : o + 9 * nc].reshape(nc, 3, 3)
    o += 9 * nc
    crad, ch, cb = sf[o : o + nc], sf[o + nc : o + 2 * nc], sf[o + 2 * nc : o + 3 * nc]
    o += 3 * nc
    sc = sf[o : o + 3 * nsph].reshape(nsph, 3)
    srad = sf[o + 3 * nsph : o + 4 * nsph]
    robot = (axis, origin_r, origin_t, revolute, parent, frame, local, radius, pair_i, pair_j, lower, upper)
    return robot, (bc, br, bh, bb, cc, cr, crad, ch, cb, sc, srad)


@numba.njit(cache=True)
def _scratch(robot):
    """Frame rotations, translations and sphere centres of one configuration, and one joint's motion
    (rotation, local rotation, skew matrix, translation, local translation), reused across states."""
    n, spheres = robot[0].shape[0], robot[5].shape[0]
    return (
        np.empty((n + 1, 3, 3)),
        np.empty((n + 1, 3)),
        np.empty((spheres, 3)),
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.zeros((3, 3)),
        np.empty(3),
        np.empty(3),
    )


@numba.njit(cache=True)
def _clearances(qs, rf, ri, sf, si, tol):
    robot, scene = _unpack(rf, ri, sf, si)
    scratch = _scratch(robot)
    env, slf, ok = np.empty(qs.shape[0]), np.empty(qs.shape[0]), np.empty(qs.shape[0], np.bool_)
    for k in range(qs.shape[0]):
        env[k], slf[k], ok[k] = _one(qs[k], robot, scene, tol, scratch, False)
    return env, slf, ok


@numba.njit(cache=True)
def _all_valid(qs, rf, ri, sf, si, tol):
    """Whether every configuration is collision-free and within limits, stopping at the first that is not."""
    robot, scene = _unpack(rf, ri, sf, si)
    scratch = _scratch(robot)
    for k in range(qs.shape[0]):
        env, slf, ok = _one(qs[k], robot, scene, tol, scratch, True)
        if not (env >= 0.0 and slf >= 0.0 and ok):
            return False
    return True


class NativeChecker:
    """State validity of `robot` in `scene` without JAX: `clearances(qs)` equals `state_clearances`,
    `all_valid(qs)` stops at the first invalid state (a motion's interpolated states, in order)."""

    def __init__(self, robot: Robot, scene: Scene, tol: float = 1e-6):
        flat = lambda *arrays, dtype=np.float64: np.ascontiguousarray(np.concatenate([np.asarray(a, dtype).ravel() for a in arrays]))  # noqa: E731
        self.dof = robot.dof
        counts = (robot.dof, len(robot.collision.radius), len(robot.collision.pair_i))
        self.rf = flat(
            robot.joint_axis, robot.joint_origin_r, robot.joint_origin_t, robot.collision.local, robot.collision.radius, robot.lower, robot.upper
        )
        self.ri = flat(
            counts, robot.joint_revolute, robot.joint_parent, robot.collision.frame, robot.collision.pair_i, robot.collision.pair_j, dtype=np.int64
        )
        arrays = _scene_arrays(scene)
        self.sf = flat(*arrays)
        self.si = np.array([len(arrays[0]), len(arrays[4]), len(arrays[9])], np.int64)
        self.tol = float(tol)

    def _states(self, qs) -> np.ndarray:
        return np.ascontiguousarray(qs, np.float64).reshape(-1, self.dof)

    def clearances(self, qs: np.ndarray):
        """(env, self, within limits), each (M,), of configurations (M, n)."""
        return _clearances(self._states(qs), self.rf, self.ri, self.sf, self.si, self.tol)

    def valid(self, qs: np.ndarray) -> np.ndarray:
        env, slf, ok = self.clearances(qs)
        return (env >= 0.0) & (slf >= 0.0) & ok

    def all_valid(self, qs: np.ndarray) -> bool:
        return bool(_all_valid(self._states(qs), self.rf, self.ri, self.sf, self.si, self.tol))


def _scene_arrays(scene: Scene) -> tuple:
    """The used primitives as float64 arrays (rotations as matrices; cloud points as radius-0 spheres)."""
    import jaxlie

    f64 = lambda a: np.ascontiguousarray(np.asarray(a, np.float64))  # noqa: E731
    keep = lambda prims: np.asarray(prims.mask, bool)  # noqa: E731
    rot = lambda quat: f64(jaxlie.SO3(np.asarray(quat, np.float64)).as_matrix()).reshape(-1, 3, 3)  # noqa: E731
    c, y, s, p = scene.cuboids, scene.cylinders, scene.spheres, scene.cloud
    kc, ky, ks, kp = keep(c), keep(y), keep(s), keep(p)
    sphere_c = np.concatenate([np.asarray(s.center, np.float64)[ks], np.asarray(p.points, np.float64)[kp]]).reshape(-1, 3)
    sphere_r = np.concatenate([np.asarray(s.radius, np.float64)[ks], np.zeros(int(kp.sum()))])
    half, radius, half_length = (f64(np.asarray(a)[k]) for a, k in ((c.half_extents, kc), (y.radius, ky), (y.half_length, ky)))
    return (
        f64(np.asarray(c.center)[kc]).reshape(-1, 3),
        rot(np.asarray(c.quat)[kc]) if kc.any() else np.zeros((0, 3, 3)),
        half.reshape(-1, 3),
        np.linalg.norm(half.reshape(-1, 3), axis=1),  # bounding-sphere radii
        f64(np.asarray(y.center)[ky]).reshape(-1, 3),
        rot(np.asarray(y.quat)[ky]) if ky.any() else np.zeros((0, 3, 3)),
        radius,
        half_length,
        np.hypot(radius, half_length),
        f64(sphere_c),
        f64(sphere_r),
    )
