"""An autoencoder that compresses the scene part d_E of the GFCS problem encoding (gfcs_paper §IV-B:
"reduced by an autoencoder when large"): MLP n -> hidden -> latent -> hidden -> n, fitted by
optax Adam on the training problems' distance vectors before the energy model sees them."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx


class DistanceAE(nnx.Module):
    def __init__(self, n: int, latent: int, hidden: int = 256, *, rngs: nnx.Rngs):
        self.enc1, self.enc2 = nnx.Linear(n, hidden, rngs=rngs), nnx.Linear(hidden, latent, rngs=rngs)
        self.dec1, self.dec2 = nnx.Linear(latent, hidden, rngs=rngs), nnx.Linear(hidden, n, rngs=rngs)
        self.n, self.latent, self.width = n, latent, hidden

    def encode(self, d: jax.Array) -> jax.Array:
        return self.enc2(jax.nn.relu(self.enc1(d)))

    def __call__(self, d: jax.Array) -> jax.Array:
        return self.dec2(jax.nn.relu(self.dec1(self.encode(d))))


@nnx.jit
def _step(model: DistanceAE, opt: nnx.Optimizer, d: jax.Array) -> jax.Array:
    loss, grads = nnx.value_and_grad(lambda m: jnp.mean((m(d) - d) ** 2))(model)
    opt.update(model, grads)
    return loss


def fit(d: np.ndarray, latent: int, hidden: int = 256, steps: int = 500, lr: float = 1e-3, seed: int = 0) -> tuple[DistanceAE, list[float]]:
    """Fit on distance vectors d (P, n), full batch; returns the model and the loss (mean squared
    reconstruction error) after every step."""
    model = DistanceAE(d.shape[1], latent, hidden, rngs=nnx.Rngs(seed))
    opt = nnx.Optimizer(model, optax.adam(lr), wrt=nnx.Param)
    x = jnp.asarray(d, jnp.float32)
    return model, [float(_step(model, opt, x)) for _ in range(steps)]
