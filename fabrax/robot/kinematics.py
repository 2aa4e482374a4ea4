"""Forward kinematics of a `Robot` as pure JAX functions.

Frames are world transforms (R, t) of the active joints, with index 0 the fixed
base; a point is attached to one frame by a local position. Kinematics of many
points (collision-sphere centres, end-effector keypoints) come from one chain
evaluation: positions, Jacobians and the curvature term Jdot qd (thesis eq.
2.4: xdd = J qdd + Jdot qd).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie

from fabrax.soa import cross0, matvec


class PointKinematics(NamedTuple):
    """Kinematics of N points, component-first (3, ...) so that batch work vectorises over points."""

    x: jax.Array  # (3, N) positions
    jac: jax.Array  # (3, n, N) Jacobians
    xd: jax.Array  # (3, N) velocities J qd
    jdqd: jax.Array  # (3, N) curvature terms Jdot qd
    axes: jax.Array  # (3, n) world joint axes z_a (Jacobian columns: z_a x (x - o_a) or z_a)
    origins: jax.Array  # (3, n) world joint origins o_a


def _skew(a):
    z = jnp.zeros_like(a[..., 0])
    return jnp.stack(
        [jnp.stack([z, -a[..., 2], a[..., 1]], -1), jnp.stack([a[..., 2], z, -a[..., 0]], -1), jnp.stack([-a[..., 1], a[..., 0], z], -1)],
        -2,
    )


def _mm(a, b):
    """Small matrix product as multiply-and-sum (XLA CPU runs tiny batched dots slowly)."""
    return (a[..., :, :, None] * b[..., None, :, :]).sum(-2)


def frame_transforms(robot, q):
    """World rotation (n+1, 3, 3) and translation (n+1, 3) of the base and every joint frame."""
    k = _skew(robot.joint_axis)
    s, c = jnp.sin(q)[:, None, None], jnp.cos(q)[:, None, None]
    eye = jnp.eye(3, dtype=q.dtype)
    revolute = jnp.asarray(robot.joint_revolute)[:, None, None]
    motion_r = jnp.where(revolute, eye + s * k + (1.0 - c) * _mm(k, k), eye)
    motion_t = jnp.where(revolute[..., 0], 0.0, robot.joint_axis * q[:, None])
    local_r = _mm(robot.joint_origin_r, motion_r)
    local_t = matvec(robot.joint_origin_r, motion_t) + robot.joint_origin_t
    rs, ts = [eye], [jnp.zeros(3, q.dtype)]
    for i, p in enumerate(robot.joint_parent):  # static tree walk, unrolled at trace time
        rp, tp = rs[p + 1], ts[p + 1]
        rs.append(_mm(rp, local_r[i]))
        ts.append(matvec(rp, local_t[i]) + tp)
    return jnp.stack(rs), jnp.stack(ts)


def points(robot, q, frame, local):
    """World positions (N, 3) of points given by frame index (N,) and local position (N, 3)."""
    r, t = frame_transforms(robot, q)
    return matvec(r[frame], local) + t[frame]


def point_kinematics(robot, q, qd, frame, local) -> PointKinematics:
    """Positions, Jacobians, velocities J qd and curvature terms Jdot qd of points (frame (N,), local (N, 3)).

    Geometric Jacobian: column i is z_i x (p - o_i) for a revolute and z_i for
    a prismatic joint i that moves the point. Its time derivative along qd,
    summed over joints, gives Jdot qd without a recursion over the tree:
    d/dt[z_i x (p - o_i)] = (w_i x z_i) x (p - o_i) + z_i x (pd - od_i), with w_i
    the angular velocity of joint i's frame and od_i the velocity of its
    origin. That sum runs over the joint origins only; each point takes its
    frame's rigid-body motion (velocity, angular velocity and acceleration):
    2-3 cross products per point instead of a sum over its joints. Agrees with
    nested forward-mode autodiff of `points` (tested).
    """
    r, t = frame_transforms(robot, q)
    rev = jnp.asarray(robot.joint_revolute)  # (n,)
    z = matvec(r[1:], robot.joint_axis).T  # (3, n) world joint axes
    o = t[1:].T  # (3, n) joint origins
    zq = z * qd  # (3, n)
    anc = robot.ancestors[1:].T  # (n_i, n_j): joint i moves joint frame j

    def lin(p):  # (3, n, M): velocity that each joint gives to points p (3, M)
        return jnp.where(rev[None, :, None], cross0(zq[:, :, None], p[:, None, :] - o[:, :, None]), zq[:, :, None])

    od = jnp.sum(jnp.where(anc[None], lin(o), 0.0), axis=1)  # (3, n) joint-origin velocities
    w = jnp.sum(jnp.where((anc & rev[:, None])[None], zq[:, :, None], 0.0), axis=1)  # (3, n) joint-frame angular velocities
    wz = cross0(w, z)  # (3, n): dz_i/dt

    # Per frame f (index 0: the still base): rotation, origin, origin velocity od_f, angular
    # velocity w_f, angular acceleration alpha_f and Jdot qd a_f of the origin (qdd = 0). A point
    # p = t_f + R_f l on frame f moves with pd = od_f + w_f x (p - t_f) and has Jdot qd =
    # a_f + alpha_f x (p - t_f) + w_f x (w_f x (p - t_f)): O(1) per point, the sums over joints
    # run over the n origins only.
    wzq = wz * qd
    spun = cross0(wzq[:, :, None], o[:, None, :] - o[:, :, None]) + cross0(zq[:, :, None], od[:, None, :] - od[:, :, None])  # (3, n_i, n_f)
    ao = jnp.sum(jnp.where(anc[None], jnp.where(rev[None, :, None], spun, wzq[:, :, None]), 0.0), axis=1)  # (3, n) a_f
    al = jnp.sum(jnp.where((anc & rev[:, None])[None], wzq[:, :, None], 0.0), axis=1)  # (3, n) alpha_f
    moving = jnp.concatenate([od, w, ao, al])  # (12, n)
    per = jnp.concatenate([r.reshape(-1, 9).T, t.T, jnp.concatenate([jnp.zeros((12, 1), q.dtype), moving], axis=1)])  # (24, F)
    # each point's frame by a product with a constant one-hot matrix (exact; HIGHEST keeps f32 on
    # accelerators): XLA fused a gather with the arithmetic above and recomputed it per point
    onehot = (jnp.arange(per.shape[1])[:, None] == frame[None, :]).astype(q.dtype)  # (F, N)
    at = jnp.matmul(per, onehot, precision=jax.lax.Precision.HIGHEST)  # (24, N)
    rel = jnp.stack([sum(at[3 * c + i] * local[:, i] for i in range(3)) for c in range(3)])  # (3, N): R_f l
    x = rel + at[9:12]
    vf, wf, af, alf = at[12:15], at[15:18], at[18:21], at[21:24]
    moves = robot.ancestors[frame].T[None]  # (1, n, N)
    arm = x[:, None, :] - o[:, :, None]  # (3, n, N)
    jac = jnp.where(moves, jnp.where(rev[None, :, None], cross0(z[:, :, None], arm), z[:, :, None]), 0.0)
    spin = cross0(wf, rel)
    xd = vf + spin
    jdqd = af + cross0(alf, rel) + cross0(wf, spin)
    return PointKinematics(x, jac, xd, jdqd, z, o)


def link_poses(robot, q) -> jaxlie.SE3:
    """World poses of every link, as a batched `jaxlie.SE3` of shape (L,)."""
    r, t = frame_transforms(robot, q)
    f = robot.link_frame
    rot = _mm(r[f], robot.link_offset_r)
    trans = matvec(r[f], robot.link_offset_t) + t[f]
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(rot), trans)


def frame_pose(robot, q, name: str) -> jaxlie.SE3:
    """World pose of a named frame (any link, or an extra frame such as a TCP)."""
    i = robot.frame_index(name)
    r, t = frame_transforms(robot, q)
    f = robot.frame_parent[i]
    rot = r[f] @ robot.frame_offset_r[i]
    trans = r[f] @ robot.frame_offset_t[i] + t[f]
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(rot), trans)


@functools.partial(jax.jit, static_argnames=("name",))
def frame_path(robot, qs, name: str):
    """Positions (T, 3) and quaternions wxyz (T, 4) of a named frame along configurations qs (T, n).
    Jitted once per frame and length: callers pad lengths to a few sizes."""
    poses = jax.vmap(lambda q: frame_pose(robot, q, name))(qs)
    return poses.translation(), poses.rotation().wxyz


def sphere_centers(robot, q):
    """World centres (S, 3) of the collision spheres."""
    return points(robot, q, robot.collision.frame, robot.collision.local)


def keypoints(robot, q):
    """World positions (8, 3) of the end effector's bounding-box corners (thesis §3.4.2)."""
    frame = jnp.full((8,), robot.keypoint_frame, jnp.int32)
    return points(robot, q, frame, robot.keypoint_local)


def keypoints_at_pose(robot, name: str, position, quat_wxyz):
    """The keypoints (8, 3) of an end effector whose named frame `name` is at the pose (position,
    quaternion wxyz), without a joint configuration (e.g. a pose goal as keypoints, thesis §3.4.2).
    The frame must ride on the keypoints' joint frame."""
    i = robot.frame_index(name)
    if int(robot.frame_parent[i]) != robot.keypoint_frame:
        raise ValueError(f"frame '{name}' is not on the joint frame that carries robot '{robot.name}''s keypoints")
    r_goal = jaxlie.SO3(jnp.asarray(quat_wxyz) / jnp.linalg.norm(quat_wxyz)).as_matrix()
    r = r_goal @ robot.frame_offset_r[i].T
    t = jnp.asarray(position) - r @ robot.frame_offset_t[i]
    return robot.keypoint_local @ r.T + t
