"""Figures like the paper's Fig. 3-5: latent uncertainty and magnification maps with geodesics, and the
decoded end-effector paths next to the demonstrations."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fabrax.skills import metric

COLORS = {"Riemannian": "gold", "Euclidean": "red", "with obstacle": "cyan"}


def grid_maps(model, obs, lo, hi, n: int = 80):
    """(uncertainty, magnification) on an n x n latent grid spanning lo..hi (2,), and the grid axes."""
    u, v = np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n)
    zs = jnp.asarray(np.stack(np.meshgrid(u, v), -1).reshape(-1, 2), jnp.float32)
    unc = jax.jit(jax.vmap(model.uncertainty))(zs)
    mag = jax.jit(jax.vmap(lambda z: metric.magnification(model, obs, z)))(zs)
    return np.asarray(unc).reshape(n, n), np.asarray(mag).reshape(n, n), u, v


def latent_maps(model, codes: np.ndarray, curves: dict, obs, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    flat = codes.reshape(-1, 2)
    pad = 0.5 * (flat.max(0) - flat.min(0)) + 0.5
    lo, hi = flat.min(0) - pad, flat.max(0) + pad
    unc, mag, u, v = grid_maps(model, metric.NONE, lo, hi)
    _, mag_obs, _, _ = grid_maps(model, obs, lo, hi)
    fig, axes = plt.subplots(1, 3, figsize=(16, 5))
    panels = ((np.log10(unc), "log10 predictive variance"), (mag, "magnification log sqrt det M"), (mag_obs, "magnification with the obstacle"))
    for ax, (img, title) in zip(axes, panels):
        im = ax.pcolormesh(u, v, img, shading="auto", cmap="viridis")
        fig.colorbar(im, ax=ax)
        ax.scatter(flat[:, 0], flat[:, 1], s=2, c="white", alpha=0.4)
        for name, z in curves.items():
            if name == "with obstacle" and title.endswith("variance"):
                continue
            for k, zc in enumerate(np.asarray(z)):
                ax.plot(zc[:, 0], zc[:, 1], color=COLORS.get(name, "k"), lw=1.2, label=name if k == 0 else None)
        ax.set_title(title)
        ax.set_xlim(lo[0], hi[0]), ax.set_ylim(lo[1], hi[1])
    axes[0].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def task_paths(demo_x: np.ndarray, curves: dict, obstacle: dict, path: Path) -> None:
    """Decoded end-effector paths in the demonstrations' y-z plane, with the obstacle's circle."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6))
    for k, x in enumerate(demo_x):
        ax.plot(x[:, 1], x[:, 2], color="0.6", lw=3, alpha=0.5, label="demonstrations" if k == 0 else None)
    for name, xs in curves.items():
        for k, x in enumerate(np.asarray(xs)):
            ax.plot(x[:, 1], x[:, 2], color=COLORS.get(name, "k"), lw=1.2, label=name if k == 0 else None)
    c = obstacle["center"]
    ax.add_patch(plt.Circle((c[1], c[2]), obstacle["radius"], color="k", alpha=0.4, label="obstacle"))
    ax.set_aspect("equal"), ax.set_xlabel("y (m)"), ax.set_ylabel("z (m)"), ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
