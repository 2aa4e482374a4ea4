"""Full-speed sweeps: the arm already moving at its velocity limits toward a wall, a thin board or a
box edge, with a joint goal beyond the obstacle that keeps pulling it in.

Each sweep is a `Problem` with a start velocity. A random posture near the default one and a joint
velocity direction are drawn; one collision sphere is chosen (the fastest, or, with `worst`, the
one whose approach speed along its own direction of motion is the largest when every joint runs at
its limit in the sign that drives it there); the obstacle is placed across its path
(0.05-0.5 m ahead, normal within ~27 deg of the motion). A sweep is kept only if every sphere (and self-collision pair) could still stop before
contact braking at `share` of the deceleration the joint acceleration limits give it at the start
(`stopping_margin`; the available deceleration changes as the arm moves, so `share` < 1 keeps only
sweeps the limits can really stop): the test of a barrier is that it stops what the robot's limits
allow to be stopped.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from fabrax.check.clearance import clearances
from fabrax.problems.problem import Problem
from fabrax.robot.kinematics import point_kinematics
from fabrax.robot.limits import max_acceleration
from fabrax.robot.robot import Robot
from fabrax.scene import COMMON_CAPACITY, from_dict
from fabrax.scene.sdf import nearest_distance

KINDS = ("wall", "board", "edge")


def _quat_z_to(normal: np.ndarray) -> list[float]:
    """wxyz of the rotation taking local z onto `normal`."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normal)
    s, c = np.linalg.norm(axis), float(z @ normal)
    if s < 1e-8:
        return [1.0, 0.0, 0.0, 0.0] if c > 0 else [0.0, 1.0, 0.0, 0.0]
    half = 0.5 * np.arctan2(s, c)
    return [float(np.cos(half)), *(np.sin(half) * axis / s).tolist()]


@functools.partial(jax.jit, static_argnames=("dt", "share"))
def stopping_margin(robot: Robot, scene, q: jax.Array, qd: jax.Array, dt: float, share: float = 1.0) -> jax.Array:
    """Smallest, over the spheres' distances to the scene and the self-collision pairs' distances, of the
    distance minus what it needs to brake to rest, rate^2 / (2 a_n) + |rate| dt, with a_n = share *
    sum_j |u_j| a'_j (u the distance's gradient in joint space: `share` of the largest deceleration the
    joint acceleration limits give it in this configuration; curvature terms ignored); distances that
    grow need nothing. Positive: every approach can still be stopped."""
    kin = point_kinematics(robot, q, qd, robot.collision.frame, robot.collision.local)
    near = nearest_distance(scene, kin.x, kin.xd)
    acc = max_acceleration(robot, dt)

    def margin(x, rate, u):
        cap = share * (jnp.abs(u) @ acc)
        return x - jnp.where(rate < 0, rate**2 / (2.0 * cap + 1e-9) - rate * dt, 0.0)

    scene_margin = margin(near.d - robot.collision.radius, near.rate, jnp.einsum("cjs,cs->sj", kin.jac, near.n))
    i, j = robot.collision.pair_i, robot.collision.pair_j
    rel = kin.x[:, i] - kin.x[:, j]
    dist = jnp.sqrt(jnp.sum(rel * rel, 0) + 1e-18)
    nrm = rel / dist
    u = jnp.einsum("cjp,cp->pj", kin.jac[:, :, i] - kin.jac[:, :, j], nrm)
    self_margin = margin(dist - robot.collision.radius[i] - robot.collision.radius[j], jnp.sum(nrm * (kin.xd[:, i] - kin.xd[:, j]), 0), u)
    return jnp.minimum(jnp.min(scene_margin), jnp.min(self_margin, initial=jnp.inf))


@jax.jit
def _motion(robot: Robot, q: jax.Array, qd: jax.Array):
    kin = point_kinematics(robot, q, qd, robot.collision.frame, robot.collision.local)
    return kin.jac, kin.x.T, kin.xd.T


def sweeps(
    robot: Robot,
    n: int,
    seed: int = 0,
    *,
    worst: bool = True,
    kinds=KINDS,
    distance=(0.05, 0.5),
    default_q=None,
    spread: float = 0.5,
    dt: float = 0.01,
    share: float = 0.5,
) -> list[Problem]:
    """`n` sweeps (kinds in turn), reproducible from `seed`; see the module docstring."""
    rng = np.random.default_rng(seed)
    lo, hi, vel = np.asarray(robot.lower), np.asarray(robot.upper), np.asarray(robot.velocity)
    centre = np.asarray(default_q if default_q is not None else 0.5 * (lo + hi))
    out: list[Problem] = []
    for _ in range(200 * n):
        if len(out) == n:
            break
        q0 = np.clip(centre + rng.uniform(-1, 1, robot.dof) * 0.5 * spread * (hi - lo), lo + 0.2, hi - 0.2)
        d = rng.normal(size=robot.dof)
        qd = d / np.max(np.abs(d) / vel)  # the fastest joint at its limit
        jac, x, v = (np.asarray(a) for a in _motion(robot, jnp.asarray(q0, jnp.float32), jnp.asarray(qd, jnp.float32)))
        i = int(np.argmax(np.linalg.norm(v, axis=1)))
        if worst:  # every joint at its limit, each in the sign that drives sphere i along its motion
            qd = vel * np.sign(jac[:, :, i].T @ v[i])
            v = np.einsum("cjs,j->sc", jac, qd)
        speed = float(np.linalg.norm(v[i]))
        if speed < 0.3:
            continue
        u = v[i] / speed
        kind = kinds[len(out) % len(kinds)]
        d0 = rng.uniform(*distance) + float(robot.collision.radius[i])
        tilt = rng.normal(size=3)
        tilt -= (tilt @ u) * u
        tilt /= np.linalg.norm(tilt) + 1e-12
        normal = u + 0.5 * rng.uniform() * tilt
        normal /= np.linalg.norm(normal)
        if kind == "wall":
            obs = {"type": "cuboid", "center": (x[i] + u * d0 + normal * 0.01).tolist(), "quat_wxyz": _quat_z_to(normal), "size": [1.6, 1.6, 0.02]}
        elif kind == "board":
            obs = {"type": "cuboid", "center": (x[i] + u * d0 + normal * 0.005).tolist(), "quat_wxyz": _quat_z_to(normal), "size": [0.5, 0.5, 0.01]}
        else:  # a 0.3 m box turned 45 deg about an axis across the motion: its edge lies ahead
            half = 0.15
            turn = Rotation.from_rotvec(tilt * np.pi / 4) * Rotation.from_quat(_quat_z_to(u), scalar_first=True)
            center = x[i] + u * (d0 + half * np.sqrt(2.0))
            obs = {"type": "cuboid", "center": center.tolist(), "quat_wxyz": turn.as_quat(scalar_first=True).tolist(), "size": [2 * half] * 3}
        scene = from_dict({"obstacles": [obs]}).pad(**COMMON_CAPACITY)
        env, slf, ok = clearances(robot, scene, q0[None])
        if float(env[0]) < 0.02 or float(slf[0]) < 0.0 or not bool(ok[0]):
            continue
        if float(stopping_margin(robot, scene, jnp.asarray(q0, jnp.float32), jnp.asarray(qd, jnp.float32), dt, share)) <= 0.0:
            continue
        goal = np.clip(q0 + 2.0 * qd / np.linalg.norm(qd), lo, hi)
        out.append(Problem(start_q=q0, scene=scene, goal_q=goal, name=f"sweep/{len(out):04d}", kind=f"sweep_{kind}", start_qd=qd))
    if len(out) < n:
        raise ValueError(f"found only {len(out)} of {n} sweeps")
    return out
