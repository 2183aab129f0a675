"""Name -> (env class, default config, description). `make` validates overrides before compiling."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from vnl import config as config_lib
from vnl.env import Env
from vnl.errors import VnlError
from vnl.tasks import escape_bowl, find_target, run, run_gaps
from vnl.vision.env import VisionConfig, VisionEnv


@dataclasses.dataclass(frozen=True)
class Entry:
    factory: Callable[[Any], Env]
    default_config: Any
    description: str
    # Per-preset training overrides merged over `vnl.train.config.PRESETS[preset]`.
    presets: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        # Several entries are built from one presets dict: each holds its own frozen copy.
        object.__setattr__(self, "presets", config_lib.freeze(self.presets))


def _c_on_cpu(cpu: dict[str, Any] | None = None, **others: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Presets whose `cpu` preset runs MuJoCo C physics (`env_config.impl: c`, see README: Physics
    on a CPU) with the settings in `cpu`; `others` (e.g. `gpu`) as given."""
    return {"cpu": config_lib.merge({"env_config": {"impl": "c"}}, cpu or {}), **others}


# The rat steps ~10x slower than the ant (43 joints, 10 physics steps of 2 ms per control step).
# On a CPU it runs on MuJoCo C (impl c: 10x MJX's speed there, README); on a GPU on MJX.
# cpu (the rat's three envs; each adds its own below): the ant's batch (256 envs x 8 minibatches x
# unroll 10, 4 epochs), a 2x256 policy MLP, entropy 1e-3, gradient clipping and a PPO clip of 0.2,
# 5M steps: 21-25 minutes at 3,600-4,200 env steps/s on the last machine measured (about 40 at the
# ~2,100 of earlier ones; rodent_run_gaps: 8M steps, about 38 minutes).
# Without the clipping this policy had KL jumps of up to 38,254 between successive policies and
# collapsed; Brax's 4x32 policy with entropy 1e-2 stayed upright 80% of the time.
# rodent_run: what made the rat run was a compass. dm_control's proprioception senses tilt but
# not yaw, and the run pays world-x velocity: before `observe_heading` (run.RODENT_RUN) every gait
# found was lost again within 0.5-1M steps (0.69 m/s at one evaluation of two seeds, standing at
# the next; none of a 45-degree tilt check, learning-rate decay, a KL-adaptive rate or a normal
# policy held it), and the best runner's episodes curved 10-160 degrees off +x. With the heading the
# preset's seed 0 ran at 1.57 m/s upright through whole episodes at 4.6M steps but fell at 5.1M;
# with the learning rate also decaying linearly to 0 over the run (`_RODENT_RUN_PRESETS`) seeds 0
# and 1 end the 5M steps running at 1.79 and 1.76 m/s, upright 97-99% (README, Does every task learn?).
# rodent_escape_bowl: 15-18x the untrained reward in 3.5M (discount 0.99, below), no escape: the
# bumps' slopes pass what the rat's gait climbs (it falls at 15°); rodent_run_gaps: this shared
# preset with dm_control's task was no better than untrained in 4M steps (it wriggled on its side);
# its own preset (`_RODENT_GAPS_PRESETS`, below) runs into the first or second gap.
_RODENT_PRESETS = _c_on_cpu(
    {
        "ppo": {
            "num_timesteps": 5_000_000,
            "num_envs": 256,
            "batch_size": 256,
            "num_minibatches": 8,
            "num_updates_per_batch": 4,
            "unroll_length": 10,
            "entropy_cost": 1e-3,
            "reward_scaling": 1.0,
            "max_grad_norm": 1.0,
            "clipping_epsilon": 0.2,
            "num_evals": 11,
            "num_eval_envs": 32,
        },
        "network": {"policy_hidden_layer_sizes": [256, 256]},
        "log": {"video_seconds": 4.0},
    },
    gpu={"ppo": {"num_envs": 2048}},  # the seed notebooks' rodent setting (README: CLI, presets)
)
# rodent_run's cpu preset also decays the learning rate linearly to 0 over the run: the rat's policy
# otherwise keeps taking large steps late (KL up to 98 between successive policies) and a runner
# at 1.57 m/s fell within 2 s one evaluation later (README, Does every task learn?).
_RODENT_RUN_PRESETS = config_lib.merge(_RODENT_PRESETS, {"cpu": {"ppo": {"learning_rate_final": 0.0}}})
# rodent_escape_bowl (both presets) discounts by 0.99, not 0.97: the bowl pays for where the rat
# is, not how fast it goes, and the rat's 20-ms control step makes 0.97 a ~0.7-s horizon (the
# ant's 50-ms step: ~1.7 s), too short to see the way out pay. Measured (README, Does every task
# learn?): from scratch, reward 191.6 in 3.5M steps against 109.5 with 0.97 (seed 0); warm-started
# from the runner on a gentle bowl (0.1 m high), 0.97 took it from escaping 88% of episodes to
# none within 0.5M steps, 0.99 to all of them by 0.9M.
_BOWL_DISCOUNT = {"ppo": {"discounting": 0.99}}
_RODENT_BOWL_PRESETS = config_lib.merge(_RODENT_PRESETS, {"cpu": _BOWL_DISCOUNT, "gpu": _BOWL_DISCOUNT})

# rodent_run_gaps: the rat learns to run in the corridor without gaps first, as rodent_run
# (a compass, `observe_heading`; the episode ending beyond 45 degrees of tilt; a healthy bonus of
# 0.2 per step, the floor task's 5:1 of speed to bonus; the rate decaying to 0), then meets short
# gaps and the run's own, with the bonus off: dm_control's velocity term pays nothing at rest, so
# without the bonus standing earns nothing and an episode ended in a gap costs the speed it would
# have earned after. With the bonus on the gaps (0.2 x 1,500 steps = 300 for standing still, a
# runner that falls into the second gap earns ~80) the rat learned to stand before them (README,
# Does every task learn?). A 12-point ground scan (0.1 m behind to 0.45 m ahead) tells it where
# the gaps are; `observe_corridor` where the corridor's sides are: with the heading alone, the rat
# running on the gapless corridor drifted sideways and fell off the edge 1 m out after 2.8-5.4 m
# (6 of 8 rollouts at 3.1M steps). (Both add the world x-axis in the torso frame; the heading is
# kept so that a rodent_run checkpoint's observation stays a prefix of this one, for warm starts.)
# The stages' steps sum to the run's length: 8M on a CPU (about 38 minutes here: 0.25 and 1.06
# gaps per episode, seeds 0 and 1; README); on a GPU 4x as many (32M, the order of the gpu
# preset's 30M), not measured.
_RODENT_GAPS_SCAN = tuple(round(-0.1 + 0.05 * i, 2) for i in range(12))


def _rodent_gaps_preset(scale: int) -> dict[str, Any]:
    """The corridor's settings with stages of 3M, 2M and 3M steps times `scale`."""
    return {
        "env_config": {
            "observe_heading": True,
            "observe_corridor": True,
            "healthy_min_upright": 0.7071,
            "healthy_reward": 0.0,
            "ground_scan": list(_RODENT_GAPS_SCAN),
        },
        "ppo": {"num_evals": 17, "learning_rate_final": 0.0},
        "curriculum": [
            {
                "name": "no_gaps",
                "steps": 3_000_000 * scale,
                "env_config": {"healthy_reward": 0.2, "corridor": {"gap_length": [0.0, 0.0]}},
            },
            {"name": "short_gaps", "steps": 2_000_000 * scale, "env_config": {"corridor": {"gap_length": [0.03, 0.1]}}},
            {"name": "gaps", "steps": 3_000_000 * scale},
        ],
    }


_RODENT_GAPS_PRESETS = config_lib.merge(_RODENT_PRESETS, {"cpu": _rodent_gaps_preset(1), "gpu": _rodent_gaps_preset(4)})

# The ant and the humanoid on a CPU: MuJoCo C physics (ant_run trains 1.7x faster than on MJX
# there; env steps 2.1x (humanoid) to 13x (ant in the bowl) MJX's: README, Physics on a CPU); the
# other settings are the defaults (the main job).
_C_ON_CPU = _c_on_cpu()

# humanoid_run on a CPU: Brax's humanoid PPO settings (reward scaling 0.1, entropy 1e-3) at the
# ant's batch, 20M steps (about 28 minutes at ~12,000 env steps/s; ~45 at the ~7,500 of earlier
# machines), with the task's rewards
# reshaped so that staying up is what pays: a healthy bonus of 2 (not 5), healthy only within 45°
# of upright (as the upright measure), and the forward reward capped at 1 m/s. Measured (README,
# Does every task learn?): with Brax's rewards (bonus 5, any speed paid) seed 0 stood still (the
# bonus outweighs walking) and seed 1 walked at 1.43 m/s but fell in a third of its episodes; with
# the bonus 2 and no cap seed 0 ran at 3.3 m/s and fell after 695 of 1,000 steps; with the cap (this
# preset without gradient clipping) seeds 0 and 2 walked at ~1.1 m/s, upright through whole
# evaluation episodes from 6-7M steps on, but seed 1 had not learned to balance by 10M (0.87 m/s,
# falling after 170 steps; rerun on 2026-11-26: the same reward, speed and episode length). Clipping the
# gradient's norm at 1 (as the rat's preset does), nothing else changed, made all three seeds walk
# upright at 10M (1.13-1.18 m/s, 986-1,000 of 1,000 steps); why is not known: the logged KL between
# successive policies was alike in the clipped and unclipped seed-1 runs (0.02-0.06 from 2M steps
# on). A discount of 0.99 instead (Playground's dm_control suite uses 0.995) made seed 1 stand
# still for whole episodes (our reading: at that horizon staying up outweighs the risk of a step).
# 20M steps, not 10M: at 10M 1, 3 and 4 of 64 new evaluation episodes (seeds 0, 1, 2) ended in a
# fall; continued to 20M (the same constant rate and evaluation interval) 0, 1 and 0 did. The
# rate stays fluctuating (seed 1's checkpoint at 18M: 4 of 64); a rate decaying to 0 over 10M
# instead: 2 of 64 (seed 2).
# The gpu preset keeps the generic one's scale (4,096 envs, 30M steps; Brax's reward scaling and
# entropy already) and takes the same reshaped rewards and clipping: with Brax's rewards the
# cpu runs stood still or fell, whatever the batch (README, Does every task learn?).
_HUMANOID_SHARED = {
    "env_config": {"healthy_reward": 2.0, "healthy_min_upright": 0.7, "forward_velocity_cap": 1.0},
    "ppo": {"max_grad_norm": 1.0},
}
_HUMANOID_PRESETS = _c_on_cpu(
    config_lib.merge(
        _HUMANOID_SHARED,
        {
            "ppo": {
                "num_timesteps": 20_000_000,
                "reward_scaling": 0.1,
                "entropy_cost": 1e-3,
                "num_evals": 21,
                "num_eval_envs": 32,
            },
        },
    ),
    gpu=_HUMANOID_SHARED,
)

# ant_run_gaps on a CPU: the ant first learns to run in the same corridor without gaps, then with
# short gaps, then on the run's own gaps (the last stage has no overrides, so `--set
# env_config.corridor...` still sets the task it ends on). The blind ant with the task's own rules
# (velocity reward only, no end but a fall) reached 1.6-2.0 gaps (2 seeds, 15 min) and stayed there
# whatever was tried: a 21-point ground scan (1.3), seeing the floor (--vision, 1.7-2.4), ending the
# episode when the torso wedges in a gap (1.6), a 2x256 policy (1.9-2.3), 15M steps (1.8). Its
# frames showed why: a lower leg stepped into a gap hangs there, and the ant's legs (a hip yaw and
# one pitch joint each) cannot lift it out over the edge; it stayed trapped for the episode. What
# moved it: ending the episode when a foot dips 10 cm into a gap (terminate_foot_below) with a
# healthy bonus of 0.25 per step, so that a foot in a gap costs the rest of the episode's bonus; a
# 25-point ground scan (0.8 m behind to 1.6 m ahead, every 0.1 m: where the gaps are); the torso
# check (wedged below 0.2 m, or upside down); a 2x256 policy; 12M steps (README, Results).
_ANT_GAPS_SCAN = tuple(round(-0.8 + 0.1 * i, 1) for i in range(25))
_ANT_GAPS_PRESETS = _c_on_cpu(
    {
        "env_config": {
            "terminate_foot_below": -0.1,
            "healthy_reward": 0.25,
            "terminate_root_below": 0.2,
            "healthy_min_upright": 0.0,
            "ground_scan": list(_ANT_GAPS_SCAN),
        },
        "ppo": {"num_evals": 25},  # 12M steps: the stages' sum
        "curriculum": [
            {"name": "no_gaps", "steps": 1_500_000, "env_config": {"corridor": {"gap_length": [0.0, 0.0]}}},
            {"name": "short_gaps", "steps": 1_500_000, "env_config": {"corridor": {"gap_length": [0.125, 0.25]}}},
            {"name": "gaps", "steps": 9_000_000},
        ],
        # With --vision: a 16x16 depth image of the floor ahead from the ant's `ground` camera and
        # find_target's small CNN, ~4,500 training steps/s here (the default 64x64 RGB NatureCNN
        # did not finish 5 training steps in 30 minutes; README, Vision).
        "vision": {"camera": "walker/ground", "mode": "depth", "width": 16, "height": 16, "depth_max": 4.0},
        "network": {
            "policy_hidden_layer_sizes": [256, 256],
            "cnn_channels": [8, 16],
            "cnn_kernel_sizes": [4, 3],
            "cnn_strides": [2, 2],
            "cnn_pool": "spatial_softmax",
        },
    }
)

# ant_escape_bowl on a CPU: the defaults (the main job's PPO settings) for 4M steps, about 10
# minutes here (README, Results).
_ANT_BOWL_PRESETS = _c_on_cpu({"ppo": {"num_timesteps": 4_000_000, "num_evals": 9}})

# find_target trains from pixels on a CPU: 32x32 images, a small CNN whose spatial softmax keeps
# where the target is (README, Vision). Blind (no --vision), the same preset is the baseline.
_FIND_TARGET_PRESETS = {
    "cpu": {
        "ppo": {
            "num_timesteps": 300_000,
            "num_envs": 128,
            "batch_size": 128,
            "num_minibatches": 4,
            "num_updates_per_batch": 4,
            "unroll_length": 10,
            "num_evals": 11,
            "num_eval_envs": 64,
            "entropy_cost": 1e-3,
        },
        "network": {
            "policy_hidden_layer_sizes": [64, 64],
            "value_hidden_layer_sizes": [64, 64],
            "cnn_channels": [8, 16],
            "cnn_kernel_sizes": [4, 3],
            "cnn_strides": [2, 2],
            "cnn_pool": "spatial_softmax",
        },
        "vision": {"width": 32, "height": 32},
        "log": {"video_seconds": 4.0},
    },
}

_REGISTRY: dict[str, Entry] = {
    "ant_run": Entry(
        run.Run,
        run.ANT_RUN,
        "dm_control's ant runs forward on a flat floor (cheap: the CPU demo animal).",
        _C_ON_CPU,
    ),
    "humanoid_run": Entry(
        run.Run,
        run.HUMANOID_RUN,
        "The notebooks' MJX humanoid runs forward on a flat floor.",
        _HUMANOID_PRESETS,
    ),
    "brax_humanoid_run": Entry(
        run.Run,
        run.BRAX_HUMANOID_RUN,
        "Brax's humanoid runs forward; physics selectable: MJX or Brax's generalized/positional/spring.",
    ),
    "brax_ant_run": Entry(
        run.Run,
        run.BRAX_ANT_RUN,
        "Brax's ant runs forward; physics selectable: MJX or Brax's generalized/positional/spring.",
    ),
    "rodent_run": Entry(
        run.Run,
        run.RODENT_RUN,
        "dm_control's rat runs forward on a flat floor.",
        _RODENT_RUN_PRESETS,
    ),
    "rodent_run_gaps": Entry(
        run_gaps.RunGaps,
        run_gaps.RODENT_RUN_GAPS,
        "The rat runs at 1 m/s through a corridor of platforms and gaps redrawn every episode.",
        _RODENT_GAPS_PRESETS,
    ),
    "rodent_escape_bowl": Entry(
        escape_bowl.EscapeBowl,
        escape_bowl.RODENT_ESCAPE_BOWL,
        "The rat climbs out of a bumpy heightfield bowl (reward: upright x distance).",
        _RODENT_BOWL_PRESETS,
    ),
    "ant_run_gaps": Entry(
        run_gaps.RunGaps,
        run_gaps.ANT_RUN_GAPS,
        "The ant runs through a corridor of platforms and gaps scaled to its size.",
        _ANT_GAPS_PRESETS,
    ),
    "ant_escape_bowl": Entry(
        escape_bowl.EscapeBowl,
        escape_bowl.ANT_ESCAPE_BOWL,
        "The ant climbs out of the bumpy bowl.",
        _ANT_BOWL_PRESETS,
    ),
    "find_target": Entry(
        find_target.FindTarget,
        find_target.FIND_TARGET,
        "A ball rolls to a red target placed at random; only its egocentric camera can see it (train with --vision).",
        _FIND_TARGET_PRESETS,
    ),
    # Tasks for any walker: set walker=ant|rodent or walker_xml=path/to/model.xml, root_body=...
    "run": Entry(
        run.Run,
        run.RODENT_RUN,
        "Run task for any walker (walker=..., or walker_xml=FILE root_body=NAME).",
        _RODENT_RUN_PRESETS,
    ),
    "run_gaps": Entry(
        run_gaps.RunGaps,
        run_gaps.RODENT_RUN_GAPS,
        "Gaps corridor task for any walker (walker_xml=...).",
        _RODENT_GAPS_PRESETS,
    ),
    "escape_bowl": Entry(
        escape_bowl.EscapeBowl,
        escape_bowl.RODENT_ESCAPE_BOWL,
        "Bowl escape task for any walker (walker_xml=...).",
        _RODENT_BOWL_PRESETS,
    ),
}

ALIASES = {"run": "rodent_run", "run_gaps": "rodent_run_gaps", "escape_bowl": "rodent_escape_bowl"}
"""Generic task names whose defaults equal a walker-specific env's (tests build each once)."""


def register(
    name: str,
    factory: Callable[[Any], Env],
    default_config: Any,
    description: str = "",
    presets: dict[str, dict[str, Any]] | None = None,
) -> None:
    """Adds an environment: `factory(config) -> Env` and its frozen default config dataclass.

    The config's fields become overridable keys (`vnl.make(name, key=value)`, `env_config.key`);
    it needs an `episode_length` field for training. `presets` maps a preset name to training
    overrides for this env (e.g. a smaller `cpu` budget for a slow env).
    """
    if not hasattr(default_config, "episode_length"):
        raise VnlError(f"{name}: the default config needs an episode_length field")
    _REGISTRY[name] = Entry(factory, default_config, description, presets or {})


def unregister(name: str) -> None:
    """Removes an environment added with `register`."""
    _REGISTRY.pop(name, None)


def names() -> list[str]:
    """Registered environment names, sorted."""
    return sorted(_REGISTRY)


def entry(name: str) -> Entry:
    """The registry entry for `name`; an unknown name lists the valid ones."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise VnlError(f"unknown environment {name!r}; valid names are: {', '.join(names())}") from None


def default_config(name: str) -> Any:
    """The frozen default config of environment `name`."""
    return entry(name).default_config


def env_config(name: str, overrides: dict[str, Any] | None = None) -> Any:
    """Default config of `name` with `overrides` applied and validated (no compile)."""
    base = default_config(name)
    if not overrides:
        return base
    try:
        return config_lib.override(base, overrides)
    except VnlError as e:
        raise VnlError(f"{name}: {e}") from None


def make(name: str, vision: bool | dict[str, Any] | Any = False, **overrides: Any) -> Env:
    """Builds environment `name`; keyword overrides replace fields of its default config.

    `vision=True` (or a dict / `vnl.vision.VisionConfig` of camera settings: camera, width,
    height, mode, ...) returns the env with a dict observation {"state", "pixels/<camera>"}
    rendered by the in-graph camera (`vnl.vision.VisionEnv`).

    Bad names, unknown keys and invalid values raise `VnlError` before anything is compiled.
    """
    e = entry(name)
    if isinstance(vision, dict):
        vision = config_lib.from_dict(VisionConfig, {"enabled": True, **vision}, prefix="vision.")
    elif vision is True:
        vision = VisionConfig(enabled=True)
    elif vision is not False and not isinstance(vision, VisionConfig):
        raise VnlError(f"vision must be True/False, a dict of camera settings or a VisionConfig, got {vision!r}")
    env = e.factory(env_config(name, overrides))
    if isinstance(vision, VisionConfig) and vision.enabled:
        env = VisionEnv(env, vision)
    return env
