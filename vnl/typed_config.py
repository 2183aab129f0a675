"""Typed, frozen configs built from plain dicts (YAML, `--set key=value`, `make(**overrides)`).

Every config is a frozen dataclass. `from_dict` checks keys and types recursively and calls each
class's `validate()`, so an unknown key, a wrong type or a bad value is reported (naming the key
and the valid choices) before anything is compiled. `override` never mutates: it returns a new
config.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, TypeVar

import yaml

from vnl.errors import VnlError

C = TypeVar("C")


class FrozenDict(dict):
    """A dict that cannot be changed after it is built: the mapping fields of frozen configs
    (`TrainConfig.env_config`, registry presets), so no one can mutate a shared default."""

    def _refuse(self, *args: Any, **kwargs: Any) -> None:
        raise TypeError("config mappings are frozen; build a new config with vnl.typed_config.override/merge")

    __setitem__ = __delitem__ = clear = pop = popitem = setdefault = update = _refuse  # type: ignore[assignment]
    __ior__ = _refuse  # type: ignore[assignment]

    def __hash__(self) -> int:  # type: ignore[override]
        return hash(tuple(sorted((k, _hashable(v)) for k, v in self.items())))

    def __reduce__(self) -> Any:
        return (FrozenDict, (dict(self),))


def _hashable(value: Any) -> Any:
    if isinstance(value, dict):
        return tuple(sorted((k, _hashable(v)) for k, v in value.items()))
    if isinstance(value, list):
        return tuple(_hashable(v) for v in value)
    return value


def freeze(value: Any) -> Any:
    """A deep copy of `value` with every dict a `FrozenDict` and every list a tuple."""
    if isinstance(value, dict):
        return FrozenDict({k: freeze(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(freeze(v) for v in value)
    return value


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp).replace("typing.", ""))


def _coerce(value: Any, tp: Any, key: str) -> Any:
    """Checks `value` against the annotation `tp` and returns it in canonical form."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, key)
            except VnlError as e:
                errors.append(str(e))
        raise VnlError(errors[0] if errors else f"{key}: invalid value {value!r}")
    if origin is typing.Literal:
        choices = typing.get_args(tp)
        if value not in choices:
            raise VnlError(f"{key}: {value!r} is not one of {list(choices)}")
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise VnlError(f"{key}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise VnlError(f"{key}: expected {len(args)} values, got {len(value)} ({value!r})")
        return tuple(_coerce(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True)))
    if origin is dict:
        if not isinstance(value, dict):
            raise VnlError(f"{key}: expected a mapping, got {value!r}")
        return freeze(value)
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise VnlError(f"{key}: expected a mapping of {_type_name(tp)} fields, got {value!r}")
        return from_dict(tp, value, prefix=f"{key}.")
    if tp is bool:
        if not isinstance(value, bool):
            raise VnlError(f"{key}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise VnlError(f"{key}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise VnlError(f"{key}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise VnlError(f"{key}: expected a string, got {value!r}")
        return value
    if tp is Any:
        return value
    raise TypeError(f"unsupported config annotation {tp!r} for {key}")


def from_dict(cls: type[C], values: dict[str, Any], prefix: str = "") -> C:
    """Builds a `cls` dataclass from `values`; unknown keys and bad types raise `VnlError`."""
    if not isinstance(values, dict):
        raise VnlError(f"{prefix.rstrip('.') or 'config'}: expected a mapping, got {values!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise VnlError(
            f"unknown config key {prefix}{unknown[0]!s}; valid keys"
            f"{' under ' + prefix.rstrip('.') if prefix else ''} are: {', '.join(sorted(fields))}"
        )
    kwargs = {}
    for name, value in values.items():
        kwargs[name] = _coerce(value, hints[name], prefix + name)
    try:
        obj = cls(**kwargs)
    except TypeError as e:  # a required field is missing
        raise VnlError(f"{prefix or cls.__name__}: {e}") from None
    _validate_tree(obj, prefix)
    return obj


def _validate_tree(obj: Any, prefix: str) -> None:
    # Nested dataclasses were validated when they were built; this runs the object's own checks.
    validate = getattr(obj, "validate", None)
    if validate is not None:
        try:
            validate()
        except VnlError as e:
            raise VnlError(f"{prefix}{e}" if prefix else str(e)) from None


def to_dict(obj: Any) -> Any:
    """Plain (YAML-safe) dict of a config dataclass: tuples become lists."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_dict(v) for k, v in obj.items()}
    return obj


def merge(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """Recursive dict merge (a new dict; neither input is modified)."""
    out = dict(base)
    for k, v in update.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out


def override(config: C, updates: dict[str, Any]) -> C:
    """A new config: `config` with `updates` (nested dict) applied and re-validated."""
    return from_dict(type(config), merge(to_dict(config), updates))


def parse_assignment(text: str) -> dict[str, Any]:
    """`'ppo.learning_rate=3e-4'` -> `{'ppo': {'learning_rate': 0.0003}}` (values parsed as YAML)."""
    if "=" not in text:
        raise VnlError(f"--set expects key=value, got {text!r} (e.g. --set ppo.learning_rate=1e-3)")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise VnlError(f"--set: bad key {key!r} in {text!r}")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    # YAML 1.1 reads '3e-4' as a string; accept it as the number the user meant.
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    out: dict[str, Any] = {}
    node = out
    parts = key.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value
    return out


def load_yaml(path: str) -> dict[str, Any]:
    """Reads a YAML mapping; a missing or malformed file raises `VnlError`."""
    try:
        with open(path) as f:
            data = yaml.safe_load(f)
    except FileNotFoundError:
        raise VnlError(f"config file not found: {path}") from None
    except IsADirectoryError:
        raise VnlError(f"config file {path} is a directory; give the path of a YAML file") from None
    except OSError as e:
        raise VnlError(f"cannot read config file {path}: {e.strerror or e}") from None
    except UnicodeDecodeError:
        raise VnlError(f"config file {path} is not text (not a YAML file?)") from None
    except yaml.YAMLError as e:
        raise VnlError(f"config file {path} is not valid YAML: {e}".splitlines()[0]) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise VnlError(f"config file {path} must hold a mapping of keys, got {type(data).__name__}")
    return _fix_yaml_floats(data)


def _fix_yaml_floats(node: Any) -> Any:
    if isinstance(node, dict):
        return {k: _fix_yaml_floats(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_fix_yaml_floats(v) for v in node]
    if isinstance(node, str):
        try:
            return float(node) if any(c in node.lower() for c in "e.") else node
        except ValueError:
            return node
    return node


def to_yaml(obj: Any) -> str:
    """A config (dataclass or dict) as the YAML text a run's config.yaml holds."""
    return yaml.safe_dump(to_dict(obj), sort_keys=False)


def dump_yaml(obj: Any, path: str) -> None:
    """Writes a config (dataclass or dict) as YAML (`to_yaml`), atomically (temp file + rename)."""
    import os

    tmp = f"{path}.tmp"
    with open(tmp, "w") as f:
        f.write(to_yaml(obj))
    os.replace(tmp, path)


def task_variant_assignment(text: str) -> dict[str, Any]:
    """One `--set env_config.KEY=VALUE` of `vnl eval`, `render` or `record`, parsed; anything
    but an env_config key is refused (it would not be the run's policy). Imports nothing heavy."""
    key = text.split("=", 1)[0].strip()
    if not key.startswith("env_config."):
        raise VnlError(
            f"--set {key}: a trained run can only be evaluated on a variant of its task, so --set takes "
            "env_config.* keys here (e.g. --set env_config.terminate_root_below=null)"
        )
    return parse_assignment(text)
