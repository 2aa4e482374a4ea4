# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#   kernelspec:
#     display_name: Python 3
#     name: python3
# ---

# %% [markdown]
# # Motion skills on a learned Riemannian manifold
#
# A VAE trained on demonstrations defines a Riemannian metric on its latent space: the pullback of
# its decoders' means and standard deviations (riemannian_motion_skills_paper, eqs. 10 and 21-25).
# Geodesics of that metric stay where the demonstrations are; an obstacle reshapes the metric
# (eq. 30) without retraining; the fabric executes the decoded motion and still avoids what the
# skill never saw. Short training keeps this notebook to about a minute on a CPU; the full
# experiment is `python experiments/skills.py`.

# %%
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
from flax import nnx

from fabrax.skills import demos, geodesic, metric, vae
from fabrax.skills.plots import grid_maps
from fabrax.skills.rbf import kmeans
from fabrax.skills.spline import dense

x, q = demos.jc(points=50)  # J-shaped positions, C-shaped orientations (§4.2)
model, log = vae.fit_task(x.reshape(-1, 3), q.reshape(-1, 4), vae.VAEConfig(steps=2000, rbf_steps=400, centers=32))
codes = np.asarray(model.encode(jnp.asarray(x, jnp.float32), jnp.asarray(q, jnp.float32))[0])
print("stage-1 loss", log["stage1"][[0, -1]], "stage-2 loss", log["stage2"][[0, -1]])

# %% [markdown]
# Geodesics between each demonstration's start and end: a cubic spline minimising the energy of its decoded
# polyline (damped Newton), started from a shortest path in a graph over k-means centres of the codes.

# %%
gd, state = nnx.split(model)
solve = geodesic.solver(metric.curve_metric(gd), geodesic.GeodesicConfig(), kmeans(codes.reshape(-1, 2), 48)[0])
geo = solve((state, metric.NONE), jnp.asarray(codes[:, 0]), jnp.asarray(codes[:, -1]))
z = np.asarray(jax.vmap(dense)(geo.coeffs))
print("energy of the initial curves", np.asarray(geo.energy0).round(3), "after", np.asarray(geo.energy).round(3))
print("the same curves at 10x the chords (near the solved energy where 20 chords resolve the metric)", np.asarray(geo.resolved).round(3))

flat = codes.reshape(-1, 2)
lo, hi = flat.min(0) - 1.0, flat.max(0) + 1.0
unc, mag, u, v = grid_maps(model, metric.NONE, lo, hi, n=60)
fig, axes = plt.subplots(1, 2, figsize=(11, 4))
for ax, img, title in ((axes[0], np.log10(unc), "log10 predictive variance"), (axes[1], mag, "magnification")):
    ax.pcolormesh(u, v, img, shading="auto")
    ax.scatter(flat[:, 0], flat[:, 1], s=2, c="white", alpha=0.4)
    for zc in z:
        ax.plot(zc[:, 0], zc[:, 1], color="gold")
    ax.set_title(title)

# %% [markdown]
# An obstacle on the demonstrated path reshapes the metric: the ambient factor
# 1 + eta exp(-|x - o|^2 / r^2) weights the decoded position's velocity. The geodesic can only
# move as far as the demonstrations spread; the fabric takes care of the rest.

# %%
center = x[3, 25]
obs = metric.obstacles([center], [0.04], eta=500.0)
shaped = solve((state, obs), jnp.asarray(codes[:, 0]), jnp.asarray(codes[:, -1]))
ee_plain = np.asarray(jax.vmap(jax.vmap(model.decode_x))(jnp.asarray(z)))
ee_shaped = np.asarray(jax.vmap(jax.vmap(model.decode_x))(jax.vmap(dense)(shaped.coeffs)))
for name, ee in (("plain", ee_plain), ("reshaped", ee_shaped)):
    print(name, "closest approach to the obstacle centre (cm):", (100 * np.linalg.norm(ee - center, axis=-1).min(1)).round(1))
fig, ax = plt.subplots(figsize=(4, 4))
for d in x:
    ax.plot(d[:, 1], d[:, 2], color="0.7", lw=3)
for ee, c in ((ee_plain, "gold"), (ee_shaped, "cyan")):
    for e in ee:
        ax.plot(e[:, 1], e[:, 2], color=c)
ax.add_patch(plt.Circle((center[1], center[2]), 0.02, color="k", alpha=0.4))
ax.set_aspect("equal")
