"""Name -> (env factory, default config, description, camera). `make` validates overrides before compiling.

An env name is one task: its default config holds every rule (what the animal observes, is paid
for and is stopped by) and its camera settings, the same under every training preset and in
`make`. Training presets (`vnl/train/presets/`) choose compute, budgets and curricula only; the
env config keys a preset may set are `COMPUTE_FIELDS`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

from vnl import typed_config as config_lib
from vnl.envs import suite
from vnl.errors import VnlError
from vnl.tasks import cue_memory, escape_bowl, find_target, imitate, maze_forage, run, run_gaps, two_touch
from vnl.tasks.contract import Env
from vnl.vision.env import VisionConfig, VisionEnv

COMPUTE_FIELDS = frozenset({"impl", "threads"})
"""Env config keys that choose how the physics is computed (MuJoCo C, MJX or Warp; threads), not
the task: the only `env_config` keys a training preset may set."""

VISION_COMPUTE_FIELDS = frozenset({"enabled", "chunk"})
"""Camera settings a preset may set: none of what the camera shows (`enabled` is `--vision`'s)."""


@dataclasses.dataclass(frozen=True)
class Entry:
    """A registered env: `factory(config) -> Env`, its frozen default config, one line saying what
    the task is, and `vision`, the env's camera settings for `--vision` / `make(name, vision=True)`
    (`VisionConfig` fields; empty: its defaults, the egocentric 64x64 RGB camera)."""

    factory: Callable[[Any], Env]
    default_config: Any
    description: str
    vision: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "vision", config_lib.freeze(dict(self.vision)))  # no shared mutable dict


_BRAX = "physics selectable: MJX or Brax's generalized/positional/spring"
_REGISTRY: dict[str, Entry] = {
    "ant_run": Entry(
        run.Run, run.ANT_RUN, "dm_control's ant runs forward on a flat floor (cheap: the CPU demo animal)."
    ),
    "humanoid_run": Entry(run.Run, run.HUMANOID_RUN, "The notebooks' MJX humanoid runs forward on a flat floor."),
    "brax_humanoid_run": Entry(run.Run, run.BRAX_HUMANOID_RUN, f"Brax's humanoid runs forward; {_BRAX}."),
    "brax_ant_run": Entry(run.Run, run.BRAX_ANT_RUN, f"Brax's ant runs forward; {_BRAX}."),
    "rodent_run": Entry(run.Run, run.RODENT_RUN, "dm_control's rat runs forward on a flat floor."),
    "rodent_run_gaps": Entry(
        run_gaps.RunGaps,
        run_gaps.RODENT_RUN_GAPS,
        "The rat runs at 1 m/s through a corridor of random platforms and gaps (training replays each"
        " env's first corridor unless env_config.new_episode_on_reset).",
    ),
    "rodent_run_gaps_vision": Entry(
        run_gaps.RunGaps,
        run_gaps.RODENT_RUN_GAPS_VISION,
        "rodent_run_gaps seen through the rat's egocentric camera (16x16 depth) instead of a ground scan.",
        # Its egocentric camera, a small depth image, as the ant's: docs/experiments/vision-gaps.md
        vision={"camera": "walker/egocentric", "mode": "depth", "width": 16, "height": 16, "depth_max": 4.0},
    ),
    "rodent_escape_bowl": Entry(
        escape_bowl.EscapeBowl,
        escape_bowl.RODENT_ESCAPE_BOWL,
        "The rat climbs out of a bumpy heightfield bowl (reward: upright x distance).",
    ),
    "rodent_two_touch": Entry(
        two_touch.TwoTouch,
        two_touch.RODENT_TWO_TOUCH,
        "The rat touches an orb, waits, and touches it again 0.7-0.9 s after (dm_control's two-touch task).",
    ),
    "rodent_maze_forage": Entry(
        maze_forage.MazeForage,
        maze_forage.RODENT_MAZE_FORAGE,
        "The rat collects the targets in a maze with rooms redrawn every episode (dm_control's maze forage).",
    ),
    "rodent_maze_forage_upright": Entry(
        maze_forage.MazeForage,
        maze_forage.RODENT_MAZE_FORAGE_UPRIGHT,
        "rodent_maze_forage, but a fall (torso past 90 degrees) ends the episode and staying up pays 0.05 a step.",
    ),
    "rodent_imitate": Entry(
        imitate.Imitate,
        imitate.RODENT_IMITATE,
        "The rat tracks reference clips of a rat's motion, pose by pose (after dm_control's CoMic tracking).",
    ),
    "ant_run_gaps": Entry(
        run_gaps.RunGaps,
        run_gaps.ANT_RUN_GAPS,
        "The ant runs through a corridor of platforms and gaps scaled to its size.",
        # A 16x16 depth image of the floor ahead: the default 64x64 RGB did not finish 5 training
        # steps in 30 minutes on a CPU: docs/experiments/vision-gaps.md
        vision={"camera": "walker/ground", "mode": "depth", "width": 16, "height": 16, "depth_max": 4.0},
    ),
    "ant_escape_bowl": Entry(
        escape_bowl.EscapeBowl, escape_bowl.ANT_ESCAPE_BOWL, "The ant climbs out of the bumpy bowl."
    ),
    "find_target": Entry(
        find_target.FindTarget,
        find_target.FIND_TARGET,
        "A ball rolls to a red target placed at random; only its egocentric camera can see it (train with --vision).",
        vision={"width": 32, "height": 32},  # 32x32 trains from pixels on a CPU: docs/experiments/vision-gaps.md
    ),
    "cue_memory": Entry(
        cue_memory.CueMemory,
        cue_memory.CUE_MEMORY,
        "A ball is told which of two targets pays, waits out a delay without the cue, then rolls to it (needs memory).",
    ),
    # Tasks for any walker: set walker=ant|rodent or walker_xml=path/to/model.xml, root_body=...
    "run": Entry(run.Run, run.RODENT_RUN, "Run task for any walker (walker=..., or walker_xml=FILE root_body=NAME)."),
    "run_gaps": Entry(
        run_gaps.RunGaps, run_gaps.RODENT_RUN_GAPS, "Gaps corridor task for any walker (walker_xml=...)."
    ),
    "escape_bowl": Entry(
        escape_bowl.EscapeBowl, escape_bowl.RODENT_ESCAPE_BOWL, "Bowl escape task for any walker (walker_xml=...)."
    ),
}

SUITES = {
    # The ant's two tasks it learns alone (docs/results), split 3:1 as their presets' budgets are
    # (12M and 4M steps): one policy against two specialists: docs/how-to/multitask.md
    "ant_suite": (
        ("ant_run_gaps", "ant_escape_bowl"),
        (3, 1),
        "The ant's gaps run and bowl escape, one policy for both.",
    ),
    "rodent_suite": (
        suite.RODENT_SUITE,
        None,
        "Merel et al. 2020's four rat tasks (gaps, maze forage, bowl, two-touch) for one policy.",
    ),
}
"""Suites (`vnl.envs.suite`): (member envs, their shares of the batch, description)."""

for _name, (_members, _shares, _what) in SUITES.items():
    _factory, _default = suite.define(
        {m: (_REGISTRY[m].factory, _REGISTRY[m].default_config) for m in _members}, _shares
    )
    _REGISTRY[_name] = Entry(_factory, _default, _what)

ALIASES = {"run": "rodent_run", "run_gaps": "rodent_run_gaps", "escape_bowl": "rodent_escape_bowl"}
"""Generic task names whose defaults equal a walker-specific env's (tests build each once)."""


def register(
    name: str,
    factory: Callable[[Any], Env],
    default_config: Any,
    description: str = "",
    vision: Mapping[str, Any] | None = None,
) -> None:
    """Adds an environment: `factory(config) -> Env`, its frozen default config dataclass and,
    optionally, its camera settings (`vision`: `VisionConfig` fields such as width, height, mode).

    The config's fields become overridable keys (`vnl.make(name, key=value)`, `env_config.key`);
    it needs an `episode_length` field for training. Training presets for it (e.g. a smaller
    `cpu` budget for a slow env) go to `vnl.train.presets.register`.
    """
    if not hasattr(default_config, "episode_length"):
        raise VnlError(f"{name}: the default config needs an episode_length field")
    try:
        config_lib.from_dict(VisionConfig, dict(vision or {}), prefix="vision.")  # unknown keys, bad values
    except VnlError as e:
        raise VnlError(f"{name}: {e}") from None
    _REGISTRY[name] = Entry(factory, default_config, description, vision or {})


def unregister(name: str) -> None:
    """Removes an environment added with `register`."""
    _REGISTRY.pop(name, None)


def is_suite(name: str) -> bool:
    """Whether env `name` is a suite of tasks (`vnl.envs.suite`)."""
    return isinstance(entry(name).default_config, suite.SuiteConfig)


def names() -> list[str]:
    """Registered environment names, sorted."""
    return sorted(_REGISTRY)


def entry(name: str) -> Entry:
    """The registry entry for `name`; an unknown name lists the valid ones."""
    if not isinstance(name, str):
        raise VnlError(f"an environment's name is a string, got {name!r}; valid names are: {', '.join(names())}")
    try:
        return _REGISTRY[name]
    except KeyError:
        raise VnlError(f"unknown environment {name!r}; valid names are: {', '.join(names())}") from None


def default_config(name: str) -> Any:
    """The frozen default config of environment `name`."""
    return entry(name).default_config


def vision_defaults(name: str) -> dict[str, Any]:
    """Env `name`'s camera settings (`VisionConfig` fields it changes), as a new plain dict."""
    return dict(entry(name).vision)


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

    `vision=True` (the env's own camera settings), a dict of settings that change some of them
    (camera, width, height, mode, ...) or a whole `vnl.vision.VisionConfig` returns the env with a
    dict observation `{"state", "pixels/<camera>"}` rendered by the in-graph camera
    (`vnl.vision.VisionEnv`).

    Bad names, unknown keys and invalid values raise `VnlError` before anything is compiled.
    """
    e = entry(name)
    if isinstance(vision, dict):
        vision = config_lib.from_dict(VisionConfig, {**e.vision, "enabled": True, **vision}, prefix="vision.")
    elif vision is True:
        vision = config_lib.from_dict(VisionConfig, {**e.vision, "enabled": True}, prefix="vision.")
    elif vision is not False and not isinstance(vision, VisionConfig):
        raise VnlError(f"vision must be True/False, a dict of camera settings or a VisionConfig, got {vision!r}")
    env = e.factory(env_config(name, overrides))
    if isinstance(vision, VisionConfig) and vision.enabled:
        env = VisionEnv(env, vision)
    return env
