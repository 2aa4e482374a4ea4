"""The energy-based sampler of GFCS (gfcs_paper §IV-B): E_theta(x_c, y), InfoNCE, SGLD.

Targets y are command sequences normalised to [0, 1]^(n dof) within the joint
limits. Low energy marks good (context, target) pairs: the InfoNCE loss of
eq. 9 is the cross-entropy of softmax(-E) over one positive and N_neg
negatives. Negatives and warm-start samples come from SGLD (eqs. 10-11):
particles start uniform in the limits and descend the energy with Gaussian
noise, sigma_k^2 = (1 + k)^-0.5 scaled by `step` (eq. 10 is written as
ascent; with e^-E for positives in eq. 9 the consistent direction is descent),
clipped to the limits after every step.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax import nnx


class EnergyModel(nnx.Module):
    """MLP 3 x 800 ReLU (gfcs_paper) mapping concat(x_c, y) to a scalar energy."""

    def __init__(self, context_dim: int, target_dim: int, hidden: int = 800, layers: int = 3, *, rngs: nnx.Rngs):
        dims = [context_dim + target_dim] + [hidden] * layers
        self.hidden = nnx.List([nnx.Linear(a, b, rngs=rngs) for a, b in zip(dims[:-1], dims[1:], strict=True)])
        self.out = nnx.Linear(hidden, 1, rngs=rngs)
        self.context_dim, self.target_dim = context_dim, target_dim

    def __call__(self, x: jax.Array, y: jax.Array) -> jax.Array:
        return self.given(self.context(x), y)

    def context(self, x: jax.Array) -> jax.Array:
        """The context's share of the first layer, W_x x + b: computed once per context, since
        SGLD moves only y and the context (d_E, ~1,900 numbers) dwarfs the target (n dof)."""
        first = self.hidden[0]
        return x @ first.kernel[: self.context_dim] + first.bias

    def given(self, hx: jax.Array, y: jax.Array) -> jax.Array:
        """E(x, y) from `context(x)` (broadcast against y's batch axes): the MLP on concat(x, y)."""
        h = jax.nn.relu(hx + y @ self.hidden[0].kernel[self.context_dim :])
        for layer in self.hidden[1:]:
            h = jax.nn.relu(layer(h))
        return self.out(h)[..., 0]


@dataclasses.dataclass(frozen=True)
class SGLDConfig:
    steps: int = 50
    step: float = 0.01  # scales sigma_k^2 = (1 + k)^-0.5 (targets live in [0, 1])
    noise: float = 0.1  # scales the Langevin noise; 1 is the textbook sqrt(sigma_k^2)


def sgld(model: EnergyModel, x: jax.Array, key: jax.Array, n: int, cfg: SGLDConfig = SGLDConfig()) -> jax.Array:
    """n samples y (n, target_dim) in [0, 1] for one context x (context_dim,)."""
    k0, key = jax.random.split(key)
    y0 = jax.random.uniform(k0, (n, model.target_dim))
    hx = model.context(x)
    grad = jax.grad(lambda y: jnp.sum(model.given(hx, y)))

    def body(y, kk):
        k, sub = kk
        sigma2 = cfg.step * (1.0 + k) ** -0.5
        y = y - 0.5 * sigma2 * grad(y) + cfg.noise * jnp.sqrt(sigma2) * jax.random.normal(sub, y.shape)
        return jnp.clip(y, 0.0, 1.0), None

    keys = jax.random.split(key, cfg.steps)
    y, _ = jax.lax.scan(body, y0, (jnp.arange(cfg.steps, dtype=jnp.float32), keys))
    return y


def info_nce(model: EnergyModel, x: jax.Array, y_pos: jax.Array, y_neg: jax.Array) -> jax.Array:
    """Mean InfoNCE loss (eq. 9): x (B, C), y_pos (B, D), y_neg (B, N_neg, D)."""
    hx = model.context(x)
    e_pos = model.given(hx, y_pos)
    e_neg = model.given(hx[:, None], y_neg)
    logits = -jnp.concatenate([e_pos[:, None], e_neg], axis=1)
    return jnp.mean(optax.softmax_cross_entropy_with_integer_labels(logits, jnp.zeros(len(x), jnp.int32)))


@nnx.jit(static_argnames=("n_neg", "sgld_cfg"))
def train_step(model: EnergyModel, opt: nnx.Optimizer, x, y_pos, key, n_neg: int, sgld_cfg: SGLDConfig):
    """One Adam step on InfoNCE with fresh SGLD negatives for every positive."""
    keys = jax.random.split(key, len(x))
    y_neg = jax.lax.stop_gradient(jax.vmap(lambda xi, k: sgld(model, xi, k, n_neg, sgld_cfg))(x, keys))
    loss, grads = nnx.value_and_grad(info_nce)(model, x, y_pos, y_neg)
    opt.update(model, grads)
    return loss
