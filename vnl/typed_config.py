"""Typed, frozen configs built from plain dicts (YAML, `--set key=value`, `make(**overrides)`).

Every config is a frozen dataclass. `from_dict` checks keys and types recursively and calls each
class's `validate()`, so an unknown key, a wrong type or a bad value is reported (naming the key
and the valid choices) before anything is compiled. `override` never mutates: it returns a new
config.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, TypeVar

import yaml

from vnl import durable, safe_yaml
from vnl.errors import VnlError

C = TypeVar("C")

INT64 = (-(2**63), 2**63 - 1)
"""The integers a config holds: what numpy and JAX store them in."""

MAX_SEED = 2**32 - 1
"""The largest seed: JAX (without 64-bit mode) keeps the low 32 bits of a seed, so seeds that
differ only above them would give the same run (and 2**63 and above do not convert at all)."""


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
                value = int(value)
            else:
                raise VnlError(f"{key}: expected an integer, got {value!r}")
        if not INT64[0] <= value <= INT64[1]:
            raise VnlError(f"{key}: {value} is out of range (a 64-bit integer: at most {INT64[1]:,})")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise VnlError(f"{key}: expected a number, got {value!r}")
        if not math.isfinite(value) or abs(value) > 1.7976931348623157e308:
            raise VnlError(f"{key}: expected a finite number, got {value!r}")
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
    odd = [k for k in values if not isinstance(k, str)]
    if odd:
        raise VnlError(f"{prefix or 'config'}: the key {odd[0]!r} is not a string; config keys are names")
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
    value = parse_value(raw, f"--set {key}")
    out: dict[str, Any] = {}
    node = out
    parts = key.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value
    check_values(out, f"--set {key}")
    return out


def parse_value(raw: str, source: str) -> Any:
    """The value of a `--set key=value`, parsed as YAML (`3e-4` a number, `[1, 2]` a list, `null`
    None); text that is not YAML is taken as the string it is. Limits as `safe_yaml.load`."""
    if not raw.strip():
        return ""
    if len(raw) > safe_yaml.MAX_BYTES:
        raise VnlError(f"{source}: the value is larger than {safe_yaml.MAX_BYTES >> 20} MiB")
    try:
        safe_yaml.check_shape(raw, source)
        value = yaml.load(raw, Loader=safe_yaml.Loader)  # noqa: S506 - a SafeLoader
    except yaml.YAMLError:
        return raw
    safe_yaml.check_keys(value, source)
    return value


def load_yaml(path: str, what: str = "config file") -> dict[str, Any]:
    """Reads a YAML mapping (`safe_yaml`: YAML 1.2 numbers, bounded size, depth and aliases,
    string keys, finite numbers); a missing, unreadable or malformed file raises `VnlError`."""
    data = safe_yaml.load(safe_yaml.read_text(path, what), f"{what} {path}")
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise VnlError(f"{what} {path} must hold a mapping of keys, got {type(data).__name__}")
    check_values(data, f"{what} {path}")
    return data


def check_values(values: Any, where: str, key: str = "", depth: int = 0) -> None:
    """Raises `VnlError` (naming `where` and the key) unless `values` is what a config can hold:
    string keys, at most `safe_yaml.MAX_DEPTH` levels, finite floats and 64-bit integers.
    Cheap and import-free: the CLI runs it on `--config`, every `--set` and a run's config.yaml
    before anything heavy is imported."""
    at = f" at {key}" if key else ""
    if depth > safe_yaml.MAX_DEPTH:
        raise VnlError(f"{where}: nested more than {safe_yaml.MAX_DEPTH} levels{at}")
    if isinstance(values, dict):
        for k, v in values.items():
            if not isinstance(k, str):
                raise VnlError(f"{where}: the key {k!r}{at.replace(' at', ' under')} is not a string; keys are names")
            check_values(v, where, f"{key}.{k}" if key else k, depth + 1)
    elif isinstance(values, (list, tuple)):
        for i, v in enumerate(values):
            check_values(v, where, f"{key}[{i}]", depth + 1)
    elif isinstance(values, float) and not math.isfinite(values):
        raise VnlError(f"{where}: {key or 'a value'} must be a finite number, got {values}")
    elif isinstance(values, int) and not isinstance(values, bool) and not INT64[0] <= values <= INT64[1]:
        raise VnlError(f"{where}: {key or 'a value'} = {values} is out of range (a 64-bit integer)")


def to_yaml(obj: Any) -> str:
    """A config (dataclass or dict) as the YAML text a run's config.yaml holds."""
    return yaml.safe_dump(to_dict(obj), sort_keys=False)


def dump_yaml(obj: Any, path: str) -> None:
    """Writes a config (dataclass or dict) as YAML (`to_yaml`), atomically and durably
    (`durable.write_atomic`: a unique temp file, fsynced, renamed, the directory fsynced)."""
    durable.write_atomic(path, to_yaml(obj))


def task_variant_assignment(text: str) -> dict[str, Any]:
    """One `--set env_config.KEY=VALUE` of `vnl eval`, `render` or `record`, parsed; anything
    but an env_config key is refused (it would not be the run's policy). Imports nothing heavy."""
    key = text.split("=", 1)[0].strip()
    if "=" in text and not key.startswith("env_config."):
        raise VnlError(
            f"--set {key}: a trained run can only be evaluated on a variant of its task, so --set takes "
            "env_config.* keys here (e.g. --set env_config.terminate_root_below=null)"
        )
    return parse_assignment(text)
