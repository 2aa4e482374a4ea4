# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#   kernelspec:
#     display_name: Python 3
#     name: python3
# ---

# %% [markdown]
# # The benchmark
#
# MotionBenchMaker problems (from `$FABRAX_DATA`; generated look-alikes when the data is absent),
# one checker and one set of metrics for every method. The command line does the same:
# `fabrax bench method=gf problems=mbm classes=[cage] limit=3`.

# %%
import os

from fabrax import config
from fabrax.bench.methods import FabricMethod
from fabrax.bench.runner import run, summary_table

robot = config.load_robot("panda_mbm")
if os.environ.get("FABRAX_DATA"):
    from fabrax.problems.mbm import load_mbm

    problems = load_mbm(robot, os.environ["FABRAX_DATA"], ["cage", "table_pick"], "test", 2)
else:
    from fabrax.problems import procedural

    problems = procedural.generate(robot, "mbm_like", ["cage", "table_pick"], 2, seed=0)
print([p.name for p in problems])

# %% [markdown]
# A method turns problems into joint paths; `run` checks each path against the scene (spheres vs
# primitives, self-collision, limits, re-checked every 1/32 rad) and measures it.

# %%
fabric, params = config.load_fabric(robot, "panda")
rows = run(FabricMethod(fabric, params), robot, problems, progress=False)
print(summary_table(rows))

# %%
for r in rows:
    print(f"{r['problem']:>22}  success={r['success']!s:5}  EE path {r['ee_length']:.2f} m  clearance {100 * r['min_clearance']:.1f} cm")
assert len(rows) == len(problems) and all("success" in r for r in rows)
