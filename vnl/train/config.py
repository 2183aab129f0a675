"""The one typed, frozen training config, and how presets, YAML, `--set` and flags combine.

Precedence (later wins): preset < YAML file < `--set key=value` < plain flags (`--steps`, ...).
Everything is validated before the environment is compiled.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Literal

from vnl import typed_config as config_lib
from vnl.envs import registry
from vnl.envs.randomize import RandomizeConfig
from vnl.errors import VnlError
from vnl.train import presets
from vnl.vision.env import VisionConfig
from vnl.walkers.from_file import file_sha256

MAX_ENVS = 2**20
MAX_LAYER = 2**16
MAX_EPISODE_LENGTH = 10**7
MAX_STEPS_PER_TRAINING_STEP = 2**31
MAX_STAGES = 1000
"""Sanity bounds: far above any real run, far below what would exhaust memory before failing."""
LIMITS = {  # key -> (upper bound, the fix): counts and sizes of a run (each also >= 1)
    "num_timesteps": (2**62, "train for fewer steps"),
    "num_envs": (MAX_ENVS, "use fewer parallel environments"),
    "batch_size": (MAX_ENVS, "use a smaller batch"),
    "num_minibatches": (2**16, "use fewer minibatches"),
    "num_updates_per_batch": (10**4, "use fewer updates per batch"),
    "unroll_length": (10**4, "use shorter unrolls"),
    "action_repeat": (10**3, "repeat each action fewer times"),
    "num_evals": (10**5, "evaluate less often"),
    "num_eval_envs": (MAX_ENVS, "evaluate on fewer environments"),
}


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Brax PPO hyperparameters (names as in `brax.training.agents.ppo.train`).

    One training step collects `batch_size * num_minibatches` trajectories of `unroll_length`
    steps from `num_envs` parallel environments.
    """

    num_timesteps: int = 1_000_000
    num_envs: int = 256
    batch_size: int = 256
    num_minibatches: int = 8
    num_updates_per_batch: int = 4
    unroll_length: int = 10
    learning_rate: float = 3e-4
    # None: a constant learning rate. A number: the rate falls linearly from `learning_rate` to it
    # over the first `learning_rate_decay_steps` env steps (None: all `num_timesteps`), then stays
    # there, as CleanRL's and SB3's PPO anneal it. config.yaml holds the resolved decay length, so
    # `vnl train --resume --steps` with a longer total keeps the schedule (and trains on at the
    # final rate) and a resumed run is the run never stopped.
    learning_rate_final: float | None = None
    learning_rate_decay_steps: int | None = None
    # None: no KL-adaptive rate. A number: Brax's ADAPTIVE_KL schedule (rsl_rl's rule for legged
    # robots): after each minibatch's gradient the rate is divided by 1.5 when the mean KL of the
    # policy to the one that collected the data exceeds 2x this, multiplied by 1.5 below half,
    # within [1e-5, 1e-2], starting from `learning_rate`; the observation normalizer is updated
    # after the SGD, as Brax does, so the KL compares policies on the same inputs.
    desired_kl: float | None = None
    entropy_cost: float = 1e-2
    discounting: float = 0.97
    gae_lambda: float = 0.95
    clipping_epsilon: float = 0.3
    reward_scaling: float = 10.0
    normalize_observations: bool = True
    max_grad_norm: float | None = None
    action_repeat: int = 1
    num_evals: int = 7
    num_eval_envs: int = 64
    deterministic_eval: bool = True
    episode_length: int | None = None  # None: the env's own `episode_length`

    def validate(self) -> None:
        positive = (
            "num_timesteps",
            "num_envs",
            "batch_size",
            "num_minibatches",
            "num_updates_per_batch",
            "unroll_length",
            "action_repeat",
            "num_evals",
            "num_eval_envs",
        )
        for key in positive:
            if getattr(self, key) < 1:
                raise VnlError(f"{key} must be >= 1, got {getattr(self, key)}")
        for key, (most, fix) in LIMITS.items():
            if getattr(self, key) > most:
                raise VnlError(f"{key} must be at most {most:,}, got {getattr(self, key):,}; {fix}")
        if self.env_steps_per_training_step > MAX_STEPS_PER_TRAINING_STEP:
            raise VnlError(
                f"batch_size × num_minibatches × unroll_length × action_repeat is {self.env_steps_per_training_step:,} "
                f"environment steps per training step (all held in memory), at most {MAX_STEPS_PER_TRAINING_STEP:,}; "
                "make one of them smaller"
            )
        for key in ("learning_rate", "reward_scaling"):
            if not getattr(self, key) > 0:
                raise VnlError(f"{key} must be > 0, got {getattr(self, key)}")
        if self.learning_rate_final is not None and self.learning_rate_final < 0:
            raise VnlError(f"learning_rate_final must be >= 0 (null: a constant rate), got {self.learning_rate_final}")
        if self.learning_rate_decay_steps is not None:
            if self.learning_rate_final is None:
                raise VnlError("learning_rate_decay_steps needs learning_rate_final (the rate it decays to)")
            if self.learning_rate_decay_steps < 1:
                raise VnlError(f"learning_rate_decay_steps must be >= 1, got {self.learning_rate_decay_steps}")
        if self.desired_kl is not None:
            if not self.desired_kl > 0:
                raise VnlError(f"desired_kl must be > 0 (null: no KL-adaptive rate), got {self.desired_kl}")
            if self.learning_rate_final is not None:
                raise VnlError("ppo.desired_kl and ppo.learning_rate_final are two learning-rate schedules; set one")
        if self.entropy_cost < 0:
            raise VnlError(f"entropy_cost must be >= 0, got {self.entropy_cost}")
        for key in ("discounting", "gae_lambda", "clipping_epsilon"):
            if not 0 < getattr(self, key) <= 1:
                raise VnlError(f"{key} must be in (0, 1], got {getattr(self, key)}")
        if (self.batch_size * self.num_minibatches) % self.num_envs:
            raise VnlError(
                f"batch_size × num_minibatches ({self.batch_size} × {self.num_minibatches} = "
                f"{self.batch_size * self.num_minibatches}) must be a multiple of num_envs "
                f"({self.num_envs}); e.g. set num_envs to {self.batch_size} or change batch_size"
            )
        if self.episode_length is not None and not 1 <= self.episode_length <= MAX_EPISODE_LENGTH:
            raise VnlError(f"episode_length must be in 1..{MAX_EPISODE_LENGTH:,}, got {self.episode_length}")
        if self.max_grad_norm is not None and self.max_grad_norm <= 0:
            raise VnlError(f"max_grad_norm must be > 0, got {self.max_grad_norm}")

    @property
    def env_steps_per_training_step(self) -> int:
        return self.batch_size * self.num_minibatches * self.unroll_length * self.action_repeat


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Brax's PPO policy and value networks: MLP sizes, and with `vision.enabled` the CNN that
    encodes each `pixels/` observation before the MLP (Brax's `networks_vision`; NatureCNN by
    default). `cnn_pool` reduces the last feature map: `avg`/`max` over space (C features),
    `spatial_softmax` (the expected x, y of each channel: 2C features, keeps *where* things are),
    `none` (flattened).

    The action distribution: `tanh_normal` (Brax's default) is a Gaussian whose location and
    scale the policy MLP outputs for each state, squashed by tanh; `normal` is a Gaussian whose
    location the MLP outputs and whose scale is one learned parameter per action, the same in
    every state (Brax's `PolicyModuleWithStd`; the env clips actions to the control range), as
    legged-robot PPO uses. `init_noise_std` is that scale at the start and `noise_std_type` how it
    is stored (`log`: exp of the parameter, always positive; `scalar`: the parameter itself).
    Neither applies to `tanh_normal`."""

    policy_hidden_layer_sizes: tuple[int, ...] = (32, 32, 32, 32)
    value_hidden_layer_sizes: tuple[int, ...] = (256, 256, 256, 256, 256)
    activation: Literal["swish", "relu", "tanh", "elu"] = "swish"
    cnn_channels: tuple[int, ...] = (32, 64, 64)
    cnn_kernel_sizes: tuple[int, ...] = (8, 4, 3)
    cnn_strides: tuple[int, ...] = (4, 2, 1)
    cnn_max_pool: bool = False  # a 2x2 max-pool after each convolution
    cnn_pool: Literal["avg", "max", "spatial_softmax", "none"] = "avg"
    distribution_type: Literal["tanh_normal", "normal"] = "tanh_normal"
    noise_std_type: Literal["log", "scalar"] = "log"
    init_noise_std: float = 1.0
    # A recurrent core between the encoder and the heads: an LSTM or a GRU of `core_size` units in
    # the policy and in the value network, each its own (vnl.train.recurrent); null: feed-forward
    # MLPs (docs/how-to/recurrent.md).
    core: Literal["lstm", "gru"] | None = None
    core_size: int = 128

    def validate(self) -> None:
        if not 1 <= self.core_size <= MAX_LAYER:
            raise VnlError(
                f"core_size must be in 1..{MAX_LAYER:,} units, got {self.core_size:,}; use a smaller recurrent core"
            )
        if not self.init_noise_std > 0:
            raise VnlError(f"init_noise_std must be > 0, got {self.init_noise_std}")
        for key, most, what in (
            ("policy_hidden_layer_sizes", MAX_LAYER, "units"),
            ("value_hidden_layer_sizes", MAX_LAYER, "units"),
            ("cnn_channels", 4096, "channels"),
            ("cnn_kernel_sizes", 512, "pixels (the largest image)"),
            ("cnn_strides", 512, "pixels (the largest image)"),
        ):
            sizes = getattr(self, key)
            if not sizes or any(s < 1 for s in sizes):
                raise VnlError(f"{key} must be a non-empty list of positive sizes, got {list(sizes)}")
            if any(s > most for s in sizes) or len(sizes) > 64:
                raise VnlError(
                    f"{key}: at most 64 layers of at most {most:,} {what}, got {list(sizes)[:8]}"
                    f"{' ...' if len(sizes) > 8 else ''}; use fewer or smaller layers"
                )
        n = len(self.cnn_channels)
        if len(self.cnn_kernel_sizes) != n or len(self.cnn_strides) != n:
            raise VnlError(
                f"cnn_channels, cnn_kernel_sizes and cnn_strides need one value per convolution; got "
                f"{n}, {len(self.cnn_kernel_sizes)} and {len(self.cnn_strides)} values"
            )


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
        return registry.make(self.env, vision=self.vision, **self.env_config)

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
    """The config with `env_config` expanded to the env's full config, a user's walker file
    pinned (`walker_xml` made absolute, its SHA-256 recorded) and the learning rate's decay length
    made explicit (what config.yaml holds)."""
    full = _pin_walker_file(config_lib.to_dict(config.resolved_env_config()))
    p = config.ppo
    if p.learning_rate_final is not None and p.learning_rate_decay_steps is None:
        p = dataclasses.replace(p, learning_rate_decay_steps=p.num_timesteps)
    return dataclasses.replace(config, env_config=full, ppo=p)


def _pin_walker_file(env_config: dict[str, Any]) -> dict[str, Any]:
    """`env_config` with its `walker_xml` (if any) absolute and `walker_xml_sha256` set."""
    xml = env_config.get("walker_xml")
    if not xml or "walker_xml_sha256" not in env_config:
        return env_config
    path = Path(xml).expanduser().absolute()
    return {**env_config, "walker_xml": str(path), "walker_xml_sha256": file_sha256(path)}


def read_config(run_dir: str | Path) -> TrainConfig:
    """The TrainConfig saved in `<run_dir>/config.yaml`."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise VnlError(f"run directory not found: {run_dir}")
    path = run_dir / "config.yaml"
    if not path.is_file():
        raise VnlError(f"{run_dir} is not a vnl run directory (no config.yaml)")
    return config_lib.from_dict(TrainConfig, with_fields_added_since(config_lib.load_yaml(str(path))))


_PLAIN = (bool, int, float, str, type(None), tuple)


def with_fields_added_since(values: dict[str, Any]) -> dict[str, Any]:
    """A saved run's values with the env config fields that vnl added after it was written.

    A saved `env_config` is complete (`resolved`), so a field missing from it did not exist then.
    It takes the field's class default (by convention off: the behaviour before the field), not
    the env's current default: a run saved before `rodent_run` observed its heading rebuilds the
    env it trained, with the observation width of its checkpoints. Unknown envs pass unchanged
    (`from_dict` reports them)."""
    env_config = values.get("env_config")
    if not isinstance(env_config, dict) or values.get("env") not in registry.names():
        return values
    fields = dataclasses.fields(type(registry.default_config(values["env"])))
    added = {f.name: f.default for f in fields if f.name not in env_config and isinstance(f.default, _PLAIN)}
    return {**values, "env_config": {**env_config, **config_lib.to_dict(added)}} if added else values
