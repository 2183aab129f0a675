"""The notebooks' MJX humanoid: MuJoCo's humanoid as shipped with mujoco-mjx's test data.

It is the model of MJX's tutorial notebook: 21 motors, feet-floor contact pairs only, named
cameras `back`, `side` and `egocentric`, and its own floor and lights (a standalone world).
"""

from __future__ import annotations

from typing import Any

from dm_control import mjcf
from etils import epath

from vnl.walkers.base import Walker

_XML = "test_data/humanoid/humanoid.xml"


def xml_path() -> epath.Path:
    """Path of the humanoid XML inside the installed `mujoco.mjx` package."""
    return epath.resource_path("mujoco.mjx") / _XML


def build() -> Walker:
    """Builds the humanoid (a standalone world: floor, light and walker)."""
    model = mjcf.from_path(str(xml_path()))
    return Walker(name="humanoid", mjcf_model=model, root_body="torso", standalone=True)


def from_config(config: Any) -> Walker:
    """The humanoid (it takes no options; the registry's builder)."""
    return build()
