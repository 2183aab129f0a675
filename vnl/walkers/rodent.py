"""dm_control's virtual rodent (`dm_control.locomotion.walkers.rodent.Rat`), made MJX-ready.

The rat has 94 collision geoms, 22 of them ellipsoids that MJX cannot collide with boxes or
heightfields; `vnl.walkers.mjx_compat` gives those capsule/sphere proxies once the rat is placed
in an arena. Two further choices keep MJX fast on CPU, both configurable:

- no self-collision (rat-rat pairs; dm_control has them on, but standing and running do not
  need them and each pair costs MJX time);
- `contacts="essential"`: only the feet, toes, hands, fingers, torso, pelvis and the skull's
  main ellipsoid touch the ground (21 geoms instead of 94: the 30 tail vertebrae, jaw, spine,
  limbs' upper segments pass through it). `"all"` keeps every geom.
- `rigid_tail=True`: the 24 tail joints, their two tendons and two actuators are removed and the
  tail's 23 jointless vertebrae are fused into their parent (MuJoCo's `fusestatic`), keeping
  their mass and shape. The kinematic tree's depth drops from 39 to 16, which MJX's per-level
  tree passes pay for in compile time: `jit(mjx.step)` of the rat compiles in ~47 s instead of
  several minutes on a 2-core CPU. The skin (visual only, ignored by MJX) goes with it, since its
  bones reference the fused bodies; the rat then renders as its geoms.
"""

from __future__ import annotations

from typing import Any

from dm_control.locomotion.walkers import rodent as dmc_rodent

from vnl.walkers.base import Walker, add_ground_camera, collide_with_arena_only, keep_contacts

ESSENTIAL_BODIES = frozenset(
    {"foot_L", "foot_R", "toe_L", "toe_R", "hand_L", "hand_R", "finger_L", "finger_R", "torso", "pelvis"}
)
ESSENTIAL_GEOMS = frozenset({"skull_0_collision"})


def build(self_collision: bool = False, contacts: str = "essential", rigid_tail: bool = True) -> Walker:
    """Builds the rat (38 position actuators with activation filters, 67 hinge joints; 36 and 43
    with a rigid tail), to be attached to an arena with a free joint.

    Args:
      self_collision: keep rat-rat contacts (dm_control's default). Off by default.
      contacts: "essential" (21 ground-contact geoms) or "all" (94).
      rigid_tail: see the module docstring.
    """
    rat = dmc_rodent.Rat(name="walker")
    model = rat.mjcf_model
    if rigid_tail:
        _stiffen_tail(model)
    if not self_collision:
        collide_with_arena_only(model)
    if contacts == "essential":
        keep_contacts(model, set(ESSENTIAL_BODIES), ESSENTIAL_GEOMS)
    # The rat ships its own cameras: back, side, side_alt, top (tracking) and egocentric; `ground`
    # is its egocentric camera pitched 25 degrees down (the skull's frame is x forward, z up at
    # rest), fovy 50: the floor from 7 cm ahead to the horizon, 3 degrees a row at 16x16.
    # Why: docs/experiments/vision-gaps.md#a-camera-pitched-at-the-floor-built-not-trained-yet
    egocentric = model.find("camera", "egocentric")
    add_ground_camera(egocentric.parent, pos=tuple(egocentric.pos), pitch_deg=25.0, fovy=50.0)
    return Walker(
        name="rodent",
        mjcf_model=model,
        root_body="torso",
        end_effectors=tuple(b.name for b in rat.end_effectors),
        head=rat.head.name,
        height=0.06,
        size=1.0,
        view_distance=0.4,  # the default video follows it at 0.4 m: the rat fills about half the frame
        fuse_static=rigid_tail,
    )


def _stiffen_tail(model) -> None:
    """Removes the caudal joints and the tendons/actuators that drive them; drops the skin."""
    for joint in model.find_all("joint"):
        if joint.name and joint.name.startswith("vertebra_C"):
            joint.remove()
    for tendon in list(model.tendon.fixed):
        if tendon.name.startswith("caudal"):
            for actuator in model.find_all("actuator"):
                if actuator.tendon is tendon:
                    actuator.remove()
            tendon.remove()
    for skin in model.find_all("skin"):
        skin.remove()


def from_config(config: Any) -> Walker:
    """The rat with a task config's `self_collision`, `contacts` and `rigid_tail` (the registry's builder)."""
    return build(
        self_collision=getattr(config, "self_collision", False),
        contacts=getattr(config, "contacts", "essential"),
        rigid_tail=getattr(config, "rigid_tail", True),
    )
