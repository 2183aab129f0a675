"""vnl/train/presets: a preset chooses compute, never the task. Every env name is one task under
every preset and in `vnl.make`: the same rules (env config outside the compute fields), the same
camera, the same observation and action sizes."""

import dataclasses

import pytest

import vnl
from vnl import typed_config as config_lib
from vnl.envs import registry
from vnl.errors import VnlError
from vnl.train import config as train_config
from vnl.train import presets
from vnl.train.worlds import Worlds
from vnl.vision.env import VisionConfig

ENVS = [n for n in vnl.names() if n not in registry.ALIASES]


def _rules(env_config: dict) -> dict:
    """The task's rules: the config but its compute fields (a suite's members' too: the suite's own
    are copied into them)."""
    kept = {k: v for k, v in env_config.items() if k not in registry.COMPUTE_FIELDS}
    return {k: _rules(v) if isinstance(v, dict) and "impl" in v else v for k, v in kept.items()}


def _camera(vision: VisionConfig) -> dict:
    return {k: v for k, v in dataclasses.asdict(vision).items() if k not in registry.VISION_COMPUTE_FIELDS}


@pytest.mark.parametrize("env", ENVS)
def test_an_env_name_is_one_task_under_every_preset_and_in_make(env):
    seeing = train_config.build(env, "cpu").vision.enabled  # rodent_run_gaps_vision: under every preset
    made = vnl.make(env, impl="c", vision=seeing)
    task = _rules(config_lib.to_dict(made.config))
    camera = _camera(config_lib.from_dict(VisionConfig, registry.vision_defaults(env)))
    sizes = {}
    for preset in presets.names():
        config = train_config.build(env, preset)
        assert _rules(config_lib.to_dict(config.resolved_env_config())) == task, preset
        assert _camera(config.vision) == camera and config.vision.enabled == seeing, preset
        # The env it trains (a curriculum's first stage), on C physics: built in milliseconds.
        first = Worlds(train_config.build(env, preset, file_values={"env_config": {"impl": "c", "threads": 1}}))
        built = first.env(0)
        sizes[preset] = (str(built.observation_size), built.action_size)
    assert set(sizes.values()) == {(str(made.observation_size), made.action_size)}, sizes


def test_a_preset_that_sets_a_task_rule_is_refused(tmp_path, monkeypatch):
    for bad, key in (
        ({"cpu": {"env_config": {"healthy_reward": 2.0}}}, "env_config.healthy_reward"),
        ({"gpu": {"vision": {"width": 32}}}, "vision.width"),
    ):
        with pytest.raises(VnlError, match=rf"{key} is a rule of the task, which a preset may not change"):
            presets.register("ant_run", bad)
    presets.register("ant_run", {"cpu": {"env_config": {"impl": "jax", "threads": 1}, "vision": {"chunk": 8}}})
    presets.unregister("ant_run")
    # A preset file that sets a rule is a packaging mistake found when the file is read.
    monkeypatch.setattr(presets, "DIRECTORY", tmp_path)
    presets._file.cache_clear()
    try:
        (tmp_path / "ant_run.yaml").write_text("cpu:\n  env_config:\n    ground_scan: [0.0]\n")
        with pytest.raises(VnlError, match="ant_run.yaml: cpu: env_config.ground_scan is a rule of the task"):
            presets.for_env("ant_run", "cpu")
    finally:
        presets._file.cache_clear()


def test_a_curriculum_stage_may_change_the_rules_while_it_lasts():
    config = train_config.build("rodent_run_gaps", "cpu")
    assert config.curriculum[0].env_config["healthy_reward"] == 0.2
    assert config.stage(0).resolved_env_config().healthy_reward == 0.2
    assert config.resolved_env_config().healthy_reward == registry.default_config("rodent_run_gaps").healthy_reward


def test_make_with_vision_sees_through_the_envs_own_camera():
    """`vnl.make(env, vision=True)` and `--vision` use the env's camera settings; a dict changes some."""
    assert registry.vision_defaults("find_target") == {"width": 32, "height": 32}
    env = vnl.make("find_target", vision=True)
    assert env.observation_size["pixels/egocentric"] == (32, 32, 3)
    wider = vnl.make("find_target", vision={"width": 48})
    assert wider.observation_size["pixels/egocentric"] == (32, 48, 3)
    with pytest.raises(VnlError, match="unknown config key vision.colour"):
        registry.register(
            "odd", registry.entry("ant_run").factory, registry.default_config("ant_run"), "", {"colour": 1}
        )
    assert "odd" not in registry.names()
