"""dm_control's quadruped ant (`dm_control.locomotion.walkers.ant.Ant`)."""

from __future__ import annotations

from dm_control.locomotion.walkers import ant as dmc_ant

from vnl.walkers.base import Walker, add_tracking_cameras


def build(self_collision: bool = False, floor_contacts: str = "feet_and_torso") -> Walker:
    """Builds dm_control's Ant (8 hinge joints, 8 motors with gear 75, torso sphere r=0.25).

    Args:
      self_collision: keep leg-leg contacts. Off by default: the legs cannot reach each other in
        normal gaits and each capsule pair costs MJX time (25 vs 69 contacts on a floor).
        Off means walker geoms get contype=1, conaffinity=0: they still collide with the arena.
      floor_contacts: "all" geoms collide with the arena, or only the "feet_and_torso" (the four
        lower-leg capsules and the torso sphere). Each capsule on a plane makes 2 contacts, so
        this cuts the ant's contacts from 25 to 9; the thighs then pass through the ground when
        the ant collapses, but the torso cannot.
    """
    walker = dmc_ant.Ant(name="walker")
    model = walker.mjcf_model
    if not self_collision:
        for geom in model.find_all("geom"):
            geom.contype = 1
            geom.conaffinity = 0
    if floor_contacts == "feet_and_torso":
        feet = {g.name for foot in walker.end_effectors for g in foot.find_all("geom")}
        for geom in model.find_all("geom"):
            if geom.name not in feet and geom.name != "torso_geom":
                geom.contype = 0
                geom.conaffinity = 0
    add_tracking_cameras(model.find("body", "torso"), distance=3.0, height=1.5)
    return Walker(name="ant", mjcf_model=model, root_body="torso", standalone=False)
