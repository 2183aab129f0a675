"""PPO's own settings: its hyperparameters (`PPOConfig`), its networks (`NetworkConfig`), their
bounds, and `RunSettings`, what the algorithm reads of a run's config (`vnl.train.config.TrainConfig`
is one)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal, Protocol

from vnl.errors import VnlError

MAX_ENVS = 2**20
MAX_LAYER = 2**16
MAX_EPISODE_LENGTH = 10**7
MAX_STEPS_PER_TRAINING_STEP = 2**31
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
    # batch: the minibatch's advantages less their mean, over their std (Brax's); task: a suite's
    # tasks each by their own (vnl.ppo.losses); none: as computed.
    normalize_advantage: Literal["batch", "task", "none"] = "batch"
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
class SACConfig:
    """Soft actor-critic's own hyperparameters (`algorithm: sac`, `vnl.ppo.sac`; names as in
    `brax.training.agents.sac.train`). The run's sizes stay in `ppo`: num_timesteps, num_envs,
    num_evals, num_eval_envs, episode_length, action_repeat, deterministic_eval and
    normalize_observations (its other keys, PPO's batch and schedules, are unused, so a preset made
    for PPO trains SAC); the networks in `network` (the policy's `policy_hidden_layer_sizes`, the
    two Q networks' `value_hidden_layer_sizes`, `activation`, the action distribution).

    Each training step steps every env once (`ppo.num_envs` transitions into the replay buffer),
    then makes `grad_updates_per_step` updates of `batch_size` transitions each, once the buffer
    holds `min_replay_size`: the update-to-data ratio is grad_updates_per_step / ppo.num_envs
    updates per env step."""

    learning_rate: float = 3e-4
    discounting: float = 0.99
    reward_scaling: float = 1.0
    tau: float = 0.005  # the target Q networks' step towards the Q networks after each update
    batch_size: int = 256
    grad_updates_per_step: int = 8
    # Checkpoints hold the buffer, (max_replay_size, 2 x observation + action + 3) float32, so that
    # a resumed run is the run never stopped; rundir's disk check counts it.
    max_replay_size: int = 2**17
    min_replay_size: int = 8192
    # Env steps at the run's start in which only the Q networks learn, the policy and the temperature
    # held: a warm-started policy is not pulled about by a fresh critic (docs/how-to/sac.md).
    actor_delay: int = 0
    # The temperature at the run's start (Brax: 1) and the entropy it steers the policy towards, in
    # nats (null: Brax's -0.5 per action dimension). A warm-started PPO policy has far less
    # entropy than Brax's target: docs/how-to/sac.md#the-temperature-of-a-warm-start-2026-11-29.
    init_alpha: float = 1.0
    target_entropy: float | None = None

    def validate(self) -> None:
        for key, most in (("batch_size", MAX_ENVS), ("grad_updates_per_step", 10**4), ("max_replay_size", 2**26)):
            if not 1 <= getattr(self, key) <= most:
                raise VnlError(f"{key} must be in 1..{most:,}, got {getattr(self, key):,}")
        if not 0 <= self.min_replay_size <= self.max_replay_size:
            raise VnlError(
                f"min_replay_size must be in 0..max_replay_size ({self.max_replay_size:,}), "
                f"got {self.min_replay_size:,}"
            )
        if not 0 <= self.actor_delay <= 2**62:
            raise VnlError(f"actor_delay must be in 0..2**62 env steps, got {self.actor_delay:,}")
        if self.target_entropy is not None and not math.isfinite(self.target_entropy):
            raise VnlError(f"target_entropy must be a finite number of nats or null, got {self.target_entropy}")
        for key in ("learning_rate", "reward_scaling", "init_alpha"):
            if not (getattr(self, key) > 0 and math.isfinite(getattr(self, key))):
                raise VnlError(f"{key} must be a finite number > 0, got {getattr(self, key)}")
        for key in ("discounting", "tau"):
            if not 0 < getattr(self, key) <= 1:
                raise VnlError(f"{key} must be in (0, 1], got {getattr(self, key)}")


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
    # the policy and in the value network, each its own (vnl.ppo.recurrent); null: feed-forward
    # MLPs (docs/how-to/recurrent.md).
    core: Literal["lstm", "gru"] | None = None
    core_size: int = 128
    # `brax`: the policy and the value network apart, as above. `merel`: Merel et al. 2020's
    # virtual-rodent network (vnl.ppo.merel; docs/how-to/merel-network.md): a proprioceptive MLP
    # (`encoder_hidden_layer_sizes`) and, with --vision, a ResNet per camera feed the `core`,
    # whose output the value reads; the policy's own stacked cores (`policy_core_sizes`) read the
    # core without training it. The `*_hidden_layer_sizes` and `cnn_*` keys are then unused.
    # `intention`: Aldarondo et al. 2024's intention network for imitation (vnl.ppo.intention;
    # docs/how-to/intention-network.md): an MLP (`encoder_hidden_layer_sizes`) encodes the
    # reference part of the observation into a Gaussian latent of `intention_size`, which the
    # decoder MLP (`policy_hidden_layer_sizes`) reads with the rest of the observation; PPO's loss
    # adds `kl_weight` × the latent's KL divergence from N(0, I) (nats, summed over its units).
    # With `core`, a core of `core_size` units follows the decoder MLP (vnl.ppo.intention_core).
    architecture: Literal["brax", "merel", "intention"] = "brax"
    encoder_hidden_layer_sizes: tuple[int, ...] = (256, 256)
    policy_core_sizes: tuple[int, ...] = (128,)
    resnet_channels: tuple[int, ...] = (16, 32, 32)
    resnet_blocks: int = 2
    resnet_features: int = 256
    intention_size: int = 60  # the latent's units (track-mjx's rat: 60)
    # Per nat of KL: the rat presets' price of a nat of action entropy (ppo.entropy_cost 1e-3);
    # track-mjx's 1e-4 on the mean over 60 units is 1.7e-6 per nat (docs/how-to/intention-network.md).
    kl_weight: float = 1e-3

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
        if self.architecture == "merel":
            self._validate_merel()
        if self.architecture == "intention":
            self._validate_intention()
        n = len(self.cnn_channels)
        if len(self.cnn_kernel_sizes) != n or len(self.cnn_strides) != n:
            raise VnlError(
                f"cnn_channels, cnn_kernel_sizes and cnn_strides need one value per convolution; got "
                f"{n}, {len(self.cnn_kernel_sizes)} and {len(self.cnn_strides)} values"
            )

    def _validate_merel(self) -> None:
        if self.core is None:
            raise VnlError(
                "network.architecture merel needs a recurrent core: set network.core to lstm (the paper's) or gru"
            )
        for key, most, what in (
            ("encoder_hidden_layer_sizes", MAX_LAYER, "units"),
            ("policy_core_sizes", MAX_LAYER, "units"),
            ("resnet_channels", 4096, "channels"),
        ):
            sizes = getattr(self, key)
            if not sizes or any(s < 1 for s in sizes) or any(s > most for s in sizes) or len(sizes) > 64:
                raise VnlError(f"{key} must be a list of 1 to 64 sizes, each 1..{most:,} {what}, got {list(sizes)[:8]}")
        if not 0 <= self.resnet_blocks <= 64:
            raise VnlError(f"resnet_blocks must be in 0..64 residual blocks per section, got {self.resnet_blocks}")
        if not 1 <= self.resnet_features <= MAX_LAYER:
            raise VnlError(f"resnet_features must be in 1..{MAX_LAYER:,} units, got {self.resnet_features}")

    def _validate_intention(self) -> None:
        sizes = self.encoder_hidden_layer_sizes
        if not sizes or any(s < 1 for s in sizes) or any(s > MAX_LAYER for s in sizes) or len(sizes) > 64:
            raise VnlError(
                f"encoder_hidden_layer_sizes must be a list of 1 to 64 sizes, each 1..{MAX_LAYER:,} units, got "
                f"{list(sizes)[:8]}"
            )
        if not 1 <= self.intention_size <= MAX_LAYER:
            raise VnlError(f"intention_size must be in 1..{MAX_LAYER:,} units, got {self.intention_size:,}")
        if not 0 <= self.kl_weight <= 1e3:
            raise VnlError(f"kl_weight must be in [0, 1000] (the KL term's weight in PPO's loss), got {self.kl_weight}")


class RunSettings(Protocol):
    """What the PPO loop and its networks read of a run's config (`vnl.train.config.TrainConfig`)."""

    @property
    def ppo(self) -> PPOConfig: ...

    @property
    def network(self) -> NetworkConfig: ...

    @property
    def algorithm(self) -> str: ...

    @property
    def sac(self) -> SACConfig: ...

    @property
    def randomize(self) -> Any: ...

    @property
    def vision(self) -> Any: ...

    @property
    def levels(self) -> Any: ...

    @property
    def seed(self) -> int: ...

    def episode_length(self) -> int: ...


INTENTION_NEEDS_FLAT = "network.architecture intention reads a flat observation; train it without --vision"


def intention_without_reference(env: str) -> str:
    """The error line for `network.architecture: intention` on an env whose observation has no
    reference part (checked from the registry by the run's config, and from the env itself when
    the network is built)."""
    return (
        f"network.architecture intention encodes a reference to imitate, but {env} observes none (no "
        "reference_blocks); use it with an imitation env such as rodent_imitate, or another architecture"
    )
