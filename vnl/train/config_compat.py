"""How runs written by older vnl stay readable and keep their config hash: the env fields a saved
config lacks, and the keys added since that a hash leaves out while they are at their default
(docs/how-to/resume.md)."""

from __future__ import annotations

import dataclasses
from typing import Any

from vnl import typed_config as config_lib
from vnl.envs import registry

_PLAIN = (bool, int, float, str, type(None), tuple)

ADDED_ENV_FIELDS = ("spawn_distance", "new_episode_on_reset")
"""Env config fields added after runs were hashed: left out of a hash at their class default."""

ADDED_KEYS = {
    "sac": {"actor_delay": 0, "init_alpha": 1.0, "target_entropy": None},
    "ppo": {"normalize_advantage": "batch"},
}
"""{section: {key: default}} added after runs were hashed: left out of a hash at that default."""


def env_field_defaults(env: str) -> dict[str, Any]:
    """{field: its class default} of `env`'s config class (by convention off: the behaviour
    before the field existed), not the env's own default config."""
    return {f.name: f.default for f in dataclasses.fields(type(registry.default_config(env)))}


def without_added_at_default(values: dict[str, Any]) -> dict[str, Any]:
    """A config's values (`to_dict` of a `TrainConfig`, `log` and all) without the keys added
    since runs were hashed (`ADDED_ENV_FIELDS`, `ADDED_KEYS`) that are at their default, so that
    a run saved before a key existed hashes as it did then."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in values.items()}
    fields = env_field_defaults(values["env"])
    for key in ADDED_ENV_FIELDS:
        if key in fields and out["env_config"].get(key, fields[key]) == fields[key]:
            out["env_config"].pop(key, None)
    for section, keys in ADDED_KEYS.items():
        for key, default in keys.items():
            if out.get(section, {}).get(key, default) == default:
                out.get(section, {}).pop(key, None)
    return out


def with_fields_added_since(values: dict[str, Any]) -> dict[str, Any]:
    """A saved run's values with the env config fields that vnl added after it was written.

    A saved `env_config` is complete (`resolved`), so a field missing from it did not exist then.
    It takes the field's class default (`env_field_defaults`), not the env's current default: a
    run saved before `rodent_run` observed its heading rebuilds the env it trained, with the
    observation width of its checkpoints. Unknown envs pass unchanged (`from_dict` reports them)."""
    env_config = values.get("env_config")
    if not isinstance(env_config, dict) or values.get("env") not in registry.names():
        return values
    defaults = env_field_defaults(values["env"])
    added = {k: v for k, v in defaults.items() if k not in env_config and isinstance(v, _PLAIN)}
    return {**values, "env_config": {**env_config, **config_lib.to_dict(added)}} if added else values
