"""Name -> (env class, default config, description). `make` validates overrides before compiling."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from vnl import config as config_lib
from vnl.envs.base import Env
from vnl.errors import VnlError
from vnl.tasks import run


@dataclasses.dataclass(frozen=True)
class Entry:
    factory: Callable[[Any], Env]
    default_config: Any
    description: str


_REGISTRY: dict[str, Entry] = {
    "ant_run": Entry(
        run.Run,
        run.ANT_RUN,
        "dm_control's ant runs forward on a flat floor (cheap: the CPU demo animal).",
    ),
    "humanoid_run": Entry(
        run.Run,
        run.HUMANOID_RUN,
        "The notebooks' MJX humanoid runs forward on a flat floor.",
    ),
}


def register(name: str, factory: Callable[[Any], Env], default_config: Any, description: str = "") -> None:
    """Adds an environment: `factory(config) -> Env` and its frozen default config dataclass.

    The config's fields become overridable keys (`vnl.make(name, key=value)`, `env_config.key`);
    it needs an `episode_length` field for training.
    """
    if not hasattr(default_config, "episode_length"):
        raise VnlError(f"{name}: the default config needs an episode_length field")
    _REGISTRY[name] = Entry(factory, default_config, description)


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


def make(name: str, **overrides: Any) -> Env:
    """Builds environment `name`; keyword overrides replace fields of its default config.

    Bad names, unknown keys and invalid values raise `VnlError` before anything is compiled.
    """
    e = entry(name)
    return e.factory(env_config(name, overrides))
