"""The one typed, frozen training config, and how presets, YAML, `--set` and flags combine.

Precedence (later wins): preset < YAML file < `--set key=value` < plain flags (`--steps`, ...).
Everything is validated before the environment is compiled.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from vnl import typed_config as config_lib
from vnl.envs import registry
from vnl.envs.levels import LevelsConfig, check_fields, config_value, field_paths
from vnl.envs.randomize import RandomizeConfig
from vnl.envs.suite import SuiteConfig
from vnl.errors import VnlError
from vnl.ppo.config import (  # noqa: F401 - PPO's settings, part of a run's config (and importable from here)
    INTENTION_NEEDS_FLAT,
    LIMITS,
    MAX_ENVS,
    MAX_EPISODE_LENGTH,
    MAX_LAYER,
    MAX_STEPS_PER_TRAINING_STEP,
    NetworkConfig,
    PPOConfig,
    SACConfig,
    intention_without_reference,
)
from vnl.train import config_compat, presets
from vnl.vision.env import VisionConfig
from vnl.walkers.from_file import file_sha256

MAX_STAGES = 1000
"""At most this many curriculum stages."""


@dataclasses.dataclass(frozen=True)
class LogConfig:
    """What a run writes besides metrics.jsonl."""

    checkpoint_every: int = 1  # write a checkpoint every N evaluations
    keep_checkpoints: int = 5  # newest N kept; 0 keeps all
    # Also keep the checkpoint whose evaluation scored highest on this metric (of the evaluations
    # checkpointed, every `checkpoint_every`), so a policy that later unlearns is not lost; `vnl
    # eval/render/record RUN --step best` and `--init-from RUN --step best` load it. null: only the newest.
    keep_best: str | None = "eval/episode_reward"
    video: bool = True  # an .mp4 of the final policy
    video_camera: str | None = None  # None: the env's default tracking camera
    video_seconds: float = 10.0
    video_width: int = 480
    video_height: int = 360
    progress: bool = True  # a progress line on the terminal
    tensorboard: bool = False  # TensorBoard event files in <run>/tensorboard/
    wandb: bool = False  # a Weights & Biases run in <run>/wandb/ (pip install 'vnl[wandb]')
    wandb_project: str = "vnl"
    wandb_name: str | None = None  # None: the run directory's name
    wandb_tags: tuple[str, ...] = ()
    wandb_mode: Literal["auto", "offline", "online"] = "auto"  # auto: online once `wandb login` was run

    def validate(self) -> None:
        if self.checkpoint_every < 1:
            raise VnlError(f"checkpoint_every must be >= 1, got {self.checkpoint_every}")
        if self.keep_checkpoints < 0:
            raise VnlError(f"keep_checkpoints must be >= 0, got {self.keep_checkpoints}")
        if self.keep_best is not None and not self.keep_best.startswith(("eval/", "training/")):
            raise VnlError(
                f"keep_best must name a metric of metrics.jsonl (eval/... or training/...), got {self.keep_best!r}; "
                "e.g. eval/episode_reward, or null to keep only the newest checkpoints"
            )
        if not 0 < self.video_seconds <= 3600:
            raise VnlError(f"video_seconds must be in (0, 3600], got {self.video_seconds}; videos are at most an hour")
        for key in ("video_width", "video_height"):
            if not 16 <= getattr(self, key) <= 4096:
                raise VnlError(
                    f"{key} must be in 16..4,096 pixels, got {getattr(self, key):,}; MuJoCo's offscreen buffer "
                    "goes to 4,096"
                )


@dataclasses.dataclass(frozen=True)
class InitConfig:
    """A warm start (`vnl train ENV --init-from RUN_DIR`): the run begins with another run's policy,
    value network and observation normalizer (`vnl.train.warm_start`).

    `step` None means the parent's newest checkpoint; the config.yaml of the new run records the
    step used and `config_hash`, the hash of the parent's config (`warm_start.config_hash`).
    `keep_optimizer` also takes the parent's Adam state (moments and step count); by default the
    optimizer starts fresh.
    """

    run: str | None = None
    step: int | None = None
    keep_optimizer: bool = False
    config_hash: str | None = None

    def validate(self) -> None:
        if self.run is None and (self.step is not None or self.keep_optimizer):
            raise VnlError("init.step and init.keep_optimizer need init.run (--init-from RUN_DIR)")
        if self.step is not None and self.step < 0:
            raise VnlError(f"init.step must be >= 0, got {self.step}")


@dataclasses.dataclass(frozen=True)
class DecoderConfig:
    """A frozen decoder (`--set decoder.run=RUN_DIR`): the run's policy acts in the latent space
    of another run's intention network, whose decoder, frozen, turns each latent into the body's
    actions (`vnl.train.frozen_decoder`; docs/how-to/intention-network.md).

    The policy's action a (intention_size,) in [-1, 1] is the latent `latent_scale` × a. `step`
    None means the decoder run's newest checkpoint; the run's config.yaml records the step used,
    the directory as an absolute path and `config_hash`, the hash of the decoder run's config."""

    run: str | None = None
    step: int | None = None
    # 2: the latent's prior is N(0, I), and ±2 standard deviations hold 95% of it.
    latent_scale: float = 2.0
    config_hash: str | None = None

    def validate(self) -> None:
        # Messages name the key without the section: the caller (typed_config) prefixes "decoder.".
        for key in ("step", "config_hash"):
            if self.run is None and getattr(self, key) is not None:
                raise VnlError(f"{key} needs decoder.run (the run whose intention network's decoder to reuse)")
        if self.step is not None and self.step < 0:
            raise VnlError(f"step must be >= 0, got {self.step}")
        if not 0 < self.latent_scale <= 100:
            raise VnlError(f"latent_scale must be in (0, 100] (latent units per action unit), got {self.latent_scale}")


@dataclasses.dataclass(frozen=True)
class StageConfig:
    """One stage of a curriculum: `env_config` overrides (of the run's own env_config) trained for
    `steps` environment steps (`vnl.train.curriculum`)."""

    steps: int
    env_config: dict[str, Any] = dataclasses.field(default_factory=dict)
    name: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "env_config", config_lib.freeze(self.env_config))  # no shared mutable dict

    def validate(self) -> None:
        if self.steps < 1:
            raise VnlError(f"steps must be >= 1, got {self.steps}")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training run (written to `<run>/config.yaml`).

    `env_config` holds overrides of the env's default config when given by the user; in a saved
    config.yaml it holds the full resolved env config.
    """

    env: str
    env_config: dict[str, Any] = dataclasses.field(default_factory=dict)
    preset: str = "cpu"
    seed: int = 0
    ppo: PPOConfig = PPOConfig()
    network: NetworkConfig = NetworkConfig()
    log: LogConfig = LogConfig()
    randomize: RandomizeConfig = RandomizeConfig()  # domain randomization (vnl.envs.randomize)
    vision: VisionConfig = VisionConfig()  # pixel observations from an in-graph camera (vnl.vision)
    init: InitConfig = InitConfig()  # warm start from another run (vnl.train.warm_start)
    curriculum: tuple[StageConfig, ...] = ()  # stages of env_config overrides (vnl.train.curriculum)
    levels: LevelsConfig = LevelsConfig()  # terrain levels, an automatic curriculum (vnl.envs.levels)
    decoder: DecoderConfig = DecoderConfig()  # act through another run's frozen decoder (vnl.train.frozen_decoder)
    # The learner: Brax's PPO (vnl.ppo.loop), or soft actor-critic from a replay buffer (vnl.ppo.sac,
    # its hyperparameters in `sac`; docs/how-to/sac.md).
    algorithm: Literal["ppo", "sac"] = "ppo"
    sac: SACConfig = SACConfig()

    def __post_init__(self) -> None:
        # A frozen config must not hold a dict someone else can change (or that it shares).
        object.__setattr__(self, "env_config", config_lib.freeze(self.env_config))

    def validate(self) -> None:
        presets.check_name(self.preset)
        env_config = registry.env_config(self.env, self.env_config)  # raises on unknown env or bad overrides
        if self.randomize.enabled and getattr(env_config, "backend", "mjx") != "mjx":
            raise VnlError(
                f"randomize: domain randomization changes MJX's model only; env_config.backend is "
                f"{env_config.backend!r}. Use backend: mjx or turn randomize off"
            )
        if not 0 <= self.seed <= config_lib.MAX_SEED:
            raise VnlError(f"seed must be in 0..{config_lib.MAX_SEED} (JAX uses 32 bits of it), got {self.seed}")
        if self.init.keep_optimizer and self.ppo.learning_rate_final is not None:
            raise VnlError(
                "--keep-optimizer with ppo.learning_rate_final: the decay counts the optimizer's updates, so it "
                "would go on from the parent's count instead of starting at learning_rate; drop one of them"
            )
        self._validate_curriculum()
        if self.levels.enabled:
            self._validate_levels(env_config)
        if isinstance(env_config, SuiteConfig):
            self._validate_suite(env_config)
        elif self.ppo.normalize_advantage == "task":
            raise VnlError(f"ppo.normalize_advantage=task is per task of a suite; {self.env} is one task: use batch")
        if self.decoder.run is not None:
            self._validate_decoder()
        if self.network.architecture == "intention":
            self._validate_intention()
        if self.algorithm == "sac":
            self._validate_sac(env_config)

    def _validate_sac(self, env_config: Any) -> None:
        """Soft actor-critic trains a feed-forward policy on a flat observation of one env (a
        curriculum's stages hand on the replay buffer with the rest of the training state)."""
        p = self.ppo
        unsupported = {
            "--vision (its networks read a flat observation)": self.vision.enabled,
            "network.core (a feed-forward policy and Q networks)": self.network.core is not None,
            f"network.architecture {self.network.architecture}": self.network.architecture != "brax",
            "a suite of tasks": isinstance(env_config, SuiteConfig),
            "--keep-optimizer (SAC's three optimizers are not PPO's)": self.init.keep_optimizer,
            "decoder.run": self.decoder.run is not None,
            "randomize": self.randomize.enabled,
        }
        refused = [name for name, on in unsupported.items() if on]
        if refused:
            raise VnlError(f"algorithm sac cannot train with {refused[0]} yet; turn it off or use algorithm ppo")
        if self.sac.max_replay_size < p.num_envs:
            raise VnlError(
                f"sac.max_replay_size ({self.sac.max_replay_size:,}) must hold one step of every env "
                f"(ppo.num_envs = {p.num_envs:,})"
            )

    def _validate_suite(self, env_config: SuiteConfig) -> None:
        """A suite trains one flat-observation network on all its tasks at once (`vnl.envs.suite`)."""
        unsupported = {
            "--vision (a suite's observation is its tasks' flat union)": self.vision.enabled,
            "decoder.run": self.decoder.run is not None,
            "randomize": self.randomize.enabled,
            "network.architecture: intention": self.network.architecture == "intention",
        }
        refused = [name for name, on in unsupported.items() if on]
        if refused:
            raise VnlError(f"{self.env} is a suite of tasks, which cannot train with {refused[0]} yet; turn it off")
        tasks, shares = len(env_config.tasks), sum(env_config.shares or (1,) * len(env_config.tasks))
        if self.ppo.num_eval_envs % tasks or self.ppo.num_envs % shares:
            raise VnlError(
                f"{self.env}: ppo.num_eval_envs ({self.ppo.num_eval_envs}) must be a multiple of its {tasks} tasks "
                f"and ppo.num_envs ({self.ppo.num_envs}) of the sum of their shares ({shares})"
            )

    def check_trainable(self) -> None:
        """`VnlError` for what a valid config can evaluate but not train: one task of a suite
        (`env_config.task`, which eval, record and render take), and terrain levels that change
        nothing (a levels run's checkpoints evaluated on its easiest terrain: `vnl eval RUN --set
        env_config...`)."""
        if self.levels.enabled and not self._levels_vary():
            raise VnlError(
                "levels change nothing: levels.easiest equals the env config of the run (and of every curriculum "
                "stage); give level 0 easier values"
            )
        task = getattr(self.resolved_env_config(), "task", None)
        if isinstance(self.resolved_env_config(), SuiteConfig) and task is not None:
            raise VnlError(
                f"env_config.task={task} picks one task of {self.env} for eval, record and render; a suite "
                f"trains on env_config.tasks (to train {task} alone, train that env)"
            )

    def _validate_decoder(self) -> None:
        """A frozen decoder drives a flat-observation env through a brax or merel policy."""
        if self.vision.enabled:
            raise VnlError(
                "decoder.run with --vision: a frozen decoder reads a flat observation; train without --vision"
            )
        if self.network.architecture == "intention":
            raise VnlError(
                "decoder.run gives the run another run's decoder; its own network must not be an intention "
                "network too (network.architecture brax or merel)"
            )

    def _validate_intention(self) -> None:
        """The intention network needs a flat observation with a reference part (`vnl.ppo.intention`):
        an env class that declares no `reference_blocks` is refused here, before anything is built."""
        if self.vision.enabled:
            raise VnlError(INTENTION_NEEDS_FLAT)
        factory = registry.entry(self.env).factory
        if isinstance(factory, type) and not getattr(factory, "reference_blocks", ()):
            raise VnlError(intention_without_reference(self.env))

    def _validate_levels(self, env_config: Any) -> None:
        """Terrain levels vary fields the env declares (`level_fields`), within a valid env config."""
        unsupported = {
            "--vision (its camera renders after the batch's reset)": self.vision.enabled,
            "randomize": self.randomize.enabled,
            "a suite of tasks": isinstance(env_config, SuiteConfig),
            "decoder.run": self.decoder.run is not None,
        }
        refused = [name for name, on in unsupported.items() if on]
        if refused:
            raise VnlError(f"levels cannot train with {refused[0]} yet; turn one of them off")
        check_fields(self.env, getattr(registry.entry(self.env).factory, "level_fields", ()), self.levels.easiest)
        self._levels_vary()

    def _levels_vary(self) -> bool:
        """Whether level 0 (each stage's env config with `levels.easiest`, a valid env config or a
        `VnlError` naming the stage) differs from the stage's own config in any stage."""
        easiest = dict(self.levels.easiest)
        stages = [config_lib.merge(self.env_config, s.env_config) for s in self.curriculum] or [self.env_config]
        varies = False
        for i, env_config in enumerate(stages):
            try:
                easy = registry.env_config(self.env, config_lib.merge(env_config, easiest))
            except VnlError as e:
                raise VnlError(f"levels.easiest{f' (curriculum[{i}])' if self.curriculum else ''}: {e}") from None
            hard = registry.env_config(self.env, env_config)
            varies |= any(
                not np.array_equal(np.asarray(config_value(easy, p)), np.asarray(config_value(hard, p)))
                for p in field_paths(easiest)
            )
        return varies

    def _validate_curriculum(self) -> None:
        """Every stage's env config is valid, and the stages' steps add up to ppo.num_timesteps."""
        if len(self.curriculum) > MAX_STAGES:
            raise VnlError(
                f"curriculum has {len(self.curriculum):,} stages, at most {MAX_STAGES:,} (each builds its own "
                "world); merge stages"
            )
        for i, stage in enumerate(self.curriculum):
            try:
                registry.env_config(self.env, config_lib.merge(self.env_config, stage.env_config))
            except VnlError as e:
                raise VnlError(f"curriculum[{i}].env_config: {e}") from None
        total = sum(stage.steps for stage in self.curriculum)
        if self.curriculum and self.ppo.num_timesteps != total:
            raise VnlError(
                f"with a curriculum the run's length is the sum of its stages' steps ({total:,}), but "
                f"ppo.num_timesteps is {self.ppo.num_timesteps:,}; drop --steps / ppo.num_timesteps, change "
                "the stages' steps, or train without the curriculum (--set curriculum=[])"
            )

    def stage(self, index: int) -> TrainConfig:
        """The config that curriculum stage `index` trains with: `env_config` with the stage's
        overrides, no curriculum."""
        overrides = self.curriculum[index].env_config
        return dataclasses.replace(self, env_config=config_lib.merge(self.env_config, overrides), curriculum=())

    def make_env(self) -> Any:
        """The env this config trains: the registered env with `env_config`, seeing through
        `vision`'s camera when it is enabled (a `VnlError` for an unknown camera)."""
        env = registry.make(self.env, vision=self.vision, **self.env_config)
        if self.decoder.run is None:
            return env
        from vnl.train import frozen_decoder

        env = frozen_decoder.wrap(env, self.decoder, self.decoder_run_config())
        if env.stateful and self.ppo.action_repeat != 1:  # its core would step once per repeat, not per control step
            raise VnlError(
                f"decoder.run {self.decoder.run}: a recurrent decoder steps once per control step, and "
                f"ppo.action_repeat is {self.ppo.action_repeat}; set ppo.action_repeat to 1"
            )
        return env

    def decoder_run_config(self) -> TrainConfig:
        """The saved config of `decoder.run`; a `VnlError` that names decoder.run if it is none."""
        try:
            return read_config(self.decoder.run)
        except VnlError as e:
            raise VnlError(f"decoder.run: {e}") from None

    def content_hash(self) -> str:
        """A short hash of this config without its `log` section (what a resume may change); an
        unused `decoder` section is left out too, so runs written before it keep their hash."""
        values = {k: v for k, v in config_lib.to_dict(self).items() if k != "log"}
        if self.decoder == DecoderConfig():
            values.pop("decoder")
        if self.levels == LevelsConfig():  # runs from before terrain levels keep their hash
            values.pop("levels")
        values = config_compat.without_added_at_default(values)  # runs from before these keys keep their hash
        if self.algorithm == "ppo" and self.sac == SACConfig():  # runs from before SAC keep their hash
            values.pop("algorithm")
            values.pop("sac")
        return hashlib.sha256(yaml.safe_dump(values, sort_keys=True).encode()).hexdigest()[:16]

    def resolved_env_config(self) -> Any:
        """The env's full frozen config with `env_config` applied."""
        return registry.env_config(self.env, self.env_config)

    def episode_length(self) -> int:
        return self.ppo.episode_length or self.resolved_env_config().episode_length


def default_preset() -> str:
    """`cpu` when JAX has no accelerator, else `gpu`."""
    import jax

    return "cpu" if jax.default_backend() == "cpu" else "gpu"


def build(
    env: str,
    preset: str | None = None,
    file_values: dict[str, Any] | None = None,
    assignments: list[str] | None = None,
    flags: dict[str, Any] | None = None,
) -> TrainConfig:
    """Combines preset < YAML file values < `--set` assignments < plain flags into a config."""
    file_values = dict(file_values or {})
    if "env" in file_values and file_values["env"] != env:
        raise VnlError(f"the config file is for env {file_values['env']!r} but {env!r} was asked for")
    if "preset" in file_values:  # checked even when --preset overrides it: never silently ignored
        presets.check_name(file_values["preset"])
    preset = presets.check_name(preset or file_values.get("preset") or default_preset())
    start = {"env": env, "preset": preset, "vision": registry.vision_defaults(env)}  # the env's own camera
    values: dict[str, Any] = config_lib.merge(start, presets.resolve(env, preset))
    values = config_lib.merge(values, file_values)
    values["preset"] = preset
    for text in assignments or []:
        values = config_lib.merge(values, config_lib.parse_assignment(text))
    values = config_lib.merge(values, flags or {})
    explicit = [file_values, flags or {}, *(config_lib.parse_assignment(a) for a in assignments or [])]
    given = any(isinstance(v.get("ppo"), dict) and "num_timesteps" in v["ppo"] for v in explicit)
    values = _curriculum_length(values, given)
    return config_lib.from_dict(TrainConfig, values)


def _curriculum_length(values: dict[str, Any], explicit: bool) -> dict[str, Any]:
    """With a curriculum, `ppo.num_timesteps` defaults to the sum of the stages' steps (a value
    given explicitly is kept, and `TrainConfig.validate` says when it disagrees)."""
    stages = values.get("curriculum")
    if explicit or not isinstance(stages, (list, tuple)) or not stages:
        return values
    try:
        total = sum(int(stage["steps"]) for stage in stages)
    except (TypeError, KeyError, ValueError):
        return values  # malformed stages: `from_dict` names the problem
    return config_lib.merge(values, {"ppo": {"num_timesteps": total}})


def resolved(config: TrainConfig) -> TrainConfig:
    """The config with `env_config` expanded to the env's full config, a user's files pinned
    (`walker_xml` and `clips` made absolute, their SHA-256 recorded: `PINNED_FILES`) and the
    learning rate's decay length made explicit (what config.yaml holds)."""
    full = _pin_files(config_lib.to_dict(config.resolved_env_config()))
    p = config.ppo
    if p.learning_rate_final is not None and p.learning_rate_decay_steps is None:
        p = dataclasses.replace(p, learning_rate_decay_steps=p.num_timesteps)
    return dataclasses.replace(config, env_config=full, ppo=p)


PINNED_FILES = {"walker_xml": "walker_xml_sha256", "clips": "clips_sha256"}
"""The env config's user files (a walker's MJCF, an imitation's clips) and the field that holds
each one's SHA-256 in a run's config.yaml."""


def _pin_files(env_config: dict[str, Any]) -> dict[str, Any]:
    """`env_config` with each of its `PINNED_FILES` that is set made absolute and its SHA-256 set."""
    pinned = dict(env_config)
    for key, sha in PINNED_FILES.items():
        name = env_config.get(key)
        if name and sha in env_config:
            path = Path(name).expanduser().absolute()
            pinned.update({key: str(path), sha: file_sha256(path)})
    return pinned


def read_config(run_dir: str | Path) -> TrainConfig:
    """The TrainConfig saved in `<run_dir>/config.yaml`."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise VnlError(f"run directory not found: {run_dir}")
    path = run_dir / "config.yaml"
    if not path.is_file():
        raise VnlError(f"{run_dir} is not a vnl run directory (no config.yaml)")
    return config_lib.from_dict(TrainConfig, config_compat.with_fields_added_since(config_lib.load_yaml(str(path))))
