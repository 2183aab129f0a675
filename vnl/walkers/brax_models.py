"""Brax's own ant and humanoid (the models of Brax's `ant` and `humanoid` envs).

Brax's physics pipelines (generalized, positional, spring) load only models whose every body has
a joint and whose joints in one body share a position; dm_control's ant (jointless leg bodies)
and the MJX humanoid (stacked joints at different positions) are not such models. These two are,
once Brax's `fuse_bodies` has merged their jointless bodies into their parents, as Brax's own
loader does: the seed notebooks swapped Brax's pipelines on exactly them. Both are standalone worlds (their own
floor), with `side` and `back` tracking cameras added for `vnl render`.
"""

from __future__ import annotations

from typing import Any

from dm_control import mjcf
from etils import epath

from vnl.walkers.base import Walker, add_tracking_cameras


def xml_path(name: str) -> epath.Path:
    """Path of Brax's `ant.xml` / `humanoid.xml` inside the installed `brax` package."""
    return epath.resource_path("brax") / "envs" / "assets" / f"{name}.xml"


def build(name: str) -> Walker:
    """`name` is "ant" or "humanoid"; the walker is called `brax_<name>`."""
    from brax.io import mjcf as brax_mjcf

    # Brax's loader first merges jointless bodies into their parents (`fuse_bodies`); so do we.
    model = mjcf.from_xml_string(brax_mjcf.fuse_bodies(xml_path(name).read_text()))
    torso = model.find("body", "torso")
    distance, height = (3.0, 1.5) if name == "ant" else (4.0, 1.0)
    add_tracking_cameras(torso, distance, height)
    return Walker(name=f"brax_{name}", mjcf_model=model, root_body="torso", standalone=True)


def ant_from_config(config: Any) -> Walker:
    """Brax's ant (it takes no options; the registry's builder for `brax_ant`)."""
    return build("ant")


def humanoid_from_config(config: Any) -> Walker:
    """Brax's humanoid (it takes no options; the registry's builder for `brax_humanoid`)."""
    return build("humanoid")
