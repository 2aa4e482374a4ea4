"""The guide's network of thesis Table 3.4 (flax linen, the module library brax's PPO builds on).

BPS head: three 3-D convolutions with ReLU (8 filters k4 s2, 16 k3 s2, 32 k2 s1); exploration-map
head: (4 k4 s2, 8 k3 s2, 16 k3 s1); proprioception: one dense layer of 256, ELU; their
concatenation: an MLP 512-256-128 with ELU, then the output layer. `variant="mlp"` drops both
convolutional heads (the ablation of Table 4.2 without the BPS and map encoders).

The actor's Gaussian (brax's tanh-squashed normal) has one learned scale per action dimension,
shared by every state (`std="global"`), as rl-games' `fixed_sigma` (the thesis' PPO) and brax's
own PPO networks have it, and a pre-tanh mean bounded softly to +-`loc_bound`, b tanh(x / b) of the
network's output x (slope 1 at 0, so the bound leaves small means' updates as they were; brax's
`mean_clip_scale` bounds with slope b; rl-games keeps its means in bounds with a loss). A scale output per state
(`std="state"`, how earlier guides were trained) can collapse to the distribution's floor (0.001)
on a few states; an unbounded mean drifts far past tanh's range, where moving it changes no action.
In both cases PPO's KL between successive policies (brax's, on the pre-tanh Gaussians) is dominated
by states whose squashed actions barely moved, and the clipped objective does not hold them back.

XLA's CPU convolution, and its gradient above all, is slow; `Conv3D` therefore gathers each output
voxel's input patch (`block_patches3d`: slices of the space-to-depth input, few kernels to compile)
and applies the kernel as one 2-D matrix product, the same linear map as `lax.conv_general_dilated`
with VALID padding (tested against it). Dense layers
act on 2-D arrays only: on 5-D tensors their gradients were 7-20x slower here. A deployed guide
(`fabrax.rl.policy.load_guide`, no gradients) convolves by `shift_conv3d` instead, the same map
again: space-to-depth by a reshape, one matrix product, then a sum of shifted slices. Its forward
pass is the faster one on the CPU, its gradient the slower (docs/results.md, "Reaction time").
"""

from __future__ import annotations

import functools
import math
from typing import Sequence

import jax
import jax.numpy as jnp
from flax import linen as nn

from fabrax.settings import check_keys

BPS_HEAD = ((8, 4, 2), (16, 3, 2), (32, 2, 1))  # (filters, kernel, stride) per layer
# Normalised observations are clipped to +-OBS_CLIP standard deviations, as rl-games (the thesis' PPO)
# and IsaacGym tasks clip theirs. brax's running normaliser divides by a std floored at 1e-6 and does
# not clip: the `switch` observation is 0 throughout curriculum stage 1, so the first 1 (stage 2, and
# every evaluation, which runs in stage 2) reached the actor as ~1e6 and its outputs saturated.
OBS_CLIP = 5.0
MAP_HEAD = ((4, 4, 2), (8, 3, 2), (16, 3, 1))
GRIDS = ("bps", "exploration")  # 3-D inputs: given to PPO as "pixels/<name>", which brax's normaliser leaves out
PROPRIO = ("goal_keypoints", "q", "hand_keypoints", "fabric_q", "fabric_qd", "fabric_qdd", "dynamic_bps", "switch")


def _valid_out(spatial: tuple[int, ...], kernel: int, stride: int) -> list[int]:
    """Output sides of a VALID convolution, refused in one line where the input is smaller than the kernel."""
    out = [(n - kernel) // stride + 1 for n in spatial]
    if min(out) < 1:
        raise ValueError(f"input of spatial shape {tuple(spatial)} is smaller than the kernel {kernel}")
    return out


def block_patches3d(x: jax.Array, kernel: int, stride: int) -> jax.Array:
    """(B, D, H, W, C) -> (B, D', H', W', (a s)^3 C) with a = ceil(kernel / stride): each VALID
    output voxel's input patch, gathered block-wise. Writing a kernel offset i = s a + b (s the
    stride, b < s), output voxel o reads input s (o + a) + b, i.e. block o + a of the space-to-depth
    input y[u, b] = x[s u + b]: a^3 slices of y (8 for Table 3.4's strided layers) instead of k^3
    (64 for a 4-kernel) strided slices of x, each one more kernel for XLA to compile, forward and
    backward. Rows are ordered (a along D, H, W, b along D, H, W, channel) as `block_kernel` orders
    the kernel's; offsets past the kernel (s not dividing k) and the zero padding to whole blocks
    meet its zero rows."""
    s, batch, c = stride, x.shape[0], x.shape[-1]
    out = _valid_out(x.shape[1:4], kernel, s)
    ka = -(-kernel // s)
    blocks = [o + ka - 1 for o in out]
    need = [b * s for b in blocks]
    x = jnp.pad(x, [(0, 0)] + [(0, max(0, m - n)) for m, n in zip(need, x.shape[1:4])] + [(0, 0)])[:, : need[0], : need[1], : need[2]]
    y = x.reshape(batch, blocks[0], s, blocks[1], s, blocks[2], s, c).transpose(0, 1, 3, 5, 2, 4, 6, 7)
    y = y.reshape(batch, *blocks, s**3 * c)
    parts = [y[:, i : i + out[0], j : j + out[1], m : m + out[2]] for i in range(ka) for j in range(ka) for m in range(ka)]
    return jnp.concatenate(parts, axis=-1) if len(parts) > 1 else parts[0]


def block_kernel(w: jax.Array, stride: int) -> jax.Array:
    """A (k, k, k, C, F) kernel as the ((a s)^3 C, F) matrix `block_patches3d`'s rows meet: zero
    rows for offsets past k."""
    k, c, f = w.shape[0], w.shape[3], w.shape[4]
    s, ka = stride, -(-w.shape[0] // stride)
    wb = jnp.pad(w, [(0, ka * s - k)] * 3 + [(0, 0), (0, 0)]).reshape(ka, s, ka, s, ka, s, c, f)
    return wb.transpose(0, 2, 4, 1, 3, 5, 6, 7).reshape(ka**3 * s**3 * c, f)


def shift_conv3d(x: jax.Array, w: jax.Array, stride: int) -> jax.Array:
    """VALID 3-D convolution of x (B, D, H, W, C) with w (k, k, k, C, F), forward only.

    Writing a kernel offset i = s a + b (s the stride, a < ceil(k/s), b < s), output voxel o reads
    input s (o + a) + b: on the space-to-depth input y[u, b] = x[s u + b] the convolution is
    sum_a y[o + a] W_a, a stride-1 convolution with a kernel of ceil(k/s) blocks. One matrix product
    gives every y[u] W_a; the sum over a adds shifted slices of it. Offsets past k (when s does not
    divide k) get zero weights, and the input is zero-padded to whole blocks (those rows meet only
    zero weights)."""
    k, c, f = w.shape[0], w.shape[3], w.shape[4]
    s, batch = stride, x.shape[0]
    out = _valid_out(x.shape[1:4], k, s)
    ka = -(-k // s)  # kernel blocks per axis
    blocks = [o + ka - 1 for o in out]
    need = [b * s for b in blocks]
    x = jnp.pad(x, [(0, 0)] + [(0, max(0, m - n)) for m, n in zip(need, x.shape[1:4])] + [(0, 0)])[:, : need[0], : need[1], : need[2]]
    y = x.reshape(batch, blocks[0], s, blocks[1], s, blocks[2], s, c).transpose(0, 1, 3, 5, 2, 4, 6, 7)
    wb = jnp.pad(w, [(0, ka * s - k)] * 3 + [(0, 0), (0, 0)]).reshape(ka, s, ka, s, ka, s, c, f)
    wb = wb.transpose(1, 3, 5, 6, 0, 2, 4, 7).reshape(s**3 * c, ka**3 * f)  # rows (b, c), columns (a, f)
    z = (y.reshape(-1, s**3 * c) @ wb).reshape(batch, *blocks, ka, ka, ka, f)
    shifted = [z[:, i : i + out[0], j : j + out[1], m : m + out[2], i, j, m] for i in range(ka) for j in range(ka) for m in range(ka)]
    return functools.reduce(jnp.add, shifted)


def _as_matrix(init):
    """`init` drawn as the (prod(shape[:-1]), shape[-1]) matrix the kernel is applied as, reshaped:
    the same fan-in and, as jax draws the bits of the flat array, the same values as a draw of the
    5-D shape, whose XLA program compiles far more slowly on a CPU (every PPO start initialises
    the networks)."""

    def matrix_init(key, shape, dtype=jnp.float32):
        return init(key, (math.prod(shape[:-1]), shape[-1]), dtype).reshape(shape)

    return matrix_init


class Conv3D(nn.Module):
    """A VALID 3-D convolution as block patches times a 2-D kernel matrix (`shift`: by
    `shift_conv3d`, the same map with the faster forward pass and the slower gradient)."""

    features: int
    kernel: int
    stride: int
    shift: bool = False

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        c = x.shape[-1]
        w = self.param("kernel", _as_matrix(nn.initializers.lecun_normal()), (self.kernel, self.kernel, self.kernel, c, self.features))
        b = self.param("bias", nn.initializers.zeros, (self.features,))
        if self.shift:
            return shift_conv3d(x, w, self.stride) + b
        p = block_patches3d(x, self.kernel, self.stride)
        y = p.reshape(-1, p.shape[-1]) @ block_kernel(w, self.stride) + b
        return y.reshape(*p.shape[:-1], self.features)


class Encoder3D(nn.Module):
    layers: Sequence[tuple[int, int, int]]
    shift: bool = False

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for features, kernel, stride in self.layers:
            x = nn.relu(Conv3D(features, kernel, stride, self.shift)(x))
        return x.reshape(x.shape[0], -1)


class GuideNetwork(nn.Module):
    """Table 3.4 on a batch of observation dicts (leading batch axis); returns (B, outputs)."""

    outputs: int
    variant: str = "conv"  # conv | mlp
    hidden: Sequence[int] = (512, 256, 128)
    shift: bool = False  # convolve by `shift_conv3d` (a deployed guide: forward passes only)

    @nn.compact
    def __call__(self, obs: dict[str, jax.Array]) -> jax.Array:
        batch = obs["q"].shape[0]
        proprio = jnp.concatenate([obs[k].reshape(batch, -1) for k in PROPRIO], axis=-1)
        parts = [nn.elu(nn.Dense(256)(proprio))]
        if self.variant == "conv":
            parts += [Encoder3D(BPS_HEAD, self.shift)(obs["bps"]), Encoder3D(MAP_HEAD, self.shift)(obs["exploration"])]
        elif self.variant != "mlp":
            raise ValueError(f"network variant must be 'conv' or 'mlp', got '{self.variant}'")
        x = jnp.concatenate(parts, axis=-1)
        for width in self.hidden:
            x = nn.elu(nn.Dense(width)(x))
        return nn.Dense(self.outputs)(x)


STDS = ("global", "state")
DEFAULTS = {"variant": "conv", "hidden": (512, 256, 128), "std": "global", "loc_bound": 3.0}  # configs/rl.yaml's `network`
# what a checkpoint or settings.json without these network keys was trained with
LEGACY = {"std": "state", "loc_bound": None}


def network_settings(network: dict | None) -> dict:
    """`network` settings with `DEFAULTS` filled in and checked, refused in one line naming the key:
    variant conv | mlp, hidden widths, std global | state, loc_bound a positive number or None."""
    net = {**DEFAULTS, **dict(network or {})}
    check_keys(net, tuple(DEFAULTS), "rl network")
    if net["variant"] not in ("conv", "mlp"):
        raise ValueError(f"network.variant must be 'conv' or 'mlp', got {net['variant']!r}")
    if net["std"] not in STDS:
        raise ValueError(f"network.std must be one of {', '.join(STDS)}, got {net['std']!r}")
    bound = net["loc_bound"]
    if bound is not None and (isinstance(bound, bool) or not isinstance(bound, (int, float)) or not bound > 0):
        raise ValueError(f"network.loc_bound must be a positive number or null, got {bound!r}")
    return {**net, "hidden": [int(h) for h in net["hidden"]], "loc_bound": None if bound is None else float(bound)}


class GuidePolicy(nn.Module):
    """The actor with one learned, state-independent pre-softplus scale per action dimension
    (`std="global"`): outputs (B, 2 x actions), locs then scales, as brax's tanh-Gaussian reads them.
    The scale parameter starts at 0, the scale a zero network output gives (softplus(0) = 0.69)."""

    actions: int
    variant: str = "conv"
    hidden: Sequence[int] = (512, 256, 128)
    shift: bool = False

    @nn.compact
    def __call__(self, obs: dict[str, jax.Array]) -> jax.Array:
        loc = GuideNetwork(self.actions, self.variant, self.hidden, self.shift)(obs)
        scale = self.param("std", nn.initializers.zeros, (self.actions,))
        return jnp.concatenate([loc, jnp.broadcast_to(scale, loc.shape)], axis=-1)


def ppo_observation(obs: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """The env's observations as PPO sees them: the grids renamed "pixels/<name>" (brax's running
    normaliser needs inputs of one rank and skips "pixels/" keys; the grids stay unnormalised)."""
    return {("pixels/" + k if k in GRIDS else k): v for k, v in obs.items()}


def env_observation(obs: dict) -> dict:
    """`ppo_observation`'s inverse: the env's own names."""
    return {k.removeprefix("pixels/"): v for k, v in obs.items()}


def _flat_apply(module: nn.Module, shapes: dict[str, tuple[int, ...]], variables, obs: dict[str, jax.Array]) -> jax.Array:
    """Apply `module` to observations with any leading batch axes (PPO's unrolls are (B, T, ...))."""
    lead = obs["q"].shape[: obs["q"].ndim - len(shapes["q"])]
    flat = {k: obs[k].reshape((-1,) + tuple(shapes[k])) for k in shapes}
    out = module.apply(variables, flat)
    return out.reshape(lead + out.shape[-1:])


def _split(obs: dict):
    return {k: v for k, v in obs.items() if not k.startswith("pixels/")}, {k[len("pixels/") :]: v for k, v in obs.items() if k.startswith("pixels/")}


def make_guide_networks(
    observation_size: dict[str, tuple[int, ...]],
    action_size: int,
    preprocess_observations_fn=None,
    variant: str = DEFAULTS["variant"],
    hidden: Sequence[int] = DEFAULTS["hidden"],
    std: str = DEFAULTS["std"],
    loc_bound: float | None = DEFAULTS["loc_bound"],
    shift: bool = False,
):
    """brax `network_factory` for `ppo.train`: actor and critic are each a `GuideNetwork` (Table
    3.4; separate parameters), the actor's outputs the mean and scale of brax's tanh-squashed
    Gaussian over the action box [-1, 1], the scale one learned value per action dimension
    (`std="global"`, `GuidePolicy`) or an output of the network (`std="state"`).
    `loc_bound` bounds the Gaussian's pre-tanh mean softly to (-loc_bound, loc_bound) (None: unbounded).
    `preprocess_observations_fn` is brax's normaliser (identity by default); `variant`, `hidden`,
    `std` and `loc_bound` are plain values, so brax's checkpoints record them. `shift` convolves by
    `shift_conv3d` (same parameters, same map): for a deployed guide, never for training."""
    from brax.training import distribution, networks, types
    from brax.training.acme import running_statistics
    from brax.training.agents.ppo.networks import PPONetworks

    preprocess = preprocess_observations_fn or types.identity_observation_preprocessor
    if preprocess is running_statistics.normalize:  # normalised observations clipped to +-OBS_CLIP (see OBS_CLIP)
        preprocess = functools.partial(running_statistics.normalize, max_abs_value=OBS_CLIP)
    if not isinstance(observation_size, dict) or "q" not in observation_size or "pixels/bps" not in observation_size:
        raise ValueError("the guide's networks need the environment's dict observations as `ppo_observation` names them")
    net = network_settings({"variant": variant, "hidden": hidden, "std": std, "loc_bound": loc_bound})
    hidden, loc_bound = tuple(net["hidden"]), net["loc_bound"]  # a checkpoint's JSON gives a list
    shapes = {k.removeprefix("pixels/"): tuple(v) for k, v in observation_size.items()}
    dist = distribution.NormalTanhDistribution(event_size=action_size)

    def network(outputs: int, actor: bool = False):
        if actor and std == "global":
            module = GuidePolicy(outputs // 2, variant, hidden, shift)
        else:
            module = GuideNetwork(outputs, variant=variant, hidden=hidden, shift=shift)
        dummy = {k: jnp.zeros((1,) + s) for k, s in shapes.items()}

        def apply(processor_params, params, obs):
            vectors, grids = _split(obs)  # the normaliser's statistics cover the vectors only
            out = _flat_apply(module, shapes, params, {**preprocess(vectors, processor_params), **grids})
            if actor and loc_bound is not None:  # loc = b tanh(x / b): slope 1 at 0, |loc| < b
                loc, scale = jnp.split(out, 2, axis=-1)
                out = jnp.concatenate([loc_bound * jnp.tanh(loc / loc_bound), scale], axis=-1)
            return out

        # one compiled program for the whole initialisation, not one per operation of the forward pass
        return networks.FeedForwardNetwork(init=jax.jit(lambda key: module.init(key, dummy)), apply=apply)

    policy, value = network(dist.param_size, actor=True), network(1)
    value_apply = value.apply
    value = networks.FeedForwardNetwork(init=value.init, apply=lambda *a: value_apply(*a)[..., 0])
    return PPONetworks(policy_network=policy, value_network=value, parametric_action_distribution=dist)
