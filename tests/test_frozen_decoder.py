"""A trained intention network's decoder, frozen, under a new policy (`decoder.run`,
vnl.train.frozen_decoder, vnl.envs.latent): the latent action is decoded as the parent decodes
its encoder's latent; a run trains through it and records what it used; bad uses are refused.

The parent: tests/tiny_env.py's point mass observing its target, the target declared as the
reference (as in tests/test_intention.py); the child env: the point mass without the target."""

import dataclasses
import shutil

import jax
import jax.numpy as jp
import numpy as np
import pytest
from test_intention import NETWORK, K, L  # the same small intention network (tests/ is on sys.path)
from tiny_env import PointConfig, PointMass

from vnl.envs import registry
from vnl.envs.latent import LatentActionEnv
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.policy import load_run
from vnl.train import config as train_config
from vnl.train import frozen_decoder, trainer

pytestmark = [pytest.mark.xdist_group("frozen_decoder"), pytest.mark.usefixtures("point_envs")]

SMALL = {"policy_hidden_layer_sizes": [8], "value_hidden_layer_sizes": [8]}


class ReferencePoint(PointMass):
    reference_blocks = ("target",)


class OtherSenses(PointMass):
    """The point mass whose velocity block is named otherwise: not the senses the decoder read."""

    def observation_layout(self):
        return [("offset", 1), ("speed", 1)]


@pytest.fixture(scope="module", autouse=True)
def envs():
    registry.register("test_point_ref2", ReferencePoint, PointConfig(observe_target=True), "test-only")
    registry.register("test_point_other", OtherSenses, PointConfig(), "test-only")
    yield
    registry.unregister("test_point_ref2")
    registry.unregister("test_point_other")


def build(env, network, **values):
    values = {
        "ppo": {"num_timesteps": 2 * K, "num_evals": 2, "learning_rate": 3e-3, "episode_length": None},
        "env_config": {"impl": "c", "episode_length": 12},
        "network": network,
        "log": {"video": False, "progress": False},
        **values,
    }
    return train_config.build(env, "tiny", file_values=values)


def quiet(_):
    pass


@pytest.fixture(scope="module")
def parent(tmp_path_factory):
    out = tmp_path_factory.mktemp("parent") / "run"
    trainer.train(build("test_point_ref2", NETWORK), out, say=quiet)
    return out


def test_a_latent_action_env_steps_its_env_with_the_decoded_action():
    inner = registry.make("test_point", impl="c")
    decode = lambda z, obs: jp.tanh(z[:1] + obs[:1])  # noqa: E731
    env = LatentActionEnv(inner, decode, latent_size=4, scale=2.0)
    assert env.action_size == 4 and env.observation_layout() == inner.observation_layout()
    state = env.reset(jax.random.PRNGKey(0))
    action = jp.asarray([0.3, -1.0, 0.5, 0.0])
    body = jp.tanh(2.0 * action[:1] + state.obs[:1])
    mine, theirs = env.step(state, action), inner.step(state, body)
    np.testing.assert_array_equal(mine.obs, theirs.obs)
    np.testing.assert_array_equal(mine.info["decoded_action"], body)
    assert float(mine.reward) == float(theirs.reward)


@pytest.mark.slow
def test_the_frozen_decoder_decodes_a_latent_as_its_intention_network_does(parent):
    """The parent's own deterministic action for an observation equals the frozen decoder's for its
    encoder's mean latent (given as the action latent/scale) and the same senses without the
    reference."""
    run = load_run(parent)
    decoder = train_config.DecoderConfig(run=str(parent), latent_scale=1.5)
    env = frozen_decoder.wrap(registry.make("test_point", impl="c"), decoder, run.config)
    assert isinstance(env, LatentActionEnv) and env.action_size == L
    obs = jax.random.normal(jax.random.PRNGKey(3), (16, 3))
    net = frozen_decoder.make_network(run.config, run.env)
    mean, _ = net.policy_network.posterior(run.params[0], run.params[1], obs)
    expected = run.policy(obs, jax.random.PRNGKey(0))
    got = jax.vmap(env.decode)(mean, obs[:, :2])
    np.testing.assert_allclose(got, expected, atol=1e-6)
    state = env.reset(jax.random.PRNGKey(1))
    stepped = env.step(state, mean[0] / 1.5)
    np.testing.assert_allclose(stepped.info["decoded_action"], env.decode(mean[0], state.obs), atol=1e-6)


@pytest.mark.slow
def test_a_run_trains_through_a_frozen_decoder_and_records_it(parent, tmp_path):
    before = checkpoint.load(parent)[1]
    cfg = build("test_point", SMALL, decoder={"run": str(parent)})
    out = tmp_path / "child"
    trainer.train(cfg, out, say=quiet)
    saved = train_config.read_config(out)
    newest = checkpoint.load(parent)[0]
    assert saved.decoder.run == str(parent.absolute()) and saved.decoder.step == newest
    assert saved.decoder.config_hash == train_config.read_config(parent).content_hash()
    child = load_run(out)
    assert isinstance(child.env, LatentActionEnv) and child.env.action_size == L
    action = child.policy(jp.zeros((2, 2)), jax.random.PRNGKey(0))
    assert action.shape == (2, L)
    # Recorded: the new policy's layers, its action (the latent action) and the frozen decoder's
    # layers, whose output's mode is the body's action (the env's `decoded_action`).
    from vnl import record

    ds = record.record(child, episodes=2, steps=4)
    assert ds["action"].shape[-1] == 1 and ds["latent_action"].shape[-1] == L  # the body's one actuator; the latent
    np.testing.assert_allclose(ds["policy_decoder_intention"].values, 2.0 * ds["latent_action"].values, atol=1e-6)
    assert {"policy_hidden_0", "policy_decoder_hidden_0", "policy_decoder_hidden_1", "policy_decoder_output"} <= set(
        ds.data_vars
    )
    obs = jp.asarray(ds["observation"].values[:, 0])
    body = jax.vmap(child.env.decode)(2.0 * jp.asarray(ds["latent_action"].values[:, 0]), obs)
    mode = jp.tanh(jp.asarray(ds["policy_decoder_output"].values[:, 0, :1]))  # tanh_normal's mode: tanh(loc)
    np.testing.assert_allclose(body, mode, atol=1e-6)
    np.testing.assert_allclose(ds["action"].values[:, 0], body, atol=1e-6)
    after = checkpoint.load(parent)[1]
    for a, b in zip(jax.tree.leaves(before), jax.tree.leaves(after), strict=True):
        np.testing.assert_array_equal(a, b)
    # The decoder run's config changed since: the child says so instead of decoding with other weights.
    changed = dataclasses.replace(saved.decoder, config_hash="0" * 16)
    with pytest.raises(VnlError, match="changed since"):
        frozen_decoder.wrap(registry.make("test_point", impl="c"), changed, train_config.read_config(parent))


@pytest.mark.slow
def test_bad_frozen_decoders_are_refused(parent, tmp_path):
    with pytest.raises(VnlError, match="'velocity'"):
        build("test_point_other", SMALL, decoder={"run": str(parent)}).make_env()
    with pytest.raises(VnlError, match="its own network must not be an intention"):
        build("test_point", NETWORK, decoder={"run": str(parent)})
    with pytest.raises(VnlError, match="without --vision"):
        build("test_point", SMALL, decoder={"run": str(parent)}, vision={"enabled": True})
    with pytest.raises(VnlError, match="decoder.step needs decoder.run"):
        build("test_point", SMALL, decoder={"step": 0})
    with pytest.raises(VnlError, match="latent_scale"):
        build("test_point", SMALL, decoder={"run": str(parent), "latent_scale": 0.0})
    plain = tmp_path / "plain"  # the parent's directory with a config of another network
    shutil.copytree(parent, plain)
    text = (plain / "config.yaml").read_text()
    (plain / "config.yaml").write_text(text.replace("architecture: intention", "architecture: brax"))
    with pytest.raises(VnlError, match="comes from an intention network"):
        build("test_point", SMALL, decoder={"run": str(plain)}).make_env()
    with pytest.raises(VnlError, match="decoder.run: run directory not found"):
        build("test_point", SMALL, decoder={"run": str(tmp_path / "nowhere")}).make_env()
