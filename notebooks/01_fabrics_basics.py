# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#   kernelspec:
#     display_name: Python 3
#     name: python3
# ---

# %% [markdown]
# # Geometric fabrics basics
#
# Build the Panda fabric from its URDF and config, roll it out toward a goal behind a shelf board,
# and look at what the fabric does along the way: its energy and its distance to the obstacles.
# (Thesis §2.1 and §3.3; `docs/fabric.md` maps every term to its equation.)

# %%
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

from fabrax import config
from fabrax.problems import batch
from fabrax.problems.generators import demo_problem
from fabrax.rollout import reach

robot = config.load_robot("panda")  # any URDF arm: configs/robot/<name>.yaml
fabric, params = config.load_fabric(robot, "panda")  # the term library of configs/fabric/panda.yaml
print(robot.name, robot.dof, "joints,", robot.n_spheres, "collision spheres;", [t.name for t in fabric.terms])

# %% [markdown]
# A problem is a start, a goal and a scene of primitives. `reach` rolls the fabric out in a
# `lax.scan` (batched with `vmap` over problems) until the goal test holds.

# %%
problem = demo_problem(robot)
tr = jax.jit(lambda b: reach(fabric, params, b, dt=0.01, steps=700))(batch([problem]))
n = int(tr.length[0])
q, qd = tr.q[0, :n], tr.qd[0, :n]
print(f"reached: {bool(tr.reached[0])} in {float(tr.t_goal[0]):.2f} s, min clearance {float(tr.min_clearance[0]) * 100:.1f} cm")

# %% [markdown]
# `fabric.evaluate` gives the energised fabric at a state: the energy metric M_e, the energy H_e
# (conserved when the fabric is unforced and undamped), the forcing potential and the clearance.

# %%
goal_params = fabric.with_joint_goal(params, jnp.asarray(problem.goal_q, jnp.float32))
ev = jax.jit(jax.vmap(lambda q_, qd_: fabric.evaluate(goal_params, problem.scene, q_, qd_)))(q, qd)
t = np.arange(n) * 0.01
fig, ax = plt.subplots(1, 2, figsize=(9, 3))
ax[0].plot(t, np.asarray(ev.energy), label="H_e (kinetic)")
ax[0].plot(t, np.asarray(ev.potential), label="forcing potential")
ax[0].set_xlabel("t (s)")
ax[0].legend()
ax[1].plot(t, 100 * np.asarray(ev.terms.clearance))
ax[1].set_xlabel("t (s)")
ax[1].set_ylabel("clearance (cm)")
fig.tight_layout()

# %% [markdown]
# The potential falls as the arm approaches the goal while the damping drains the energy; the
# clearance never goes below zero.

# %%
assert np.all(np.isfinite(np.asarray(ev.energy)))
assert float(ev.potential[-1]) < float(ev.potential[0])
assert float(np.min(np.asarray(ev.terms.clearance))) > 0.0
