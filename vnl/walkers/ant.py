"""dm_control's quadruped ant (`dm_control.locomotion.walkers.ant.Ant`)."""

from __future__ import annotations

from typing import Any

from dm_control.locomotion.walkers import ant as dmc_ant

from vnl.walkers.base import Walker, add_ground_camera, add_tracking_cameras, collide_with_arena_only, keep_contacts


def build(self_collision: bool = False, contacts: str = "essential") -> Walker:
    """Builds dm_control's Ant (8 hinge joints, 8 motors with gear 75, torso sphere r=0.25).

    Args:
      self_collision: keep leg-leg contacts. Off by default: the legs cannot reach each other in
        normal gaits and each capsule pair costs MJX time (25 vs 69 contacts on a floor).
      contacts: "all" geoms collide with the arena, or only the "essential" ones: the four
        lower-leg capsules and the torso sphere. Each capsule on a plane makes 2 contacts, so
        this cuts the ant's contacts from 25 to 9; the thighs then pass through the ground when
        the ant collapses, but the torso cannot.
    """
    walker = dmc_ant.Ant(name="walker")
    model = walker.mjcf_model
    if not self_collision:
        collide_with_arena_only(model)
    if contacts == "essential":
        feet = frozenset(g.name for foot in walker.end_effectors for g in foot.find_all("geom"))
        keep_contacts(model, bodies=set(), geoms=feet | {"torso_geom"})
    torso = model.find("body", "torso")
    add_tracking_cameras(torso, distance=3.0, height=1.5)
    # Next to dm_control's egocentric camera, 45 degrees down: from 0.1 m to ~3.7 m ahead.
    add_ground_camera(torso, pos=(0.25, 0.0, 0.11), pitch_deg=45.0, fovy=70.0)
    return Walker(
        name="ant",
        mjcf_model=model,
        root_body="torso",
        end_effectors=tuple(b.name for b in walker.end_effectors),
        height=0.5,
        size=2.5,
    )


def from_config(config: Any) -> Walker:
    """The ant with a task config's `self_collision` and `contacts` (the registry's builder)."""
    return build(
        self_collision=getattr(config, "self_collision", False), contacts=getattr(config, "contacts", "essential")
    )
