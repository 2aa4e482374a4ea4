"""The guide's network of thesis Table 3.4 (flax linen, the module library brax's PPO builds on).

BPS head: three 3-D convolutions with ReLU (8 filters k4 s2, 16 k3 s2, 32 k2 s1); exploration-map
head: (4 k4 s2, 8 k3 s2, 16 k3 s1); proprioception: one dense layer of 256, ELU; their
concatenation: an MLP 512-256-128 with ELU, then the output layer. `variant="mlp"` drops both
convolutional heads (the ablation of Table 4.2 without the BPS and map encoders).

XLA's CPU convolution, and its gradient above all, is slow; `Conv3D` therefore gathers each output
voxel's k^3 input patch with strided slices and applies the kernel as one 2-D matrix product, the
same linear map as `lax.conv_general_dilated` with VALID padding (tested against it). Dense layers
act on 2-D arrays only: on 5-D tensors their gradients were 7-20x slower here.
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp
from flax import linen as nn

BPS_HEAD = ((8, 4, 2), (16, 3, 2), (32, 2, 1))  # (filters, kernel, stride) per layer
MAP_HEAD = ((4, 4, 2), (8, 3, 2), (16, 3, 1))
PROPRIO = ("goal_keypoints", "q", "hand_keypoints", "fabric_q", "fabric_qd", "fabric_qdd", "dynamic_bps", "switch")


def patches3d(x: jax.Array, kernel: int, stride: int) -> jax.Array:
    """(B, D, H, W, C) -> (B, D', H', W', kernel^3 C): each VALID output voxel's input patch,
    ordered (offset along D, H, W, then channel) like a (k, k, k, C, F) kernel's rows."""
    out = [(n - kernel) // stride + 1 for n in x.shape[1:4]]
    if min(out) < 1:
        raise ValueError(f"input of spatial shape {x.shape[1:4]} is smaller than the kernel {kernel}")
    parts = [
        x[:, i : i + stride * (out[0] - 1) + 1 : stride, j : j + stride * (out[1] - 1) + 1 : stride, k : k + stride * (out[2] - 1) + 1 : stride]
        for i in range(kernel)
        for j in range(kernel)
        for k in range(kernel)
    ]
    return jnp.concatenate(parts, axis=-1)


class Conv3D(nn.Module):
    """A VALID 3-D convolution as strided-slice patches times a 2-D kernel matrix."""

    features: int
    kernel: int
    stride: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        c = x.shape[-1]
        w = self.param("kernel", nn.initializers.lecun_normal(), (self.kernel, self.kernel, self.kernel, c, self.features))
        b = self.param("bias", nn.initializers.zeros, (self.features,))
        p = patches3d(x, self.kernel, self.stride)
        y = p.reshape(-1, p.shape[-1]) @ w.reshape(-1, self.features) + b
        return y.reshape(*p.shape[:-1], self.features)


class Encoder3D(nn.Module):
    layers: Sequence[tuple[int, int, int]]

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for features, kernel, stride in self.layers:
            x = nn.relu(Conv3D(features, kernel, stride)(x))
        return x.reshape(x.shape[0], -1)


class GuideNetwork(nn.Module):
    """Table 3.4 on a batch of observation dicts (leading batch axis); returns (B, outputs)."""

    outputs: int
    variant: str = "conv"  # conv | mlp
    hidden: Sequence[int] = (512, 256, 128)

    @nn.compact
    def __call__(self, obs: dict[str, jax.Array]) -> jax.Array:
        batch = obs["q"].shape[0]
        proprio = jnp.concatenate([obs[k].reshape(batch, -1) for k in PROPRIO], axis=-1)
        parts = [nn.elu(nn.Dense(256)(proprio))]
        if self.variant == "conv":
            parts += [Encoder3D(BPS_HEAD)(obs["bps"]), Encoder3D(MAP_HEAD)(obs["exploration"])]
        elif self.variant != "mlp":
            raise ValueError(f"network variant must be 'conv' or 'mlp', got '{self.variant}'")
        x = jnp.concatenate(parts, axis=-1)
        for width in self.hidden:
            x = nn.elu(nn.Dense(width)(x))
        return nn.Dense(self.outputs)(x)
