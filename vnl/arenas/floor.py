"""A flat floor: dm_control's `locomotion.arenas.Floor` (checkered plane, headlight, skybox)."""

from __future__ import annotations

import mujoco
from dm_control import mjcf
from dm_control.locomotion.arenas import floors

from vnl.walkers.base import Walker


def build(size: float = 50.0) -> mjcf.RootElement:
    """The floor arena's MJCF. `size` (m) is the rendered half-extent; collision is infinite."""
    return floors.Floor(size=(size, size)).mjcf_model


def compile_world(walker: Walker, arena: mjcf.RootElement | None) -> mujoco.MjModel:
    """Attaches `walker` to `arena` with a free joint and compiles the world once on the host.

    Standalone walkers (with their own world) are compiled as they are; `arena` must be None.
    Body, geom and camera names of an attached walker get the prefix `walker/`.
    """
    if walker.standalone:
        root = walker.mjcf_model
    else:
        if arena is None:
            raise ValueError(f"walker {walker.name!r} needs an arena")
        root = arena
        frame = root.attach(walker.mjcf_model)
        frame.add("freejoint")
    xml = root.to_xml_string()
    assets = root.get_assets()
    return mujoco.MjModel.from_xml_string(xml, assets)
