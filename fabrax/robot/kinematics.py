"""Forward kinematics of a `Robot` as pure JAX functions.

Frames are world transforms (R, t) of the active joints, with index 0 the fixed
base; a point is attached to one frame by a local position. Kinematics of many
points (collision-sphere centres, end-effector keypoints) come from one chain
evaluation: positions, Jacobians and the curvature term Jdot qd by forward-mode
autodiff (thesis eq. 2.4: xdd = J qdd + Jdot qd).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie


def _skew(a):
    z = jnp.zeros_like(a[..., 0])
    return jnp.stack(
        [jnp.stack([z, -a[..., 2], a[..., 1]], -1), jnp.stack([a[..., 2], z, -a[..., 0]], -1), jnp.stack([-a[..., 1], a[..., 0], z], -1)],
        -2,
    )


def frame_transforms(robot, q):
    """World rotation (n+1, 3, 3) and translation (n+1, 3) of the base and every joint frame."""
    k = _skew(robot.joint_axis)
    s, c = jnp.sin(q)[:, None, None], jnp.cos(q)[:, None, None]
    eye = jnp.eye(3, dtype=q.dtype)
    revolute = jnp.asarray(robot.joint_revolute)[:, None, None]
    motion_r = jnp.where(revolute, eye + s * k + (1.0 - c) * (k @ k), eye)
    motion_t = jnp.where(revolute[..., 0], 0.0, robot.joint_axis * q[:, None])
    local_r = robot.joint_origin_r @ motion_r
    local_t = jnp.einsum("nij,nj->ni", robot.joint_origin_r, motion_t) + robot.joint_origin_t
    rs, ts = [eye], [jnp.zeros(3, q.dtype)]
    for i, p in enumerate(robot.joint_parent):  # static tree walk, unrolled at trace time
        rp, tp = rs[p + 1], ts[p + 1]
        rs.append(rp @ local_r[i])
        ts.append(rp @ local_t[i] + tp)
    return jnp.stack(rs), jnp.stack(ts)


def points(robot, q, frame, local):
    """World positions (N, 3) of points given by frame index (N,) and local position (N, 3)."""
    r, t = frame_transforms(robot, q)
    return jnp.einsum("nij,nj->ni", r[frame], local) + t[frame]


def point_kinematics(robot, q, qd, frame, local):
    """Positions x (N,3), Jacobians J (N,3,n), velocities J qd (N,3) and Jdot qd (N,3).

    One primal chain; J from n forward tangents, Jdot qd from a nested jvp along qd.
    """
    f = lambda q_: points(robot, q_, frame, local)  # noqa: E731
    vel = lambda q_: jax.jvp(f, (q_,), (qd,))  # noqa: E731
    (x, xd), (_, jdqd) = jax.jvp(vel, (q,), (qd,))
    jac = jax.vmap(lambda v: jax.jvp(f, (q,), (v,))[1], out_axes=-1)(jnp.eye(q.shape[-1], dtype=q.dtype))
    return x, jac, xd, jdqd


def link_poses(robot, q) -> jaxlie.SE3:
    """World poses of every link, as a batched `jaxlie.SE3` of shape (L,)."""
    r, t = frame_transforms(robot, q)
    f = robot.link_frame
    rot = r[f] @ robot.link_offset_r
    trans = jnp.einsum("lij,lj->li", r[f], robot.link_offset_t) + t[f]
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
