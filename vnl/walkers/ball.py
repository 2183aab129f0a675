"""A ball that rolls on the floor: the body of find_target and cue_memory.

Two slide joints (x, y) with viscous damping, a motor on each (`gear` N at action 1), a 1 kg sphere
that touches nothing (contype 0: the tasks need no contacts, so MuJoCo C and MJX step it the same)
and an `egocentric` camera 1.5 m above it looking straight down (fovy 90°: it sees about ±1.5 m).
It is attached to an arena without a free joint: the slide joints are its only degrees of freedom.
"""

from __future__ import annotations

from typing import Any

from dm_control import mjcf

from vnl.walkers.base import Walker

HEIGHT = 0.1
"""The ball's centre above the floor (m)."""


def build(radius: float = 0.1, gear: float = 5.0, damping: float = 2.0) -> Walker:
    """The ball: sphere of `radius` (m), motors of `gear` (N), slide damping `damping` (N·s/m)."""
    model = mjcf.RootElement(model="walker")  # names as other walkers': walker/egocentric
    body = model.worldbody.add("body", name="ball", pos=[0, 0, HEIGHT])
    for axis, direction in (("x", [1, 0, 0]), ("y", [0, 1, 0])):
        body.add("joint", name=axis, type="slide", axis=direction, damping=damping)
    body.add(
        "geom", name="ball", type="sphere", size=[radius], mass=1, rgba=[0.9, 0.85, 0.3, 1], contype=0, conaffinity=0
    )
    body.add("camera", name="egocentric", pos=[0, 0, 1.5], xyaxes=[1, 0, 0, 0, 1, 0], fovy=90)
    for axis in ("x", "y"):
        model.actuator.add("motor", name=axis, joint=axis, gear=[gear], ctrlrange=[-1, 1], ctrllimited=True)
    return Walker(name="ball", mjcf_model=model, root_body="ball", height=HEIGHT, size=radius)


def from_config(config: Any) -> Walker:
    """The ball with a task config's `ball_radius`, `gear` and `damping` (the registry's builder)."""
    return build(
        radius=getattr(config, "ball_radius", 0.1),
        gear=getattr(config, "gear", 5.0),
        damping=getattr(config, "damping", 2.0),
    )
