"""Walkers (animal bodies) as PyMJCF models built from their upstream sources, by name.

A walker is a module here with a function `from_config(config) -> Walker` that reads the options it
needs from a task's config (e.g. `self_collision`, `contacts`), and one row in `_WALKERS` below:
its name, module, whether it is a standalone world (its own floor, so it runs only on it) and one
line saying what it is. Task configs check their `walker` against `names()`; `build` makes one.
Modules are imported when a walker is built, so listing the names costs nothing.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import TYPE_CHECKING, Any

from vnl.errors import VnlError

if TYPE_CHECKING:
    from vnl.walkers.base import Walker


@dataclasses.dataclass(frozen=True)
class Spec:
    """A registered walker: `module:function` builds it from a task config."""

    module: str
    description: str
    standalone: bool = False
    function: str = "from_config"


_WALKERS: dict[str, Spec] = {
    "ant": Spec("vnl.walkers.ant", "dm_control's quadruped ant (8 hinge joints)"),
    "rodent": Spec("vnl.walkers.rodent", "dm_control's rat (Merel et al. 2020), tail rigid by default"),
    "humanoid": Spec("vnl.walkers.humanoid", "the MJX notebooks' humanoid, with its own floor", standalone=True),
    "brax_ant": Spec("vnl.walkers.brax_models", "Brax's ant, with its own floor", True, "ant_from_config"),
    "brax_humanoid": Spec(
        "vnl.walkers.brax_models", "Brax's humanoid, with its own floor", True, "humanoid_from_config"
    ),
    "ball": Spec("vnl.walkers.ball", "a ball rolled by two motors on slide joints, with a downward camera"),
}


def names() -> tuple[str, ...]:
    """The registered walker names, in registration order."""
    return tuple(_WALKERS)


def spec(name: str) -> Spec:
    """The registered walker `name`; a `VnlError` listing the valid names otherwise."""
    if not isinstance(name, str) or name not in _WALKERS:
        raise VnlError(
            f"unknown walker {name!r}; valid walkers are: {', '.join(names())} (or walker_xml: a path to an MJCF file)"
        )
    return _WALKERS[name]


def build(name: str, config: Any) -> Walker:
    """Walker `name`, with the options it reads from `config` (a task config)."""
    s = spec(name)
    return getattr(importlib.import_module(s.module), s.function)(config)


def register(name: str, module: str, description: str, standalone: bool = False, function: str = "from_config") -> None:
    """Adds a walker at run time: `module:function(config) -> Walker` (a `vnl.walkers.base.Walker`)."""
    if not name.isidentifier():
        raise VnlError(f"a walker's name must be a Python identifier, got {name!r}")
    if name in _BUILT_IN:
        raise VnlError(f"{name!r} is a built-in walker; register yours under another name")
    _WALKERS[name] = Spec(module, description, standalone, function)


def unregister(name: str) -> None:
    """Removes a walker added with `register` (the built-in ones stay)."""
    if name in _BUILT_IN:
        raise VnlError(f"{name!r} is a built-in walker and cannot be removed")
    _WALKERS.pop(name, None)


_BUILT_IN = frozenset(_WALKERS)
