"""Merel et al. 2020's network (`network.architecture: merel`, vnl.ppo.merel): the core trained by
the value alone, the policy's cores reading it through a stop-gradient, a ResNet per camera, the
parameters split between PPO's policy and value, and a run trained, resumed, recorded and loaded."""

import json

import jax
import jax.numpy as jp
import numpy as np
import pytest
import xarray as xr
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo.losses import PPONetworkParams

from vnl.cli import main
from vnl.envs import registry
from vnl.envs.wrappers import wrap_for_training
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.policy import RecurrentPolicy, load_policy
from vnl.ppo.merel import MerelNetworks
from vnl.ppo.recurrent import make_recurrent_networks
from vnl.ppo.recurrent_ppo import actor_step, recurrent_ppo_loss, zero_carry
from vnl.train import config as train_config
from vnl.train import trainer

pytestmark = [pytest.mark.xdist_group("recurrent"), pytest.mark.usefixtures("point_envs")]

K = 1024
QUIET = {"video": False, "progress": False}
NETWORK = {
    "architecture": "merel",
    "core": "lstm",
    "core_size": 8,
    "encoder_hidden_layer_sizes": [16],
    "policy_core_sizes": [8, 6],
}


def config(network=None, **ppo):
    values = {
        "ppo": {"num_timesteps": 2 * K, "num_evals": 3, "learning_rate": 3e-3, "episode_length": None, **ppo},
        "env_config": {"impl": "c", "episode_length": 12},
        "network": {**NETWORK, **(network or {})},
        "log": QUIET,
    }
    return train_config.build("test_point", "tiny", file_values=values)


def quiet(_):
    pass


def collect(cfg, steps, seed=0):
    """`steps` steps of 4 envs with the untrained network, sampling, as training collects them."""
    env = registry.make("test_point", **cfg.env_config)
    nets = make_recurrent_networks(cfg, env)
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
    normalizer = running_statistics.init_state(specs.Array((env.observation_size,), jp.dtype("float32")))
    params = (normalizer, *nets.init(k1))
    wrapped = wrap_for_training(env, episode_length=cfg.episode_length())
    state = wrapped.reset(jax.random.split(k2, 4))

    def one(c, key):
        s, carry = c
        s, carry, transition = actor_step(wrapped, nets, params, s, carry, key, extra_fields=("truncation",))
        return (s, carry), transition

    _, data = jax.lax.scan(one, (state, zero_carry(nets, (4,))), jax.random.split(k2, steps))
    return nets, params, data


def test_the_parameters_split_into_the_policys_cores_and_the_values_encoder_and_core():
    nets = make_recurrent_networks(config(), registry.make("test_point", impl="c"))
    assert isinstance(nets, MerelNetworks)
    policy, value = nets.init(jax.random.PRNGKey(0))
    assert set(policy["params"]) == {"policy_core_0", "policy_core_1", "policy_head"}
    assert set(value["params"]) == {"encoder_0", "core", "value_head"}
    carry = nets.initial_carry((3,))
    assert [c.shape for c in carry["value"]] == [(3, 8)] * 2
    assert [c.shape for c in carry["policy"]] == [(3, 8), (3, 8), (3, 6), (3, 6)]


def test_the_core_learns_from_the_value_alone_and_the_encoder_from_both():
    """The policy's loss sends no gradient into the core or the value head (the paper's
    stop-gradient), but does into the shared encoder; the value's loss trains the core."""
    cfg = config()
    nets, params, data = collect(cfg, steps=20)
    batch_first = jax.tree.map(lambda x: jp.swapaxes(x, 0, 1), data)

    def grads(policy_weight, value_weight):
        def loss(p):
            _, m = recurrent_ppo_loss(p, params[0], batch_first, jax.random.PRNGKey(0), nets, 0.0, 0.97, 1.0, 0.95, 0.3)
            return policy_weight * m["policy_loss"] + value_weight * m["v_loss"]

        return jax.grad(loss)(PPONetworkParams(policy=params[1], value=params[2]))

    def norm(tree):
        return float(sum(jp.sum(jp.abs(x)) for x in jax.tree.leaves(tree)))

    from_policy = grads(1.0, 0.0)
    assert norm(from_policy.value["params"]["core"]) == 0.0
    assert norm(from_policy.value["params"]["value_head"]) == 0.0
    assert norm(from_policy.value["params"]["encoder_0"]) > 0.0
    assert norm(from_policy.policy) > 0.0
    from_value = grads(0.0, 1.0)
    assert norm(from_value.value["params"]["core"]) > 0.0
    assert norm(from_value.policy) == 0.0


def test_the_losss_rerun_gives_the_rollouts_log_probabilities():
    """Unrolls crossing episode boundaries re-run from their first stored carry with the stored
    resets give the sampled log-probabilities back; without the resets they differ."""
    nets, params, data = collect(config(), steps=20)
    resets = data.extras["core"]["reset"]
    assert resets[1:].sum() > 0
    carry0 = jax.tree.map(lambda c: c[0], data.extras["core"]["carry"])
    dist = nets.parametric_action_distribution
    raw, stored = data.extras["policy_extras"]["raw_action"], data.extras["policy_extras"]["log_prob"]
    logits, _, _ = nets.unroll(*params, data.observation, carry0, resets)
    np.testing.assert_allclose(dist.log_prob(logits, raw), stored, rtol=1e-5, atol=1e-5)
    logits, _, _ = nets.unroll(*params, data.observation, carry0, 0 * resets)
    assert not np.allclose(dist.log_prob(logits, raw), stored, atol=1e-5)


def test_a_camera_is_encoded_by_a_resnet_stored_with_the_value():
    """Pixel observations: one ResNet per camera (IMPALA's sections: 16x16 -> 2x2 after three
    stride-2 pools), its features in the recorded layers; its parameters are the value's."""

    class Env:
        observation_size = {"state": (5,), "pixels/ego": (16, 16, 3)}
        action_size = 2

    cfg = config({"resnet_channels": [4, 8, 8], "resnet_blocks": 1, "resnet_features": 12})
    nets = make_recurrent_networks(cfg, Env())
    policy, value = nets.init(jax.random.PRNGKey(0))
    assert "vision_ego" in value["params"] and "vision_ego" not in policy["params"]
    assert value["params"]["vision_ego"]["features"]["kernel"].shape == (2 * 2 * 8, 12)
    normalizer = running_statistics.init_state({"state": specs.Array((5,), jp.dtype("float32"))})
    obs = {
        "state": jp.ones((3, 5)),
        "pixels/ego": jax.random.randint(jax.random.PRNGKey(1), (3, 16, 16, 3), 0, 255).astype(jp.uint8),
    }
    layers, head, carry = nets.activity(normalizer, policy, value, obs, nets.initial_carry((3,)))
    assert layers["encoder_vision_ego"].shape == (3, 12)
    assert {"encoder_hidden_0", "core_h", "core_c", "policy_core_1_h", "value_output"} <= set(layers)
    # Another image changes the action: the policy sees through the encoder's shortcut.
    other = {**obs, "pixels/ego": 255 - obs["pixels/ego"]}
    _, head2, _ = nets.activity(normalizer, policy, value, other, nets.initial_carry((3,)))
    assert not np.allclose(head, head2)


def test_merel_without_a_core_is_refused_in_one_line(tmp_path, capsys):
    argv = ["train", "test_point", "--preset", "tiny", "--out", str(tmp_path / "r"), "--no-video"]
    assert main([*argv, "--set", "network.architecture=merel"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("vnl: error:") and "network.core" in err
    assert not (tmp_path / "r").exists()
    with pytest.raises(VnlError, match="policy_core_sizes"):
        config({"policy_core_sizes": []})


@pytest.fixture(scope="module")
def merel_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("merel") / "run"
    trainer.train(config(), out, say=quiet)
    return out


@pytest.mark.slow
def test_a_merel_run_resumes_bit_exact(merel_run, tmp_path):
    res = tmp_path / "res"
    trainer.train(config(num_timesteps=K, num_evals=2), res, say=quiet)
    trainer.resume(res, flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    _, a, _ = checkpoint.load_train_state(merel_run)
    _, b, _ = checkpoint.load_train_state(res)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.mark.slow
def test_a_merel_run_is_recorded_loaded_and_analysed(merel_run, tmp_path):
    run = merel_run
    rec = tmp_path / "rec.nc"
    assert main(["record", str(run), "--episodes", "2", "--steps", "12", "--out", str(rec)]) == 0
    ds = xr.open_dataset(rec)
    for name, units in (("encoder_hidden_0", 16), ("core_h", 8), ("policy_core_0_h", 8), ("policy_core_1_c", 6)):
        assert ds.sizes[f"{name}_unit"] == units
    # The loaded policy's state is every core's; stepping it over the recorded observations gives
    # the recorded core states back.
    policy = load_policy(run)
    assert isinstance(policy, RecurrentPolicy)
    state = policy.initial_state((2,))
    for t in range(12):
        _, state = policy.step(jp.asarray(ds["observation"].values[:, t]), state, jax.random.PRNGKey(0))
        np.testing.assert_allclose(state["value"][1], ds["core_h"].values[:, t], atol=1e-5)
        np.testing.assert_allclose(state["policy"][3], ds["policy_core_1_h"].values[:, t], atol=1e-5)
    out = tmp_path / "pca.png"
    assert main(["analyze", str(rec), "--method", "pca", "--out", str(out)]) == 0
    assert json.loads(out.with_suffix(".json").read_text())["layer"] == "policy_core_0_h"
    out = tmp_path / "decoding.png"
    assert (
        main(["analyze", str(rec), "--method", "decoding", "--target", "reward", "--folds", "2", "--out", str(out)])
        == 0
    )
    assert json.loads(out.with_suffix(".json").read_text())["layer"] == "policy_core_1_h"


@pytest.mark.slow
def test_a_merel_run_with_vision_trains_and_its_policy_reads_the_camera(tmp_path):
    """find_target --vision with Merel's network: trains (MuJoCo C physics, a 16x16 camera, a
    one-section ResNet), and the trained policy's action changes with the image alone."""
    small = ["vision.enabled=true", "vision.width=16", "vision.height=16", "env_config.impl=c"]
    small += ["network.architecture=merel", "network.core=lstm", "network.core_size=8"]
    small += ["network.encoder_hidden_layer_sizes=[16]", "network.policy_core_sizes=[8]"]
    small += ["network.resnet_channels=[4]", "network.resnet_blocks=1", "network.resnet_features=8"]
    small += ["ppo.num_timesteps=2048", "log.video=false", "log.progress=false"]
    cfg = train_config.build("find_target", "tiny", assignments=small)
    out = tmp_path / "run"
    trainer.train(cfg, out, say=quiet)
    run = load_policy(out)
    from vnl import policy as policy_module

    loaded = policy_module.load_run(out)
    s = jax.jit(loaded.env.reset)(jax.random.PRNGKey(3))
    obs = jax.tree.map(lambda x: x[None], s.obs)
    blank = {**obs, "pixels/egocentric": jp.zeros_like(obs["pixels/egocentric"])}
    actions = []
    for o in (obs, blank):
        a, _ = run.step(o, run.initial_state((1,)), jax.random.PRNGKey(0))
        actions.append(np.asarray(a))
    assert actions[0].shape == (1, 2) and np.abs(actions[0] - actions[1]).max() > 1e-6
