"""The guide's network (thesis Table 3.4): the patch-matmul 3-D convolution is lax's convolution,
value and gradient, and so is the shift-add one's value; the network takes the env's observation dict."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fabrax.rl.networks import Conv3D, GuideNetwork

LAYERS = [((2, 16, 16, 16, 3), 4, 2), ((2, 7, 7, 7, 8), 3, 2), ((1, 9, 9, 9, 4), 3, 1), ((1, 3, 3, 3, 16), 2, 1)]  # Table 3.4's shapes
LAYERS += [((1, 20, 20, 20, 1), 4, 2), ((1, 5, 6, 7, 2), 3, 3)]  # the map head's first layer; stride = kernel, uneven sides


@pytest.mark.parametrize("shape, kernel, stride", LAYERS)
def test_conv3d_is_lax_convolution_value_and_gradient(shape, kernel, stride):
    x = jax.random.normal(jax.random.PRNGKey(0), shape)
    conv = Conv3D(5, kernel, stride)
    params = conv.init(jax.random.PRNGKey(1), x)
    w, b = params["params"]["kernel"], params["params"]["bias"] + 0.3

    def reference(w, x):
        return jax.lax.conv_general_dilated(x, w, (stride,) * 3, "VALID", dimension_numbers=("NDHWC", "DHWIO", "NDHWC")) + b

    def ours(w, x):
        return conv.apply({"params": {"kernel": w, "bias": b}}, x)

    np.testing.assert_allclose(jax.jit(ours)(w, x), jax.jit(reference)(w, x), rtol=1e-4, atol=1e-4)
    shifted = Conv3D(5, kernel, stride, shift=True)  # the deployed guide's forward pass, same parameters
    np.testing.assert_allclose(jax.jit(shifted.apply)({"params": {"kernel": w, "bias": b}}, x), jax.jit(reference)(w, x), rtol=1e-4, atol=1e-4)
    grad = lambda f: jax.jit(jax.grad(lambda w, x: jnp.sum(jnp.sin(f(w, x))), argnums=(0, 1)))  # noqa: E731
    for a, r in zip(grad(ours)(w, x), grad(reference)(w, x)):
        np.testing.assert_allclose(a, r, rtol=1e-3, atol=1e-3)


def test_guide_network_on_env_observations(panda):
    """Observations of the env's shapes (`FabricGuideEnv.observation_size`, without building a scene pool)."""
    from types import SimpleNamespace

    from fabrax.rl import FabricGuideEnv, env_config

    shapes = FabricGuideEnv.observation_size.fget(SimpleNamespace(cfg=env_config({}), robot=panda))
    keys = jax.random.split(jax.random.PRNGKey(0), len(shapes))
    obs = {k: jax.random.normal(key, (3, *shape)) for key, (k, shape) in zip(keys, sorted(shapes.items()))}
    action_size = 6 + panda.dof + 1
    for variant in ("conv", "mlp"):
        net = GuideNetwork(2 * action_size, variant)
        params = jax.jit(net.init)(jax.random.PRNGKey(1), obs)
        out = jax.jit(net.apply)(params, obs)
        assert out.shape == (3, 2 * action_size) and bool(jnp.all(jnp.isfinite(out)))
        convs = [k for k in jax.tree_util.tree_flatten_with_path(params)[0] if "Conv3D" in jax.tree_util.keystr(k[0])]
        assert (len(convs) == 12) == (variant == "conv")  # 2 heads x 3 layers x (kernel, bias)
    with pytest.raises(ValueError, match="variant"):
        GuideNetwork(4, "cnn").init(jax.random.PRNGKey(1), obs)


def _dense(n_in: int, n_out: int) -> int:
    return n_in * n_out + n_out


def _head(layers, cells: int, channels: int) -> tuple[int, int]:
    """Parameters and flattened output size of a Table 3.4 conv head, by hand."""
    params = 0
    for features, kernel, stride in layers:
        params += kernel**3 * channels * features + features
        cells, channels = (cells - kernel) // stride + 1, features
    return params, cells**3 * channels


@pytest.mark.parametrize("variant,std", [("conv", "global"), ("mlp", "global"), ("conv", "state")])
def test_ppo_factory_shapes_and_parameter_counts_match_table_3_4(panda, variant, std):
    from types import SimpleNamespace

    from fabrax.rl import FabricGuideEnv, env_config
    from fabrax.rl.networks import BPS_HEAD, MAP_HEAD, make_guide_networks, ppo_observation

    shapes = FabricGuideEnv.observation_size.fget(SimpleNamespace(cfg=env_config({}), robot=panda))
    sizes = {k: tuple(v) for k, v in ppo_observation(shapes).items()}
    action = 6 + panda.dof + 1
    nets = make_guide_networks(sizes, action, variant=variant, std=std)
    deployed = make_guide_networks(sizes, action, variant=variant, std=std, shift=True)  # load_guide's
    proprio = 24 + panda.dof + 24 + 3 * panda.dof + panda.n_spheres + 1
    bps_p, bps_out = _head(BPS_HEAD, 16, 3)
    map_p, map_out = _head(MAP_HEAD, 20, 1)
    assert (bps_out, map_out) == (256, 128)  # 2^3 x 32 and 2^3 x 16 voxels
    width = 256 + (bps_out + map_out if variant == "conv" else 0)
    trunk = _dense(proprio, 256) + _dense(width, 512) + _dense(512, 256) + _dense(256, 128) + (bps_p + map_p if variant == "conv" else 0)
    obs = {k: jax.random.normal(jax.random.PRNGKey(i), (3, 2) + s) for i, (k, s) in enumerate(sizes.items())}  # PPO's (batch, unroll, ...)
    policy_head = _dense(128, action) + action if std == "global" else _dense(128, 2 * action)  # locs and one scale each, or both per state
    pairs = ((nets.policy_network, deployed.policy_network), (nets.value_network, deployed.value_network))
    for (net, shifted), outputs, head in zip(pairs, (2 * action, None), (policy_head, _dense(128, 1))):
        params = net.init(jax.random.PRNGKey(0))
        n = sum(x.size for x in jax.tree.leaves(params))
        assert n == trunk + head
        assert jax.tree.structure(shifted.init(jax.random.PRNGKey(0))) == jax.tree.structure(params)
        out = net.apply(None, params, obs)
        np.testing.assert_allclose(shifted.apply(None, params, obs), out, rtol=1e-4, atol=1e-4)
        assert out.shape == ((3, 2, outputs) if outputs else (3, 2))
        if outputs:
            locs, scales = np.asarray(out[..., :action]).reshape(6, -1), np.asarray(out[..., action:]).reshape(6, -1)
            assert np.ptp(locs, axis=0).min() > 0  # the locs follow the state
            if std == "global":  # one scale per action dimension, the same in every state
                np.testing.assert_array_equal(scales, np.broadcast_to(scales[0], scales.shape))
            else:
                assert np.ptp(scales, axis=0).min() > 0


def test_bounded_loc_stays_inside_its_bound_and_keeps_the_parameters(panda):
    """`loc_bound`: the pre-tanh mean b tanh(x / b) of the unbounded network's x, scales untouched."""
    from types import SimpleNamespace

    from fabrax.rl import FabricGuideEnv, env_config
    from fabrax.rl.networks import make_guide_networks, ppo_observation

    shapes = FabricGuideEnv.observation_size.fget(SimpleNamespace(cfg=env_config({}), robot=panda))
    sizes = {k: tuple(v) for k, v in ppo_observation(shapes).items()}
    action = 6 + panda.dof + 1
    free = make_guide_networks(sizes, action, variant="mlp", hidden=(16,), loc_bound=None).policy_network
    bound = make_guide_networks(sizes, action, variant="mlp", hidden=(16,), loc_bound=2.0).policy_network
    params = free.init(jax.random.PRNGKey(0))
    params = jax.tree.map(lambda x: 3.0 * x, params)  # larger outputs: past the bound
    obs = {k: jax.random.normal(jax.random.PRNGKey(i), (16,) + s) for i, (k, s) in enumerate(sizes.items())}
    x, y = free.apply(None, params, obs), bound.apply(None, params, obs)
    assert float(jnp.abs(x[:, :action]).max()) > 2.0 and float(jnp.abs(y[:, :action]).max()) <= 2.0
    np.testing.assert_allclose(y[:, :action], 2.0 * jnp.tanh(x[:, :action] / 2.0), rtol=1e-6)
    np.testing.assert_array_equal(y[:, action:], x[:, action:])
    with pytest.raises(ValueError, match="network.loc_bound"):
        make_guide_networks(sizes, action, loc_bound=-1.0)


def test_unknown_std_is_refused_by_name(panda):
    from types import SimpleNamespace

    from fabrax.rl import FabricGuideEnv, env_config
    from fabrax.rl.networks import make_guide_networks, ppo_observation

    shapes = FabricGuideEnv.observation_size.fget(SimpleNamespace(cfg=env_config({}), robot=panda))
    with pytest.raises(ValueError, match="network.std"):
        make_guide_networks({k: tuple(v) for k, v in ppo_observation(shapes).items()}, 14, std="fixed")


def test_normalised_observations_are_clipped_so_a_constant_feature_cannot_explode(panda):
    """A feature that was constant while the normaliser learned its statistics (the switch through
    curriculum stage 1) has std 1e-6 in brax's normaliser; its first change must reach the actor
    bounded (OBS_CLIP standard deviations), not as ~1e6."""
    from types import SimpleNamespace

    from brax.training.acme import running_statistics

    from fabrax.rl import FabricGuideEnv, env_config
    from fabrax.rl.networks import _split, make_guide_networks, ppo_observation

    shapes = FabricGuideEnv.observation_size.fget(SimpleNamespace(cfg=env_config({}), robot=panda))
    sizes = {k: tuple(v) for k, v in ppo_observation(shapes).items()}
    nets = make_guide_networks(sizes, 6 + panda.dof + 1, preprocess_observations_fn=running_statistics.normalize, variant="mlp", hidden=(16,))
    params = nets.policy_network.init(jax.random.PRNGKey(0))
    obs = {k: jax.random.normal(jax.random.PRNGKey(i), (32,) + s) for i, (k, s) in enumerate(sizes.items())}
    obs["switch"] = jnp.zeros_like(obs["switch"])  # stage 1: always off
    vectors, _ = _split(obs)
    stats = running_statistics.update(running_statistics.init_state(jax.tree.map(lambda x: x[0], vectors)), vectors)
    assert float(stats.std["switch"].min()) <= 1e-6

    def act(switch):
        return nets.policy_network.apply(stats, params, {**obs, "switch": jnp.full_like(obs["switch"], switch)})

    off, on, far = act(0.0), act(1.0), act(1e3)
    assert bool(jnp.all(jnp.isfinite(on))) and not np.allclose(off, on)
    np.testing.assert_allclose(on, far, rtol=1e-5, atol=1e-5)  # both clipped to +OBS_CLIP


def test_convolutions_refuse_an_input_smaller_than_the_kernel():
    from fabrax.rl.networks import block_patches3d, shift_conv3d

    x = jnp.zeros((1, 3, 8, 8, 2))
    with pytest.raises(ValueError, match="smaller than the kernel 4"):
        block_patches3d(x, 4, 2)
    with pytest.raises(ValueError, match="smaller than the kernel 4"):
        shift_conv3d(x, jnp.zeros((4, 4, 4, 2, 5)), 2)
