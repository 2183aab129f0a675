"""What a task needs to know about a walker: its MJCF and the name of its root body."""

from __future__ import annotations

import dataclasses

from dm_control import mjcf


@dataclasses.dataclass(frozen=True)
class Walker:
    """A walker ready to be placed in a world.

    Attributes:
      name: short name ("ant", "humanoid").
      mjcf_model: the PyMJCF root. `standalone=True` models carry their own world (floor,
        lights) and are compiled as they are; others are attached to an arena.
      root_body: name of the body whose subtree is "the animal" (forward velocity, height).
      standalone: see above.
    """

    name: str
    mjcf_model: mjcf.RootElement
    root_body: str
    standalone: bool = False


def add_tracking_cameras(body: mjcf.Element, distance: float, height: float) -> None:
    """Adds `side` and `back` cameras that follow `body`'s subtree centre of mass.

    Both look at the walker from `distance` metres away and `height` metres up; used by
    `vnl render --camera side|back`.
    """
    body.add(
        "camera",
        name="side",
        mode="trackcom",
        pos=[0, -distance, height],
        xyaxes=[1, 0, 0, 0, height, distance],
    )
    body.add(
        "camera",
        name="back",
        mode="trackcom",
        pos=[-distance, 0, height],
        xyaxes=[0, -1, 0, height, 0, distance],
    )
