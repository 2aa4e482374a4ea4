# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#   kernelspec:
#     display_name: Python 3
#     name: python3
# ---

# %% [markdown]
# # GFCS: global motion from fabric command sequences
#
# The pure fabric is local: under a table it stops in a local minimum. GFCS (gfcs_paper,
# Algorithm 1) searches, with CMA-ES from evosax, for an intermediate joint command that the fabric
# visits before the goal; a candidate's cost is its time to goal, plus penalties for not arriving
# or colliding. A small population and two batches keep this notebook to a minute on a CPU.

# %%
import os

import jax
import numpy as np

from fabrax import config
from fabrax.check.checker import check_path
from fabrax.planners.gfcs import GFCSConfig, solve
from fabrax.problems import ProblemBatch

robot = config.load_robot("panda_mbm")
fabric, params = config.load_fabric(robot, "panda")
if os.environ.get("FABRAX_DATA"):
    from fabrax.problems.mbm import load_mbm

    problem = load_mbm(robot, os.environ["FABRAX_DATA"], ["table_under_pick"], "test", 1)[0]
else:
    from fabrax.problems import procedural

    problem = procedural.generate(robot, "mbm_like", ["table_under_pick"], 1, seed=0)[0]
print(problem.name)

# %%
cfg = GFCSConfig(population=16, batches=2)
result = solve(fabric, params, ProblemBatch.of(problem), jax.random.PRNGKey(0), cfg)
for b in result.per_batch:
    print(f"batch {b['batch']}: best cost {b['best_cost']:.2f} (time to goal, s), {b['wall_s']:.2f} s wall")
print("command:", np.round(result.best_commands, 2))

# %% [markdown]
# The best candidate's motion is a fabric rollout: check it with the benchmark's checker.

# %%
tr = result.trajectory
q = np.asarray(tr.q[: int(tr.length)])
check = check_path(robot, problem.scene, q)
print(f"reached {bool(tr.reached)}, collision {check.collision}, min clearance {100 * check.min_clearance:.1f} cm")
assert result.per_batch[-1]["best_cost"] <= result.per_batch[0]["best_cost"]
