"""How well the GFCS autoencoder compresses d_E (the 0.15 m lattice distances, 1859 numbers): fit on
the MotionBenchMaker train scenes of the six GFCS classes, reconstruct the test scenes.

    FABRAX_DATA=../shared/data python experiments/gfcs_autoencoder.py   # -> docs/results/gfcs_autoencoder.json
"""

import json
import os
import time

import jax.numpy as jnp
import numpy as np

from fabrax import config
from fabrax.planners.gfcs.autoencoder import fit
from fabrax.planners.gfcs.encoding import Encoding
from fabrax.problems import ProblemBatch
from fabrax.problems.mbm import TABLE_I_CLASSES, load_mbm

robot = config.load_robot("panda_mbm")
enc = Encoding()
classes = list(TABLE_I_CLASSES)
out = {}
for split in ("train", "test"):
    ps = [p for p in load_mbm(robot, os.environ["FABRAX_DATA"], classes, split, None) if p.valid]
    out[split] = np.stack([np.asarray(enc.scene_distances(ProblemBatch.of(p).scene)) for p in ps])
res = {}
for latent in (16, 64):
    t0 = time.perf_counter()
    model, losses = fit(out["train"], latent, steps=2000, lr=1e-3)
    rec = np.asarray(model(jnp.asarray(out["test"])))
    rmse = float(np.sqrt(np.mean((rec - out["test"]) ** 2)))
    base = float(np.sqrt(np.mean((out["test"] - out["train"].mean(0)) ** 2)))
    res[latent] = {"train_mse_final": losses[-1], "test_rmse_m": rmse, "test_rmse_mean_predictor_m": base, "fit_s": time.perf_counter() - t0}
    print(latent, res[latent], flush=True)
print(out["train"].shape, out["test"].shape)
json.dump(res, open("docs/results/gfcs_autoencoder.json", "w"), indent=1)
