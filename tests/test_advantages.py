"""`ppo.normalize_advantage` (vnl.ppo.losses): a suite's tasks' advantages normalised each on their
own, vnl's feed-forward loss equal to Brax's with one group, and the option in training."""

import functools

import jax
import jax.numpy as jp
import numpy as np
import pytest
from brax.training import types as brax_types
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks
from test_compact_checkpoints import quiet

from vnl.errors import VnlError
from vnl.io import metrics as metrics_io
from vnl.ppo.losses import normalize_advantages, ppo_loss
from vnl.train import config as train_config
from vnl.train import trainer

pytestmark = [pytest.mark.usefixtures("point_envs")]

SETTINGS = {
    "entropy_cost": 1e-2,
    "discounting": 0.97,
    "reward_scaling": 10.0,
    "gae_lambda": 0.95,
    "clipping_epsilon": 0.3,
}


def test_each_group_is_centred_and_scaled_on_its_own():
    rng = np.random.default_rng(0)
    task = rng.integers(0, 3, size=(10, 8))
    task[0, 0] = 2  # group 2 holds one entry only
    task[task == 2] = 0
    task[0, 0] = 2
    scale = np.array([1.0, 100.0, 5.0])[task]
    advantages = jp.asarray(rng.normal(3.0, 1.0, size=(10, 8)) * scale, jp.float32)
    groups = jax.nn.one_hot(task, 4)  # group 3 is absent
    out = np.asarray(normalize_advantages(advantages, groups))
    assert np.isfinite(out).all()
    for k in (0, 1):
        assert out[task == k].mean() == pytest.approx(0.0, abs=1e-5)
        assert out[task == k].std() == pytest.approx(1.0, abs=1e-4)
    assert out[0, 0] == 0.0
    batch = np.asarray(normalize_advantages(advantages))
    assert batch[task == 1].std() > 10 * batch[task == 0].std()  # one scale for all: the wide task dominates
    np.testing.assert_allclose(normalize_advantages(advantages, jp.ones((10, 8, 1))), batch, rtol=1e-5, atol=1e-5)


def _unrolls(obs_size=5, action_size=2, batch=6, steps=7):
    """A Brax PPO network, its params and a batch of unrolls (B, T, ...) sampled from its policy."""
    network = ppo_networks.make_ppo_networks(
        obs_size,
        action_size,
        preprocess_observations_fn=running_statistics.normalize,
        policy_hidden_layer_sizes=(8,),
        value_hidden_layer_sizes=(8,),
    )
    keys = jax.random.split(jax.random.PRNGKey(0), 6)
    normalizer = running_statistics.init_state(specs.Array((obs_size,), jp.float32))
    params = ppo_losses.PPONetworkParams(
        policy=network.policy_network.init(keys[0]), value=network.value_network.init(keys[1])
    )
    obs = jax.random.normal(keys[2], (batch, steps, obs_size))
    _, extras = ppo_networks.make_inference_fn(network)((normalizer, params.policy))(obs, keys[3])
    data = brax_types.Transition(
        observation=obs,
        action=jp.tanh(extras["raw_action"]),
        reward=jax.random.normal(keys[4], (batch, steps)),
        discount=jp.ones((batch, steps)).at[:, 3].set(0.0),
        next_observation=obs + 0.1,
        extras={
            "policy_extras": extras,
            "state_extras": {"truncation": jp.zeros((batch, steps)).at[:, 5].set(1.0)},
        },
    )
    return network, params, normalizer, data


def test_vnls_loss_with_one_group_is_braxs_loss_and_gradient():
    network, params, normalizer, data = _unrolls()
    key = jax.random.PRNGKey(7)

    def brax(p, normalize):
        settings = {**SETTINGS, "normalize_advantage": normalize}
        return ppo_losses.compute_ppo_loss(p, normalizer, data, key, ppo_network=network, **settings)

    def ours(p, normalize):
        settings = {**SETTINGS, "normalize_advantage": normalize}
        one = lambda o: jp.ones(o.shape[:-1] + (1,))  # noqa: E731
        return ppo_loss(p, normalizer, data, key, ppo_network=network, groups_of=one, **settings)

    for normalize in (True, False):
        grad = functools.partial(jax.value_and_grad, has_aux=True)
        (loss_b, metrics_b), grads_b = jax.jit(grad(brax), static_argnums=1)(params, normalize)
        (loss_o, metrics_o), grads_o = jax.jit(grad(ours), static_argnums=1)(params, normalize)
        assert float(loss_o) == pytest.approx(float(loss_b), rel=1e-5)
        assert set(metrics_o) == set(metrics_b)
        for k in metrics_b:
            assert float(metrics_o[k]) == pytest.approx(float(metrics_b[k]), rel=1e-4, abs=1e-6), k
        for g_o, g_b in zip(jax.tree.leaves(grads_o), jax.tree.leaves(grads_b), strict=True):
            np.testing.assert_allclose(g_o, g_b, rtol=1e-4, atol=1e-6)


def test_per_task_normalisation_is_refused_for_one_task():
    with pytest.raises(VnlError, match="normalize_advantage=task is per task of a suite; test_point is one task"):
        train_config.build("test_point", "tiny", assignments=["ppo.normalize_advantage=task"])
    with pytest.raises(VnlError, match="normalize_advantage"):
        train_config.build("test_suite", "tiny", assignments=["ppo.normalize_advantage=tasks"])


K = 1024  # the tiny suite's 2 training steps of 512 env steps


@pytest.mark.slow
@pytest.mark.xdist_group("suite")
@pytest.mark.parametrize("core, modes", [(None, ("batch", "task", "none")), ("gru", ("batch", "task"))])
def test_a_suite_trains_with_each_tasks_advantages_normalised_apart(tmp_path, core, modes):
    """Each mode trains, and `task` and `none` are not `batch`: the option reaches the loss, feed-forward
    and recurrent (training on the CPU is deterministic)."""
    network = {"core": core, "core_size": 8} if core else {}
    losses = {}
    for mode in modes:
        values = {
            "ppo": {"num_timesteps": K, "num_evals": 2, "normalize_advantage": mode},
            "env_config": {"test_point": {"episode_length": 12}, "test_plane": {"episode_length": 9}, "shares": [1, 3]},
            "network": network,
            "log": {"video": False, "progress": False},
        }
        trainer.train(train_config.build("test_suite", "tiny", file_values=values), tmp_path / mode, say=quiet)
        last = metrics_io.read(tmp_path / mode / "metrics.jsonl")[-1]
        assert last["step"] == K and np.isfinite(last["eval/episode_reward"])
        losses[mode] = last["training/policy_loss"]
    assert all(losses[mode] != losses["batch"] for mode in modes[1:]), losses
