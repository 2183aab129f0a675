"""Training presets: named starting points for a run's config, one YAML file per env.

A preset chooses compute (the physics implementation and threads, batch sizes, PPO settings,
budgets, the network) and curricula, never the task: the env name is the task under every preset
(`vnl.envs.registry`). Outside a curriculum's stages a preset's `env_config` may set only
`registry.COMPUTE_FIELDS` and its `vision` only `registry.VISION_COMPUTE_FIELDS`; anything else is
refused when the file is read (or `register` is called).

`base.yaml` holds the generic presets (`cpu`, `gpu`, `tiny`); `<env>.yaml` holds what an env
changes of them, each setting with a one-line reason and the docs page with the evidence. A file
may start from another (`extends: _rodent`, deep-merged below its own values); files whose names
start with `_` are shared parts, not envs. Generic task names (`run`, `run_gaps`, `escape_bowl`)
take the presets of the env they alias (`vnl.envs.registry.ALIASES`).

A preset is a partial config (a nested dict of `TrainConfig` keys): `vnl.train.config.build`
merges it below the user's YAML file, `--set` and flags. Envs registered at run time add their
presets with `register`.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import yaml

from vnl import safe_yaml, typed_config
from vnl.envs import registry
from vnl.errors import VnlError

DIRECTORY = Path(__file__).parent
NAMES = ("cpu", "gpu", "tiny")
"""The presets every env has (an env's file changes some of them)."""

_registered: dict[str, dict[str, Any]] = {}


def names() -> tuple[str, ...]:
    """The preset names: cpu, gpu, tiny."""
    return NAMES


def check_name(preset: Any) -> str:
    """`preset` if it names a preset; `VnlError` listing the valid ones otherwise."""
    if not isinstance(preset, str) or preset not in NAMES:
        raise VnlError(f"unknown preset {preset!r}; valid presets are: {', '.join(NAMES)}")
    return preset


@functools.cache
def _file(stem: str) -> dict[str, Any]:
    """The presets of `<stem>.yaml` with its `extends` chain merged in (frozen), {} if no file."""
    path = DIRECTORY / f"{stem}.yaml"
    if not path.is_file():
        return {}
    values = yaml.load(path.read_text(), Loader=safe_yaml.Loader) or {}  # noqa: S506 - a SafeLoader
    unknown = sorted(set(values) - {"extends", *NAMES})
    if unknown:  # a packaging or editing mistake, not a user's: a test loads every file
        raise ValueError(f"{path.name}: unknown top-level keys {unknown}; expected extends and {', '.join(NAMES)}")
    for name in NAMES:
        check_compute_only(values.get(name) or {}, f"{path.name}: {name}")
    base = _file(values.pop("extends")) if "extends" in values else {}
    merged = {name: typed_config.merge(base.get(name) or {}, values.get(name) or {}) for name in NAMES}
    return typed_config.freeze({k: v for k, v in merged.items() if v})


def check_compute_only(preset: Any, where: str) -> None:
    """Raises `VnlError` when preset `preset` (a partial config) sets a task rule: an `env_config`
    key outside `registry.COMPUTE_FIELDS` or a `vision` key outside `VISION_COMPUTE_FIELDS`."""
    if not isinstance(preset, dict):
        raise VnlError(f"{where}: a preset is a mapping of config sections, got {preset!r}")
    for section, allowed in (("env_config", registry.COMPUTE_FIELDS), ("vision", registry.VISION_COMPUTE_FIELDS)):
        values = preset.get(section) or {}
        rules = sorted(set(values) - allowed) if isinstance(values, dict) else [str(values)]
        if rules:
            raise VnlError(
                f"{where}: {section}.{rules[0]} is a rule of the task, which a preset may not change (a preset "
                f"sets only {', '.join(sorted(allowed))} of {section}); change the env's default config, register "
                "a new env name for the variant, or put it in a curriculum stage"
            )


def generic(preset: str) -> dict[str, Any]:
    """The generic preset `preset` (base.yaml), as a frozen nested dict."""
    return _file("base").get(check_name(preset), typed_config.freeze({}))


def for_env(env: str, preset: str) -> dict[str, Any]:
    """What env `env` changes of the generic preset `preset`: {} when nothing (or an unknown env)."""
    check_name(preset)
    if env in _registered:
        return _registered[env].get(preset, typed_config.freeze({}))
    stem = registry.ALIASES.get(env, env)
    if stem.startswith("_") or stem == "base":
        return typed_config.freeze({})
    return _file(stem).get(preset, typed_config.freeze({}))


def resolve(env: str, preset: str) -> dict[str, Any]:
    """Preset `preset` for env `env`: the generic one with the env's changes merged over it."""
    return typed_config.merge(generic(preset), for_env(env, preset))


def path(env: str) -> Path | None:
    """The YAML file holding `env`'s presets, or None (none of its own, or registered at run time)."""
    if env in _registered:
        return None
    file = DIRECTORY / f"{registry.ALIASES.get(env, env)}.yaml"
    return file if file.is_file() and not file.name.startswith("_") else None


def register(env: str, presets: dict[str, dict[str, Any]]) -> None:
    """Adds training presets for an env registered at run time (`vnl.envs.registry.register`):
    `presets` maps a preset name (cpu, gpu, tiny) to config overrides, e.g.
    `{"cpu": {"ppo": {"num_timesteps": 2_000_000}}}`."""
    for name, values in presets.items():
        check_name(name)
        check_compute_only(values, f"presets of {env}: {name}")
    _registered[env] = typed_config.freeze(presets)


def unregister(env: str) -> None:
    """Removes the presets added with `register`."""
    _registered.pop(env, None)
