"""What a task needs to know about a walker: its MJCF, its root body and its named parts."""

from __future__ import annotations

import dataclasses

import numpy as np
from dm_control import mjcf


@dataclasses.dataclass(frozen=True)
class Walker:
    """A walker ready to be placed in a world.

    Attributes:
      name: short name ("ant", "humanoid", "rodent", or the file's model name).
      mjcf_model: the PyMJCF root. `standalone=True` models carry their own world (floor,
        lights) and are compiled as they are; others are attached to an arena with a free joint.
      root_body: name of the body whose subtree is "the animal" (forward velocity, height).
      standalone: see above.
      end_effectors: bodies whose egocentric positions are observed (feet, hands) and whose
        height ends a gaps episode when it drops below `terminate_at_height`.
      head: body observed as an appendage (dm_control's `appendages_pos`), or None.
      height: typical standing height of the root body (m), for spawning above the ground.
      size: characteristic length (m) that arenas are scaled by (rodent 1.0 = dm_control's
        rodent corridors and bowl).
      view_distance: how far (m, scaled as the `tracking` camera's offset) the default video
        camera follows the walker from; None: `size`. Set so that the animal fills about half of
        the frame (tests/test_envs.py checks every seed env).
      fuse_static: compile the world with MuJoCo's `fusestatic` (jointless bodies merged into
        their parents: a shallower tree, faster MJX compile).
    """

    name: str
    mjcf_model: mjcf.RootElement
    root_body: str
    standalone: bool = False
    end_effectors: tuple[str, ...] = ()
    head: str | None = None
    height: float = 0.0
    size: float = 1.0
    fuse_static: bool = False
    view_distance: float | None = None


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


def add_ground_camera(body: mjcf.Element, pos: tuple[float, float, float], pitch_deg: float, fovy: float) -> None:
    """Adds an egocentric `ground` camera to `body` that looks forward and `pitch_deg` down.

    A walker's own `egocentric` camera looks at the horizon, where a gap a few metres ahead is a
    line one pixel high in a 32x32 image; pitched down, the same image spends its rows on the
    floor ahead (vision for the gaps corridor: `--set vision.camera=walker/ground`).
    """
    pitch = np.deg2rad(pitch_deg)
    # image x = the body's right (-y); image up = perpendicular to the view direction
    # (cos p, 0, -sin p), so the camera's -z looks forward and down.
    up = [float(np.sin(pitch)), 0.0, float(np.cos(pitch))]
    body.add("camera", name="ground", pos=list(pos), xyaxes=[0, -1, 0, *up], fovy=fovy)


def collide_with_arena_only(model: mjcf.RootElement) -> None:
    """No walker-walker contacts; walker-arena contacts stay.

    MuJoCo collides geoms a, b when (contype_a & conaffinity_b) | (contype_b & conaffinity_a).
    Walker geoms that collide at all (after default classes) get contype=1, conaffinity=0:
    never with each other, but with every arena geom whose conaffinity has bit 0 set.
    """
    physics = mjcf.Physics.from_mjcf_model(model)
    for geom in model.find_all("geom"):
        bound = physics.bind(geom)
        collides = bool(bound.contype) or bool(bound.conaffinity)
        geom.contype = 1 if collides else 0
        geom.conaffinity = 0


def keep_contacts(model: mjcf.RootElement, bodies: set[str], geoms: frozenset[str] = frozenset()) -> None:
    """Turns off collisions of every geom not named in `geoms` and not in a body named in `bodies`."""
    for geom in model.find_all("geom"):
        if geom.name in geoms or (geom.parent.tag == "body" and geom.parent.name in bodies):
            continue
        geom.contype = 0
        geom.conaffinity = 0
