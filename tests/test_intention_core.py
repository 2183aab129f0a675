"""The intention network with a recurrent decoder (`network.architecture: intention` with
`network.core`, vnl.ppo.intention_core): the parameters; PPO's loss re-runs the decoder's core at
the rollout's latent draws (the ratio is 1) and adds the encoder's KL; the decoder remembers and
forgets at episode starts; a run trained, resumed bit-exact, recorded, loaded and exported.

The env: test_intention's point mass whose observed target is the reference."""

import jax
import jax.numpy as jp
import numpy as np
import pytest
import xarray as xr
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo.losses import PPONetworkParams
from test_intention import (  # noqa: F401 (the fixture registers test_point_ref)
    K,
    L,
    assert_kl_logged_and_resume_bit_exact,
    quiet,
    reference_env,
)
from test_intention import config as intention_config

from vnl.cli import main
from vnl.envs import registry
from vnl.envs.latent import LatentActionEnv
from vnl.envs.wrappers import wrap_for_training
from vnl.errors import VnlError
from vnl.policy import RecurrentPolicy, load_policy, load_run
from vnl.ppo import intention
from vnl.ppo.intention_core import RecurrentIntentionNetworks
from vnl.ppo.recurrent import make_recurrent_networks
from vnl.ppo.recurrent_ppo import RecurrentPPOLoop, actor_step, make_ppo_loop, recurrent_ppo_loss, zero_carry
from vnl.train import config as train_config
from vnl.train import frozen_decoder, trainer

pytestmark = [pytest.mark.xdist_group("intention"), pytest.mark.usefixtures("point_envs")]

CORE = {"core": "lstm", "core_size": 6, "policy_hidden_layer_sizes": [8]}
"""test_intention's small network with an LSTM decoder of one MLP layer."""
SETTINGS = {"entropy_cost": 1e-3, "discounting": 0.97, "reward_scaling": 1.0, "gae_lambda": 0.95}
SETTINGS["clipping_epsilon"] = 0.2


def config(network=None, **ppo):
    return intention_config({**CORE, **(network or {})}, **ppo)


def setup(cfg=None):
    cfg = cfg or config()
    env = registry.make("test_point_ref", **cfg.env_config)
    nets = make_recurrent_networks(cfg, env)
    normalizer = running_statistics.init_state(specs.Array((env.observation_size,), jp.dtype("float32")))
    policy, value = nets.init(jax.random.PRNGKey(0))
    return cfg, env, nets, (normalizer, policy, value)


def collect(steps=20, envs=4):
    """`steps` steps of `envs` envs with the untrained stochastic policy, as training collects them
    (time-major transitions), with the networks and params."""
    cfg, env, nets, params = setup()
    wrapped = wrap_for_training(env, episode_length=cfg.episode_length())
    key = jax.random.PRNGKey(3)
    state = wrapped.reset(jax.random.split(key, envs))

    def one(c, k):
        s, carry = c
        s, carry, transition = actor_step(wrapped, nets, params, s, carry, k, extra_fields=("truncation",))
        return (s, carry), transition

    _, data = jax.lax.scan(one, (state, zero_carry(nets, (envs,))), jax.random.split(key, steps))
    return nets, params, data


def test_the_decoder_has_a_core_between_its_mlp_and_the_head_and_the_value_its_own():
    cfg, env, nets, (_, policy, value) = setup()
    assert isinstance(nets, RecurrentIntentionNetworks)
    assert isinstance(make_ppo_loop(env, cfg), RecurrentPPOLoop)
    p = policy["params"]
    assert set(p) == {"encoder_0", "intention_mean", "intention_log_std", "decoder_0", "decoder_core", "policy_head"}
    assert p["encoder_0"]["kernel"].shape == (1, 16)  # the reference alone
    assert p["decoder_0"]["kernel"].shape == (L + 2, 8)  # the latent and the other columns
    assert p["policy_head"]["kernel"].shape == (6, 2)  # from the core's 6 units
    assert set(value["params"]) == {"encoder", "core", "output"}
    carry = nets.initial_carry((5,))
    assert [c.shape for c in carry["policy"]] == [(5, 6), (5, 6)]
    gru = setup(config({"core": "gru"}))[2]
    assert [c.shape for c in gru.initial_carry((5,))["policy"]] == [(5, 6)]


def test_the_loss_reruns_the_decoder_at_the_stored_draws_and_adds_the_kl():
    """Re-run over unrolls that cross episode starts, from the first stored state with the stored
    resets and latent draws, the policy gives the rollout's log-probabilities back; at the mean
    latent it does not. The loss adds kl_weight × the encoder's KL, computed here by hand."""
    nets, params, data = collect()
    normalizer, policy, value = params
    extras = data.extras["policy_extras"]
    assert extras[intention.NOISE].shape == (20, 4, L)
    assert data.extras["core"]["reset"][1:].sum() > 0
    first = jax.tree.map(lambda c: c[0], data.extras["core"]["carry"])
    resets = data.extras["core"]["reset"]
    dist = nets.parametric_action_distribution
    for noise, same in ((extras[intention.NOISE], True), (None, False)):
        logits, _, _ = nets.unroll(normalizer, policy, value, data.observation, first, resets, noise)
        rerun = dist.log_prob(logits, extras["raw_action"])
        assert np.allclose(rerun, extras["log_prob"], rtol=1e-5, atol=1e-5) == same
    batch = jax.tree.map(lambda x: jp.swapaxes(x, 0, 1), data)
    both = PPONetworkParams(policy=policy, value=value)
    key = jax.random.PRNGKey(4)
    loss, metrics = recurrent_ppo_loss(both, normalizer, batch, key, nets, kl_weight=0.5, **SETTINGS)
    zero, _ = recurrent_ppo_loss(both, normalizer, batch, key, nets, kl_weight=0.0, **SETTINGS)
    obs = np.asarray(running_statistics.normalize(data.observation, normalizer))
    p = jax.tree.map(np.asarray, policy["params"])
    h = obs[..., 2:] @ p["encoder_0"]["kernel"] + p["encoder_0"]["bias"]
    h = h / (1 + np.exp(-h))  # swish
    mean = h @ p["intention_mean"]["kernel"] + p["intention_mean"]["bias"]
    std = np.exp(h @ p["intention_log_std"]["kernel"] + p["intention_log_std"]["bias"])
    expected = np.mean(np.sum(np.log(1 / std) + (std**2 + mean**2) / 2 - 0.5, axis=-1))
    np.testing.assert_allclose(metrics["intention_kl"], expected, rtol=1e-5)
    # The loss's own re-run sees no change of policy: its KL is the stored distribution's to itself.
    stored = dist.create_dist(batch.extras["policy_extras"]["distribution_params"])
    assert float(metrics["kl_mean"]) == pytest.approx(float(jp.mean(stored.kl_divergence(stored))), rel=1e-6)
    np.testing.assert_allclose(loss - zero, 0.5 * expected, rtol=1e-4)


def test_the_decoder_remembers_within_an_episode_and_forgets_at_its_start():
    """The same observation and latent from two decoder states: different actions mid-episode, the
    same at an episode's first step (the state reset to zeros)."""
    _, _, nets, (normalizer, policy, value) = setup()
    obs = jp.tile(jax.random.normal(jax.random.PRNGKey(1), (1, 3)), (2, 1))
    past = nets.initial_carry((2,))
    past["policy"] = tuple(jax.random.normal(jax.random.PRNGKey(i), (2, 6)) * jp.array([[1.0], [0.0]]) for i in (2, 3))
    for reset, equal in ((jp.zeros(2), False), (jp.ones(2), True)):
        head, _, carry = nets.step(normalizer, policy, value, obs, past, reset)
        assert np.allclose(head[0], head[1], atol=1e-7) == equal
        assert np.allclose(carry["policy"][1][0], carry["policy"][1][1], atol=1e-7) == equal


def test_bad_recurrent_decoder_configs_are_refused_in_one_line():
    for network, match in (({"core_size": 0}, "core_size"), ({"intention_size": 0}, "intention_size")):
        with pytest.raises(VnlError, match=match):
            config(network)


@pytest.fixture(scope="module")
def lstm_intention_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("intention_core") / "run"
    trainer.train(config(), out, say=quiet)
    return out


@pytest.mark.slow
def test_a_recurrent_decoder_run_logs_its_kl_and_resumes_bit_exact(lstm_intention_run, tmp_path):
    final = assert_kl_logged_and_resume_bit_exact(lstm_intention_run, config, tmp_path / "res")
    assert any("decoder_core" in k for k in final)


@pytest.mark.slow
def test_a_recurrent_decoder_run_is_recorded_loaded_and_exported(lstm_intention_run, tmp_path):
    run = lstm_intention_run
    rec = tmp_path / "rec.nc"
    assert main(["record", str(run), "--episodes", "2", "--steps", "12", "--out", str(rec)]) == 0
    ds = xr.open_dataset(rec)
    for name, units in (("policy_intention", L), ("encoder_intention_mean", L), ("policy_core_h", 6)):
        assert ds.sizes[f"{name}_unit"] == units
    assert {"policy_core_c", "policy_hidden_0", "value_hidden_0", "value_core_h", "value_output"} <= set(ds.data_vars)
    np.testing.assert_array_equal(ds["policy_intention"].values, ds["encoder_intention_mean"].values)
    # The loaded policy, carrying its state from zeros, chooses the recorded actions and states.
    policy = load_policy(run)
    assert isinstance(policy, RecurrentPolicy)
    state = policy.initial_state((2,))
    for t in range(12):
        action, state = policy.step(jp.asarray(ds["observation"].values[:, t]), state, jax.random.PRNGKey(0))
        np.testing.assert_allclose(action, ds["action"].values[:, t], atol=1e-5)
        np.testing.assert_allclose(state[1], ds["policy_core_h"].values[:, t], atol=1e-5)
    from vnl.recording import nwb, nwb_reader

    back = nwb_reader.read(nwb.write(ds, tmp_path / "rec.nwb", config="env: test_point_ref\n"))
    assert back["policy_intention"].shape[-1] == L and back["policy_core_h"].shape[-1] == 6
    # A stochastic policy draws its latent: the actions differ from the mean latent's.
    drawn = load_policy(run, deterministic=False)
    obs = jp.asarray(ds["observation"].values[:, 0])
    a0, _ = drawn.step(obs, drawn.initial_state((2,)), jax.random.PRNGKey(1))
    assert not np.allclose(a0, ds["action"].values[:, 0], atol=1e-4)


@pytest.mark.slow
def test_a_frozen_recurrent_decoder_carries_its_state_as_its_network_does(lstm_intention_run):
    """Given the encoder's mean latent each step, the frozen decoder on the senses alone chooses
    the parent's own actions step after step (its state carried in the env's info); training's
    auto-reset puts the state back to zeros at an episode's start."""
    run = load_run(lstm_intention_run)
    decoder = train_config.DecoderConfig(run=str(lstm_intention_run), latent_scale=1.0)
    env = frozen_decoder.wrap(registry.make("test_point", impl="c"), decoder, run.config)
    assert isinstance(env, LatentActionEnv) and env.stateful and env.action_size == L
    obs = jax.random.normal(jax.random.PRNGKey(3), (8, 3))  # 8 steps of the parent's observation
    nets = make_recurrent_networks(run.config, run.env)
    mean, _ = nets.posterior(run.params[0], run.params[1], obs)
    parent_state, decoder_state = run.policy.initial_state(), env.decoder_state
    for t in range(8):
        expected, parent_state = run.policy.step(obs[t], parent_state, jax.random.PRNGKey(0))
        got, decoder_state = env.decode(mean[t], obs[t, :2], decoder_state)
        np.testing.assert_allclose(got, expected, atol=1e-5)
    assert not np.allclose(decoder_state[1], 0.0)
    # Stepped as an env: each step's body action is the decoder's from the state carried so far
    # (replayed here by hand), the state moves on, and the episode's end sets it back to zeros.
    wrapped = wrap_for_training(env, episode_length=3)
    state = wrapped.reset(jax.random.split(jax.random.PRNGKey(1), 2))
    step = jax.jit(wrapped.step)
    by_hand = jax.tree.map(lambda x: jp.broadcast_to(x, (2,) + x.shape), env.decoder_state)
    action = jp.asarray([[1.0, -0.5, 0.3], [0.2, 0.9, -1.0]])
    for t in range(3):
        expected, by_hand = env.decode(env.latent(action), state.obs, by_hand)
        state = step(state, action)
        if t < 2:  # at the episode's end the auto-reset puts the new episode's info in place
            np.testing.assert_allclose(state.info["decoded_action"], expected, atol=1e-6)
        moved = not np.allclose(state.info["decoder_state"][1], 0.0)
        assert moved == (t < 2) and bool(state.done.all()) == (t == 2)


@pytest.mark.slow
def test_a_run_trains_through_a_frozen_recurrent_decoder_and_records_its_state(lstm_intention_run, tmp_path):
    values = {
        "ppo": {"num_timesteps": 2 * K, "num_evals": 2, "learning_rate": 3e-3, "episode_length": None},
        "env_config": {"impl": "c", "episode_length": 12},
        "network": {"policy_hidden_layer_sizes": [8], "value_hidden_layer_sizes": [8]},
        "log": {"video": False, "progress": False},
        "decoder": {"run": str(lstm_intention_run)},
    }
    repeated = {**values, "ppo": {**values["ppo"], "action_repeat": 2}}
    with pytest.raises(VnlError, match="action_repeat"):  # the core would step once per repeat
        train_config.build("test_point", "tiny", file_values=repeated).make_env()
    out = tmp_path / "child"
    trainer.train(train_config.build("test_point", "tiny", file_values=values), out, say=quiet)
    child = load_run(out)
    from vnl import record

    ds = record.record(child, episodes=2, steps=6)
    assert ds.sizes["policy_decoder_core_h_unit"] == 6 and "policy_decoder_core_c" in ds.data_vars
    assert ds["latent_action"].shape[-1] == L and ds["action"].shape[-1] == 1
    # The recorded decoder state moves through the episode, and replaying the recorded latents and
    # observations through the env's decoder gives the recorded body actions back.
    h = ds["policy_decoder_core_h"].values
    assert not np.allclose(h[:, 0], h[:, -1])
    state = jax.tree.map(lambda x: jp.broadcast_to(x, (2,) + x.shape), child.env.decoder_state)
    for t in range(6):
        latent = child.env.latent(jp.asarray(ds["latent_action"].values[:, t]))
        body, state = child.env.decode(latent, jp.asarray(ds["observation"].values[:, t]), state)
        np.testing.assert_allclose(body, ds["action"].values[:, t], atol=1e-5)
        np.testing.assert_allclose(state[1], h[:, t], atol=1e-5)
