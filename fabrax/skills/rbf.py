"""RBF precision networks whose variance grows away from the data (paper §3.1.4).

beta(z) = exp(W)^T phi(z) + zeta with phi_k(z) = exp(-lambda_k |z - c_k|^2):
near the latent codes the learned positive weights give a high precision (low
variance); far from every centre phi -> 0 and the precision falls to zeta, so
the variance 1 / beta rises to 1 / zeta (Arvanitidis et al. 2018, which the
paper follows). Centres come from k-means on the training codes, bandwidths
from each cluster's spread.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from scipy.cluster.vq import kmeans2


class RBFWeight(nnx.Param):
    """Trainable RBF output weights: the only parameters of the second training stage."""


class RBFPrecision(nnx.Module):
    def __init__(self, latent: int, out: int, centers: int, zeta: float, *, rngs: nnx.Rngs):
        self.centers = nnx.Variable(jnp.zeros((centers, latent)))
        self.lam = nnx.Variable(jnp.ones((centers,)))
        self.weight = RBFWeight(0.01 * jax.random.normal(rngs.params(), (centers, out)))  # log weights
        self.zeta = nnx.Variable(jnp.asarray(zeta, jnp.float32))

    def __call__(self, z: jax.Array) -> jax.Array:
        d2 = jnp.sum((z[None, :] - self.centers[...]) ** 2, axis=-1)
        return jnp.exp(-self.lam[...] * d2) @ jnp.exp(self.weight[...]) + self.zeta[...]

    def place(self, codes: np.ndarray, bandwidth: float, precision, seed: int = 0) -> None:
        """Centres by k-means on `codes` (n, d); lambda_k = 0.5 / (bandwidth * spread_k)^2; every weight
        starts at `precision` (out,) (the first stage's global value), so training refines rather than grows it."""
        centers, labels = kmeans(codes, self.centers.shape[0], seed)
        spread = np.array(
            [np.sqrt(np.mean(np.sum((codes[labels == k] - centers[k]) ** 2, -1))) if np.any(labels == k) else 0.0 for k in range(len(centers))]
        )
        spread = np.maximum(spread, 0.1 * np.median(spread[spread > 0]) if np.any(spread > 0) else 1.0)
        self.centers[...] = jnp.asarray(centers, jnp.float32)
        self.lam[...] = jnp.asarray(0.5 / (bandwidth * spread) ** 2, jnp.float32)
        self.weight[...] = self.weight[...] + jnp.log(jnp.broadcast_to(jnp.asarray(precision, jnp.float32), self.weight.shape[1:]))


def kmeans(x: np.ndarray, k: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """k-means++ then Lloyd iterations (scipy's kmeans2); (centres (k, d), labels (n,)). k is capped at the number of points."""
    x = np.asarray(x, np.float64)
    return kmeans2(x, min(k, len(x)), minit="++", seed=seed)
