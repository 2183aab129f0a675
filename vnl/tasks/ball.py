"""What the ball tasks (find_target, cue_memory) share: their config fields and their world.

The world is a floor, a light, a `side` camera and the task's mocap targets (PyMJCF), with the
`ball` walker (`vnl.walkers.ball`) attached on its slide joints; nothing collides.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Literal

import mujoco
from dm_control import mjcf

from vnl import physics, walkers
from vnl.errors import VnlError
from vnl.tasks.base import check_warp_available


@dataclasses.dataclass(frozen=True)
class BallTaskConfig:
    """Fields every ball task has. Lengths in metres, times in seconds; steps are control steps
    (`physics_timestep` x `n_substeps` s each)."""

    walker: str = "ball"  # a name in vnl.walkers' registry whose body has two slide joints x, y
    episode_length: int = 100
    physics_timestep: float = 0.02
    n_substeps: int = 2
    ball_radius: float = 0.1
    gear: float = 5.0  # force (N) at action 1 on the 1 kg ball
    damping: float = 2.0  # N·s/m on each slide joint: top speed gear / damping
    reset_noise_scale: float = 0.05  # the ball's start position, uniform ± this
    reach_distance: float = 0.2
    reached_bonus: float = 1.0
    ctrl_cost_weight: float = 0.01
    impl: Literal["jax", "warp", "c"] = "jax"  # physics (vnl.physics); c = MuJoCo C on `threads` threads
    threads: int | None = None

    def validate(self) -> None:
        walkers.spec(self.walker)
        if not (1 <= self.episode_length <= 10**7 and 1 <= self.n_substeps <= 10**4):
            raise VnlError(
                f"episode_length must be in 1..10,000,000 control steps and n_substeps in 1..10,000, got "
                f"{self.episode_length:,} and {self.n_substeps:,}; shorten the episode or the physics step's split"
            )
        if not 0 < self.physics_timestep <= 0.05:
            raise VnlError(f"physics_timestep must be in (0, 0.05], got {self.physics_timestep}")
        for key in ("ball_radius", "reach_distance", "gear", "damping"):
            if not getattr(self, key) > 0:
                raise VnlError(f"{key} must be > 0, got {getattr(self, key)}")
        for key in ("reached_bonus", "ctrl_cost_weight", "reset_noise_scale"):
            if not getattr(self, key) >= 0:
                raise VnlError(f"{key} must be >= 0, got {getattr(self, key)}")
        if self.impl == "warp":
            check_warp_available()
        physics.resolve_threads(self.threads)


@dataclasses.dataclass(frozen=True)
class Target:
    """A mocap sphere the ball rolls to: name, start position (m), radius (m), colour (RGBA)."""

    name: str
    pos: tuple[float, float, float]
    size: float
    rgba: tuple[float, float, float, float]


def world(
    config: BallTaskConfig, floor: float, side: tuple[Sequence[float], Sequence[float]], targets: Sequence[Target]
) -> mujoco.MjModel:
    """The compiled world: a floor of half-size `floor`, a `side` camera at `side` = (pos, xyaxes),
    the ball walker of `config` and `targets` (mocap bodies, in this order in `mocap_pos`)."""
    root = mjcf.RootElement(model="world")
    root.option.timestep = config.physics_timestep
    root.visual.__getattr__("global").offwidth = 640
    root.visual.__getattr__("global").offheight = 480
    root.worldbody.add("light", pos=[0, 0, 4], dir=[0, 0, -1], directional=True)
    root.worldbody.add(
        "geom",
        name="floor",
        type="plane",
        size=[floor, floor, 0.1],
        rgba=[0.55, 0.6, 0.65, 1],
        contype=0,
        conaffinity=0,
    )
    root.worldbody.add("camera", name="side", pos=list(side[0]), xyaxes=list(side[1]), fovy=60)
    root.attach(walkers.build(config.walker, config).mjcf_model)  # no free joint: the slide joints move it
    for t in targets:
        body = root.worldbody.add("body", name=t.name, mocap=True, pos=list(t.pos))
        body.add("geom", name=t.name, type="sphere", size=[t.size], rgba=list(t.rgba), contype=0, conaffinity=0)
    return mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())
