"""The config rejects bad input with a message naming the key, before anything compiles."""

import dataclasses
from pathlib import Path

import pytest
import yaml

import vnl
from vnl import typed_config as config_lib
from vnl.envs import registry
from vnl.errors import VnlError
from vnl.train import config as train_config
from vnl.train import presets


def build(*assignments, **kw):
    return train_config.build("ant_run", "cpu", assignments=list(assignments), **kw)


def test_defaults_and_overrides_make_new_configs():
    base = build()
    changed = build("ppo.learning_rate=1e-3", "env_config.reset_noise_scale=0.05")
    assert changed.ppo.learning_rate == pytest.approx(1e-3)
    assert changed.resolved_env_config().reset_noise_scale == pytest.approx(0.05)
    # The shared default is untouched.
    assert base.ppo.learning_rate == pytest.approx(3e-4)
    assert train_config.PPOConfig().learning_rate == pytest.approx(3e-4)


@pytest.mark.parametrize(
    "assignment, words",
    [
        ("ppo.foo=1", ["ppo.foo", "valid keys", "learning_rate"]),
        ("bogus=1", ["bogus", "valid keys"]),
        ("ppo.num_envs=100", ["multiple of num_envs", "100"]),
        ("ppo.learning_rate=abc", ["ppo.learning_rate", "number"]),
        ("ppo.learning_rate=-1", ["learning_rate", "> 0"]),
        ("ppo.learning_rate_final=-1e-4", ["learning_rate_final", ">= 0"]),
        ("ppo.learning_rate_decay_steps=1000", ["learning_rate_decay_steps", "learning_rate_final"]),
        ("ppo.num_envs=2.5", ["ppo.num_envs", "integer"]),
        ("ppo.discounting=1.5", ["discounting"]),
        ("network.activation=gelu", ["network.activation", "swish"]),
        ("network.policy_hidden_layer_sizes=[]", ["policy_hidden_layer_sizes"]),
        ("env_config.reset_noise_scale=-1", ["reset_noise_scale", ">= 0"]),
        ("env_config.incline=50", ["incline", "(-45, 45)"]),
        ("env_config.nonsense=3", ["nonsense", "valid keys"]),
        ("env_config.healthy_z_range=[1.0, 0.5]", ["healthy_z_range"]),
        ("ppo.desired_kl=0", ["desired_kl", "> 0"]),
        ("log.checkpoint_every=0", ["checkpoint_every"]),
        ("log.keep_best=reward", ["keep_best", "eval/episode_reward", "null"]),
        ("seed=-3", ["seed"]),
        ("ppo.normalize_observations=3", ["normalize_observations", "true or false"]),
        ("noequals", ["key=value"]),
    ],
)
def test_bad_values_name_the_key(assignment, words):
    with pytest.raises(VnlError) as e:
        build(assignment)
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def test_learning_rate_decay_is_linear_over_its_steps_and_fixed_in_config_yaml():
    from vnl.ppo.loop import learning_rate

    assert learning_rate(build()) == pytest.approx(3e-4)  # no final rate: constant
    config = build("ppo.learning_rate_final=1e-5", "ppo.num_timesteps=204800")
    p = config.ppo
    updates = 204_800 // p.env_steps_per_training_step * p.num_updates_per_batch * p.num_minibatches
    schedule = learning_rate(config)
    assert float(schedule(0)) == pytest.approx(3e-4)
    assert float(schedule(updates // 2)) == pytest.approx((3e-4 + 1e-5) / 2)
    assert float(schedule(updates)) == float(schedule(10 * updates)) == pytest.approx(1e-5)
    # config.yaml holds the decay length, so a resume with a longer --steps keeps the schedule.
    assert train_config.resolved(config).ppo.learning_rate_decay_steps == 204_800
    assert train_config.resolved(build()).ppo.learning_rate_decay_steps is None


def test_two_learning_rate_schedules_are_refused():
    with pytest.raises(VnlError, match="desired_kl and ppo.learning_rate_final"):
        build("ppo.desired_kl=0.01", "ppo.learning_rate_final=0")
    # A kept optimizer would carry the parent's update count into the child's decay.
    with pytest.raises(VnlError, match="--keep-optimizer with ppo.learning_rate_final"):
        build("ppo.learning_rate_final=0", "init.run=/some/run", "init.keep_optimizer=true")


def test_unknown_env_and_preset_list_valid_names():
    with pytest.raises(VnlError, match="valid names are: ant_escape_bowl, ant_run, .*humanoid_run"):
        train_config.build("ant_walk", "cpu")
    with pytest.raises(VnlError, match="valid presets are: cpu, gpu, tiny"):
        train_config.build("ant_run", "fast")


@pytest.mark.parametrize("env", [n for n in vnl.names() if n not in registry.ALIASES])
def test_every_env_builds_with_every_preset(env):
    for preset in presets.names():
        cfg = train_config.build(env, preset)  # validates env_config and the curriculum's stages
        assert cfg.preset == preset


def test_humanoid_presets_train_the_envs_reshaped_rewards_with_clipping_at_their_scales():
    cpu, gpu = train_config.build("humanoid_run", "cpu"), train_config.build("humanoid_run", "gpu")
    task = registry.env_config("humanoid_run")
    assert (task.healthy_reward, task.healthy_min_upright, task.forward_velocity_cap) == (2.0, 0.7, 1.0)
    for key in ("healthy_reward", "healthy_min_upright", "forward_velocity_cap"):
        assert getattr(gpu.resolved_env_config(), key) == getattr(cpu.resolved_env_config(), key) == getattr(task, key)
        assert getattr(registry.env_config("brax_humanoid_run"), key) != getattr(task, key)  # Brax's own rewards
    assert gpu.ppo.max_grad_norm == cpu.ppo.max_grad_norm == 1.0
    assert gpu.ppo.num_envs == presets.generic("gpu")["ppo"]["num_envs"] > cpu.ppo.num_envs
    assert gpu.env_config.get("impl", "mjx") == "mjx" and cpu.env_config["impl"] == "c"


def test_precedence_preset_file_set_flags():
    cfg = train_config.build(
        "ant_run",
        "tiny",
        file_values={"ppo": {"num_timesteps": 1000, "learning_rate": 1e-3}, "seed": 4},
        assignments=["ppo.num_timesteps=2000"],
        flags={"ppo": {"num_timesteps": 3000}},
    )
    assert cfg.ppo.num_timesteps == 3000  # flag beats --set beats file beats preset
    assert cfg.ppo.learning_rate == pytest.approx(1e-3)  # file beats preset
    assert cfg.ppo.num_envs == 16  # preset
    assert cfg.seed == 4


def test_yaml_roundtrip(tmp_path):
    cfg = train_config.resolved(build("ppo.learning_rate=1e-3"))
    config_lib.dump_yaml(cfg, str(tmp_path / "c.yaml"))
    again = config_lib.from_dict(train_config.TrainConfig, config_lib.load_yaml(str(tmp_path / "c.yaml")))
    assert again == cfg


def test_yaml_file_errors(tmp_path):
    with pytest.raises(VnlError, match="not found"):
        config_lib.load_yaml(str(tmp_path / "missing.yaml"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("ppo: [unclosed\n")
    with pytest.raises(VnlError, match="not valid YAML"):
        config_lib.load_yaml(str(bad))
    lst = tmp_path / "list.yaml"
    lst.write_text("- 1\n- 2\n")
    with pytest.raises(VnlError, match="mapping"):
        config_lib.load_yaml(str(lst))


def test_file_for_another_env_is_refused():
    with pytest.raises(VnlError, match="humanoid_run"):
        train_config.build("ant_run", "cpu", file_values={"env": "humanoid_run"})


def test_make_rejects_bad_input_before_compiling():
    with pytest.raises(VnlError, match="valid names are"):
        vnl.make("rat_run")
    with pytest.raises(VnlError, match="unknown config key not_a_key"):
        vnl.make("ant_run", not_a_key=1)
    with pytest.raises(VnlError, match="reset_noise_scale must be >= 0"):
        vnl.make("humanoid_run", reset_noise_scale=-0.1)
    with pytest.raises(VnlError, match="walker"):
        vnl.make("ant_run", walker="rat")
    assert {
        "ant_run",
        "humanoid_run",
        "rodent_run",
        "rodent_run_gaps",
        "rodent_escape_bowl",
        "ant_run_gaps",
        "ant_escape_bowl",
    } <= set(vnl.names())


def test_a_run_saved_before_an_env_field_existed_reads_back_with_the_field_off(tmp_path):
    """A saved config.yaml is complete, so an env field missing from it was added to vnl later: it
    reads back as the field's class default (off), not the env's current default, and the run
    rebuilds the env its checkpoints were trained on. A field that is present keeps its value."""
    cfg = train_config.resolved(train_config.build("rodent_run", "cpu"))
    assert cfg.env_config["observe_heading"] is True  # rodent_run's default today
    config_lib.dump_yaml(cfg, str(tmp_path / "config.yaml"))
    assert train_config.read_config(tmp_path) == cfg
    old = config_lib.load_yaml(str(tmp_path / "config.yaml"))
    del old["env_config"]["observe_heading"]
    config_lib.dump_yaml(old, str(tmp_path / "config.yaml"))
    back = train_config.read_config(tmp_path)
    assert back.env_config["observe_heading"] is False
    assert back.resolved_env_config().observe_heading is False
    assert dataclasses.replace(back, env_config={**back.env_config, "observe_heading": True}) == cfg


RESOLVED = yaml.safe_load((Path(__file__).parent / "data" / "resolved_presets.yaml").read_text())
"""Every env x preset resolved before the presets moved from the env registry to
vnl/train/presets/ (2026-11-26): the move changed no preset, and a later edit of a preset shows here.
2026-11-27: the task rules that cpu presets set moved into the envs' defaults (an env name is one
task): no cpu row changed; gpu and tiny rows gained the rules and cameras the cpu rows had.
2026-11-28: rodent_imitate steps with 8 Newton and line-search iterations (was 4), all presets.
2026-11-28: suites gained env_config.reward_scales (null: every task's reward as it is).
2026-11-29: maze forage and two-touch gained the fall rules (vnl.tasks.falls), off: null and 0.0.
2026-11-29: every preset gained `algorithm: ppo` and the `sac` section (vnl.ppo.sac), unused by PPO.
2026-11-29: the `sac` section gained `actor_delay: 0` (off).
2026-11-29: the `sac` section gained `init_alpha: 1.0` and `target_entropy: null` (Brax's temperature).
2026-11-29: maze forage, two-touch and the rodent suite gained `healthy_min_height: null` (off).
2026-12-01: every preset gained the `levels` section (terrain levels, vnl.envs.levels), off: count 0.
2026-12-01: the bowls (and the suites that hold one) gained `spawn_distance: 0.0` (the centre).
2026-12-02: the walker tasks gained `new_episode_on_reset` (false; maze forage and imitation true,
as they redrew their episodes before).
2026-12-02: every preset gained `ppo.normalize_advantage: batch` (Brax's, as before).
2026-12-02: rodent_run_gaps_vision (new: the corridor seen through the rat's camera)."""


def test_the_env_fields_added_since_leave_a_configs_hash_as_it_was_before_them():
    """A run saved before `new_episode_on_reset`, `spawn_distance` or `ppo.normalize_advantage`
    existed hashes as it did then (a warm-started child's `init.config_hash` still matches its
    parent); set otherwise, they change the hash."""
    import hashlib

    cases = (
        ("ant_run_gaps", "env_config", "new_episode_on_reset", True),
        ("ant_escape_bowl", "env_config", "spawn_distance", 2.0),
        ("ant_run", "ppo", "normalize_advantage", "none"),
    )
    for env, section, key, other in cases:
        cfg = train_config.resolved(train_config.build(env, "tiny"))
        unused = ("log", "decoder", "levels", "algorithm", "sac")  # the sections a PPO run's hash leaves out
        before = {k: v for k, v in config_lib.to_dict(cfg).items() if k not in unused}
        for added in ("new_episode_on_reset", "spawn_distance"):
            before["env_config"].pop(added, None)
        before["ppo"].pop("normalize_advantage")
        assert cfg.content_hash() == hashlib.sha256(yaml.safe_dump(before, sort_keys=True).encode()).hexdigest()[:16]
        was = getattr(cfg, section)
        now = {**was, key: other} if isinstance(was, dict) else dataclasses.replace(was, **{key: other})
        assert dataclasses.replace(cfg, **{section: now}).content_hash() != cfg.content_hash()


@pytest.mark.parametrize("name", sorted(RESOLVED))
def test_print_config_gives_each_presets_saved_resolved_config(name, capsys):
    from vnl.cli import main

    env, preset = name.split("/")
    assert main(["train", env, "--preset", preset, "--print-config"]) == 0
    assert yaml.safe_load(capsys.readouterr().out) == RESOLVED[name]


def test_print_config_is_what_config_yaml_holds(tmp_path, capsys):
    """--print-config with --set and flags prints the text `vnl train` writes to config.yaml."""
    from vnl.cli import main
    from vnl.train.rundir import prepare_run_dir

    args = ["ant_run", "--preset", "tiny", "--set", "ppo.learning_rate_final=0", "--steps", "8192", "--seed", "3"]
    assert main(["train", *args, "--print-config"]) == 0
    printed = capsys.readouterr().out
    config = train_config.build(
        "ant_run", "tiny", None, ["ppo.learning_rate_final=0"], {"ppo": {"num_timesteps": 8192}, "seed": 3}
    )
    prepare_run_dir(tmp_path / "run", config)
    assert printed == (tmp_path / "run" / "config.yaml").read_text()
    assert "learning_rate_decay_steps: 8192" in printed and "seed: 3" in printed


def test_the_env_registry_holds_no_training_settings():
    """name -> factory, default env config, description; presets live in vnl/train/presets/."""
    assert [f.name for f in dataclasses.fields(registry.Entry)] == [
        "factory",
        "default_config",
        "description",
        "vision",
    ]
    source = Path(registry.__file__).read_text()
    assert "ppo" not in source and "network" not in source
    for path in presets.DIRECTORY.glob("*.yaml"):  # every preset file loads and names only presets
        presets._file(path.stem)
