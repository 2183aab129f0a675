"""The intention network (`network.architecture: intention`, vnl.ppo.intention): the encoder reads
the reference alone, the decoder the latent and the rest; the KL term in PPO's loss; the mean
latent when deterministic; a run trained, resumed bit-exact, recorded and exported; bad configs.

The env: tests/tiny_env.py's point mass observing its target, the target declared as the
reference (`reference_blocks`)."""

import json

import jax
import jax.numpy as jp
import numpy as np
import pytest
import xarray as xr
from brax.training import acting
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo.losses import PPONetworkParams
from resumecheck import assert_same_final_state
from tiny_env import PointConfig, PointMass

from vnl import typed_config as config_lib
from vnl.cli import main
from vnl.envs import registry
from vnl.envs.wrappers import wrap_for_training
from vnl.errors import VnlError
from vnl.policy import load_policy
from vnl.ppo import intention, intention_ppo
from vnl.ppo.intention_ppo import IntentionPPOLoop
from vnl.ppo.networks import make_inference_fn, make_network
from vnl.train import config as train_config
from vnl.train import trainer, warm_start

pytestmark = [pytest.mark.xdist_group("intention"), pytest.mark.usefixtures("point_envs")]

K = 1024
L = 3  # the latent's units in these tests
NETWORK = {
    "architecture": "intention",
    "encoder_hidden_layer_sizes": [16],
    "intention_size": L,
    "policy_hidden_layer_sizes": [8, 8],
    "value_hidden_layer_sizes": [8],
}


class ReferencePoint(PointMass):
    """The point mass whose observed target (its last column) is the reference to follow."""

    reference_blocks = ("target",)


@pytest.fixture(scope="module", autouse=True)
def reference_env():
    registry.register("test_point_ref", ReferencePoint, PointConfig(observe_target=True), "test-only")
    yield
    registry.unregister("test_point_ref")


def config(network=None, **ppo):
    values = {
        "ppo": {"num_timesteps": 2 * K, "num_evals": 3, "learning_rate": 3e-3, "episode_length": None, **ppo},
        "env_config": {"impl": "c", "episode_length": 12},
        "network": {**NETWORK, **(network or {})},
        "log": {"video": False, "progress": False},
    }
    return train_config.build("test_point_ref", "tiny", file_values=values)


def quiet(_):
    pass


def setup(cfg=None, seed=0):
    """(config, env, networks, (normalizer, policy, value) params) of an untrained network."""
    cfg = cfg or config()
    env = registry.make("test_point_ref", **cfg.env_config)
    nets = make_network(cfg, env)
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
    normalizer = running_statistics.init_state(specs.Array((env.observation_size,), jp.dtype("float32")))
    return cfg, env, nets, (normalizer, nets.policy_network.init(k1), nets.value_network.init(k2))


def observations(n=16, seed=1):
    return jax.random.normal(jax.random.PRNGKey(seed), (n, 3))


def test_the_parameters_are_the_encoder_and_decoder_in_the_policy_and_an_mlp_in_the_value():
    _, env, nets, (_, policy, value) = setup()
    assert intention.observation_parts(env) == ((2,), (0, 1))
    p = policy["params"]
    assert set(p) == {"encoder_0", "intention_mean", "intention_log_std", "decoder_0", "decoder_1", "policy_head"}
    assert p["encoder_0"]["kernel"].shape == (1, 16)  # the reference (the target) alone
    assert p["intention_mean"]["kernel"].shape == p["intention_log_std"]["kernel"].shape == (16, L)
    assert p["decoder_0"]["kernel"].shape == (L + 2, 8)  # the latent and the other two columns
    assert p["policy_head"]["kernel"].shape == (8, 2)  # tanh_normal: location and scale of one action
    assert set(value["params"]) == {"hidden_0", "hidden_1"}
    assert value["params"]["hidden_0"]["kernel"].shape == (3, 8)  # the whole observation
    # A `normal` distribution keeps Brax's learned scale with the policy's parameters.
    _, _, _, (_, policy, _) = setup(config({"distribution_type": "normal"}))
    assert policy["params"]["std_logparam"]["log_value"].shape == (1,)


def test_rodent_imitate_declares_its_reference_columns():
    """The rat's reference is the four ref_* blocks (its next 5 frames), the rest proprioception."""
    env = registry.make("rodent_imitate", impl="c")
    reference, rest = intention.observation_parts(env)
    layout = dict(env.observation_layout())
    assert len(reference) == sum(layout[b] for b in ("ref_root_pos", "ref_root_quat", "ref_joints", "ref_bodies_pos"))
    assert len(reference) + len(rest) == env.observation_size and len(rest) > 0
    assert not set(reference) & set(rest)


def collect(cfg, env, nets, params, steps=6, envs=4):
    """Brax's unroll of the stochastic intention policy: (steps, envs, ...) transitions."""
    wrapped = wrap_for_training(env, episode_length=cfg.episode_length())
    state = wrapped.reset(jax.random.split(jax.random.PRNGKey(2), envs))
    policy = make_inference_fn(cfg, nets)(params)
    fields = ("truncation", "episode_metrics", "episode_done")
    _, data = acting.generate_unroll(wrapped, state, policy, jax.random.PRNGKey(3), steps, extra_fields=fields)
    return data


def test_the_kl_term_equals_an_independent_computation():
    cfg, env, nets, params = setup()
    data = collect(cfg, env, nets, params)
    batch = jax.tree.map(lambda x: jp.swapaxes(x, 0, 1), data)  # (envs, steps, ...), as the loop's minibatches
    normalizer, policy, value = params
    # The latent's Gaussian by hand: the encoder's Dense layers in numpy.
    obs = np.asarray(running_statistics.normalize(batch.observation, normalizer))
    p = jax.tree.map(np.asarray, policy["params"])
    h = obs[..., 2:] @ p["encoder_0"]["kernel"] + p["encoder_0"]["bias"]
    h = h / (1 + np.exp(-h))  # swish
    mean = h @ p["intention_mean"]["kernel"] + p["intention_mean"]["bias"]
    std = np.exp(h @ p["intention_log_std"]["kernel"] + p["intention_log_std"]["bias"])
    expected = np.mean(np.sum(np.log(1 / std) + (std**2 + mean**2) / 2 - 0.5, axis=-1))
    settings = {"entropy_cost": 1e-2, "discounting": 0.97, "reward_scaling": 1.0, "gae_lambda": 0.95}
    both = PPONetworkParams(policy=policy, value=value)
    key = jax.random.PRNGKey(4)
    loss, metrics = intention_ppo.intention_ppo_loss(both, normalizer, batch, key, nets, 0.5, **settings)
    without, _ = intention_ppo.intention_ppo_loss(both, normalizer, batch, key, nets, 0.0, **settings)
    np.testing.assert_allclose(metrics["intention_kl"], expected, rtol=1e-5)
    np.testing.assert_allclose(loss - without, 0.5 * expected, rtol=1e-4)
    assert float(metrics["total_loss"]) == float(loss)
    # The KL's gradient reaches the encoder and not the decoder or the value.
    grads = jax.grad(lambda q: intention_ppo.intention_kl(nets, q, normalizer, batch.observation))(both)
    assert float(jp.abs(grads.policy["params"]["intention_log_std"]["kernel"]).sum()) > 0
    assert float(sum(jp.abs(g).sum() for g in jax.tree.leaves(grads.policy["params"]["decoder_0"]))) == 0.0


def test_the_loss_decodes_at_the_rollouts_latent_draws():
    """Re-evaluated at the stored draws, the policy gives the rollout's log-probabilities back (the
    PPO ratio is 1 before any update); at the mean latent it does not."""
    cfg, env, nets, params = setup()
    data = collect(cfg, env, nets, params)
    extras = data.extras["policy_extras"]
    assert extras[intention.NOISE].shape == (6, 4, L)
    dist = nets.parametric_action_distribution
    padded = jp.concatenate([data.observation, extras[intention.NOISE]], axis=-1)
    logits = intention_ppo.with_noise_columns(nets).policy_network.apply(params[0], params[1], padded)
    np.testing.assert_allclose(dist.log_prob(logits, extras["raw_action"]), extras["log_prob"], rtol=1e-5, atol=1e-5)
    at_mean = nets.policy_network.apply(params[0], params[1], data.observation)
    assert not np.allclose(dist.log_prob(at_mean, extras["raw_action"]), extras["log_prob"], atol=1e-3)


def test_a_deterministic_policy_decodes_the_latent_mean():
    cfg, _, nets, params = setup()
    normalizer, policy, _ = params
    obs = observations()
    zeros = jp.zeros((obs.shape[0], L))
    head = nets.policy_network.apply(normalizer, policy, obs, zeros)  # mean + std × 0
    mode = nets.parametric_action_distribution.mode(head)
    act = make_inference_fn(cfg, nets)(params, deterministic=True)
    for seed in (0, 1):
        a, extras = act(obs, jax.random.PRNGKey(seed))
        np.testing.assert_allclose(a, mode, rtol=1e-6)
        assert extras == {}
    sampled, extras = make_inference_fn(cfg, nets)(params)(obs, jax.random.PRNGKey(0))
    assert extras[intention.NOISE].shape == (obs.shape[0], L)
    assert not np.allclose(sampled, mode)


def test_the_decoder_sees_the_reference_only_through_the_latent():
    """With the encoder's outputs made constant (its latent layers' kernels zero), another
    reference leaves the action unchanged and its gradient is zero; the other columns still act."""
    _, _, nets, (normalizer, policy, _) = setup()
    apply = nets.policy_network.apply
    obs = observations()
    other = obs.at[:, 2].set(obs[:, 2] + 3.0)  # another reference
    assert not np.allclose(apply(normalizer, policy, obs), apply(normalizer, policy, other))
    cut = jax.tree.map(lambda x: x, policy)
    for layer in ("intention_mean", "intention_log_std"):
        cut["params"][layer]["kernel"] = jp.zeros_like(cut["params"][layer]["kernel"])
    noise = jax.random.normal(jax.random.PRNGKey(5), (obs.shape[0], L))
    np.testing.assert_array_equal(apply(normalizer, cut, obs, noise), apply(normalizer, cut, other, noise))
    grad = jax.grad(lambda o: jp.sum(apply(normalizer, cut, o, noise)))(obs)
    assert float(jp.abs(grad[:, 2]).max()) == 0.0 and float(jp.abs(grad[:, :2]).max()) > 0.0


def test_bad_intention_configs_are_refused_in_one_line(tmp_path, capsys):
    argv = ["train", "test_point", "--preset", "tiny", "--out", str(tmp_path / "r"), "--no-video"]
    assert main([*argv, "--set", "network.architecture=intention"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("vnl: error:") and "observes none" in err
    assert not (tmp_path / "r").exists()
    for network, match in (
        ({"intention_size": 0}, "intention_size"),
        ({"kl_weight": -1.0}, "kl_weight"),
        ({"kl_weight": float("nan")}, "kl_weight"),
        ({"encoder_hidden_layer_sizes": []}, "encoder_hidden_layer_sizes"),
    ):
        with pytest.raises(VnlError, match=match):
            config(network)
    with pytest.raises(VnlError, match="without --vision"):
        train_config.build("test_point_ref", "tiny", file_values={"network": NETWORK, "vision": {"enabled": True}})


@pytest.fixture(scope="module")
def intention_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("intention") / "run"
    trainer.train(config(), out, say=quiet)
    return out


def assert_kl_logged_and_resume_bit_exact(run, make_config, res):
    """`run` (2K steps of `make_config()`) logged a finite, positive `training/intention_kl`, and K
    steps + `--resume` to 2K in `res` end bit for bit as it did; returns the final arrays."""
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    kls = [r["training/intention_kl"] for r in rows if "training/intention_kl" in r]
    assert kls and all(np.isfinite(kls)) and max(kls) > 0
    trainer.train(make_config(num_timesteps=K, num_evals=2), res, say=quiet)
    trainer.resume(res, flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    return assert_same_final_state(res, run)


@pytest.mark.slow
def test_an_intention_run_logs_its_kl_and_resumes_bit_exact(intention_run, tmp_path):
    final = assert_kl_logged_and_resume_bit_exact(intention_run, config, tmp_path / "res")
    assert any("intention_mean" in k for k in final)


@pytest.mark.slow
def test_an_intention_run_is_recorded_with_its_latent_and_exported(intention_run, tmp_path):
    rec = tmp_path / "rec.nc"
    assert main(["record", str(intention_run), "--episodes", "2", "--steps", "12", "--out", str(rec)]) == 0
    ds = xr.open_dataset(rec)
    for name, units in (("encoder_hidden_0", 16), ("encoder_intention_mean", L), ("policy_intention", L)):
        assert ds.sizes[f"{name}_unit"] == units
    assert {"encoder_intention_log_std", "policy_hidden_1", "policy_output", "value_hidden_0"} <= set(ds.data_vars)
    # Deterministic: the decoder read the mean; the loaded policy chooses the recorded actions.
    np.testing.assert_array_equal(ds["policy_intention"].values, ds["encoder_intention_mean"].values)
    policy = load_policy(intention_run)
    action = policy(jp.asarray(ds["observation"].values[:, :3]), jax.random.PRNGKey(0))
    np.testing.assert_allclose(action, ds["action"].values[:, :3], atol=1e-6)
    out = tmp_path / "pca.png"
    assert main(["analyze", str(rec), "--method", "pca", "--layer", "encoder_intention_mean", "--out", str(out)]) == 0
    from vnl.recording import nwb, nwb_reader

    path = nwb.write(ds, tmp_path / "rec.nwb", config="env: test_point_ref\n")
    back = nwb_reader.read(path)
    assert "encoder_intention_mean" in back.data_vars and back["encoder_intention_mean"].shape[-1] == L


@pytest.mark.slow
def test_an_intention_run_warm_starts_a_child_with_its_encoder_and_decoder(intention_run):
    values = {"init": {"run": str(intention_run)}, "env_config": {"impl": "c", "episode_length": 12}}
    values = config_lib.merge(warm_start.parent_defaults(intention_run), values)
    cfg = train_config.build("test_point_ref", "tiny", file_values=values)
    assert cfg.network.architecture == "intention" and cfg.network.intention_size == L
    parent = warm_start.load_parent(cfg)
    assert parent.sizes() == (3, 1)
    env = registry.make("test_point_ref", **cfg.env_config)
    parent = warm_start.check_layout(parent, env, "test_point_ref")
    loop = IntentionPPOLoop(env, cfg)
    ours = loop.to_arrays(warm_start.apply(loop, loop.init(cfg.seed), parent, keep_optimizer=False))
    for layer in ("encoder_0", "intention_mean", "decoder_1", "policy_head"):
        key = f".training.params.policy['params']['{layer}']['kernel']"
        np.testing.assert_array_equal(ours[key], parent.arrays[key])
