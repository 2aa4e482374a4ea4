"""Forward kinematics of a `Robot` as pure JAX functions.

Frames are world transforms (R, t) of the active joints, with index 0 the fixed
base; a point is attached to one frame by a local position. Kinematics of many
points (collision-sphere centres, end-effector keypoints) come from one chain
evaluation: positions, Jacobians and the curvature term Jdot qd (thesis eq.
2.4: xdd = J qdd + Jdot qd).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie

from fabrax.soa import cross0, dot0


class PointKinematics(NamedTuple):
    """Kinematics of N points, component-first (3, ...) so that batch work vectorises over points."""

    x: jax.Array  # (3, N) positions
    jac: jax.Array  # (3, n, N) Jacobians
    xd: jax.Array  # (3, N) velocities J qd
    jdqd: jax.Array  # (3, N) curvature terms Jdot qd


def _skew(a):
    z = jnp.zeros_like(a[..., 0])
    return jnp.stack(
        [jnp.stack([z, -a[..., 2], a[..., 1]], -1), jnp.stack([a[..., 2], z, -a[..., 0]], -1), jnp.stack([-a[..., 1], a[..., 0], z], -1)],
        -2,
    )


def _mm(a, b):
    """Small matrix product as multiply-and-sum (XLA CPU runs tiny batched dots slowly)."""
    return (a[..., :, :, None] * b[..., None, :, :]).sum(-2)


def _mv(a, v):
    return (a * v[..., None, :]).sum(-1)


def frame_transforms(robot, q):
    """World rotation (n+1, 3, 3) and translation (n+1, 3) of the base and every joint frame."""
    k = _skew(robot.joint_axis)
    s, c = jnp.sin(q)[:, None, None], jnp.cos(q)[:, None, None]
    eye = jnp.eye(3, dtype=q.dtype)
    revolute = jnp.asarray(robot.joint_revolute)[:, None, None]
    motion_r = jnp.where(revolute, eye + s * k + (1.0 - c) * _mm(k, k), eye)
    motion_t = jnp.where(revolute[..., 0], 0.0, robot.joint_axis * q[:, None])
    local_r = _mm(robot.joint_origin_r, motion_r)
    local_t = _mv(robot.joint_origin_r, motion_t) + robot.joint_origin_t
    rs, ts = [eye], [jnp.zeros(3, q.dtype)]
    for i, p in enumerate(robot.joint_parent):  # static tree walk, unrolled at trace time
        rp, tp = rs[p + 1], ts[p + 1]
        rs.append(_mm(rp, local_r[i]))
        ts.append(_mv(rp, local_t[i]) + tp)
    return jnp.stack(rs), jnp.stack(ts)


def points(robot, q, frame, local):
    """World positions (N, 3) of points given by frame index (N,) and local position (N, 3)."""
    r, t = frame_transforms(robot, q)
    return _mv(r[frame], local) + t[frame]


def point_kinematics(robot, q, qd, frame, local) -> PointKinematics:
    """Positions, Jacobians, velocities J qd and curvature terms Jdot qd of points (frame (N,), local (N, 3)).

    One pass over the tree propagates frame velocities and (qdd = 0)
    accelerations (recursive Newton-Euler kinematics); Jacobian columns are
    z_j x (p - o_j) for revolute and z_j for prismatic ancestors j. Agrees with
    nested forward-mode autodiff of `points` (tested) at a fraction of its cost.
    """
    r, t = frame_transforms(robot, q)
    z = _mv(r[1:], robot.joint_axis)  # (n, 3) world joint axes
    zero = jnp.zeros(3, q.dtype)
    w, v, aw, av = [zero], [zero], [zero], [zero]  # angular/linear velocity and acceleration per frame
    for k, p in enumerate(robot.joint_parent):
        p = p + 1
        rel = t[k + 1] - t[p]
        zq = z[k] * qd[k]
        wp_rel = jnp.cross(w[p], rel)
        av_k = av[p] + jnp.cross(aw[p], rel) + jnp.cross(w[p], wp_rel)
        if robot.joint_revolute[k]:
            w.append(w[p] + zq)
            v.append(v[p] + wp_rel)
            aw.append(aw[p] + jnp.cross(w[p], zq))
            av.append(av_k)
        else:
            w.append(w[p])
            v.append(v[p] + wp_rel + zq)
            aw.append(aw[p])
            av.append(av_k + 2.0 * jnp.cross(w[p], zq))
    soa = lambda rows: jnp.stack(rows, -1)[:, frame]  # noqa: E731  (3, N): per-frame vectors at each point
    x = jnp.stack([dot0(jnp.moveaxis(r, 0, -1)[c][:, frame], local.T) for c in range(3)]) + t.T[:, frame]
    rel = x - t.T[:, frame]
    wf, awf = soa(w), soa(aw)
    xd = soa(v) + cross0(wf, rel)
    jdqd = soa(av) + cross0(awf, rel) + cross0(wf, cross0(wf, rel))
    zt = z.T[:, :, None]  # (3, n, 1)
    cols = cross0(zt, x[:, None, :] - t[1:].T[:, :, None])  # (3, n, N)
    cols = jnp.where(jnp.asarray(robot.joint_revolute)[None, :, None], cols, zt)
    jac = jnp.where(robot.ancestors[frame].T[None], cols, 0.0)
    return PointKinematics(x, jac, xd, jdqd)


def link_poses(robot, q) -> jaxlie.SE3:
    """World poses of every link, as a batched `jaxlie.SE3` of shape (L,)."""
    r, t = frame_transforms(robot, q)
    f = robot.link_frame
    rot = _mm(r[f], robot.link_offset_r)
    trans = _mv(r[f], robot.link_offset_t) + t[f]
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(rot), trans)


def frame_pose(robot, q, name: str) -> jaxlie.SE3:
    """World pose of a named frame (any link, or an extra frame such as a TCP)."""
    i = robot.frame_index(name)
    r, t = frame_transforms(robot, q)
    f = robot.frame_parent[i]
    rot = r[f] @ robot.frame_offset_r[i]
    trans = r[f] @ robot.frame_offset_t[i] + t[f]
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(rot), trans)


def sphere_centers(robot, q):
    """World centres (S, 3) of the collision spheres."""
    return points(robot, q, robot.sphere_frame, robot.sphere_local)
