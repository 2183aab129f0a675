"""What every vnl arena starts from: dm_control's lighting and sky, and a checker material."""

from __future__ import annotations

from dm_control import mjcf


def new_arena(
    name: str,
    material: str,
    rgb1: tuple[float, float, float],
    rgb2: tuple[float, float, float],
    texrepeat: tuple[float, float],
    texuniform: bool,
) -> mjcf.RootElement:
    """An empty arena with dm_control's corridor headlight and gradient skybox, and a checker
    material called `material` (colours `rgb1`/`rgb2`)."""
    root = mjcf.RootElement(model=name)
    root.visual.headlight.set_attributes(ambient=[0.4, 0.4, 0.4], diffuse=[0.8, 0.8, 0.8], specular=[0.1, 0.1, 0.1])
    root.asset.add(
        "texture", type="skybox", builtin="gradient", rgb1=[0.4, 0.6, 0.8], rgb2=[0, 0, 0], width=100, height=600
    )
    root.asset.add(
        "texture", name="grid", type="2d", builtin="checker", rgb1=list(rgb1), rgb2=list(rgb2), width=100, height=100
    )
    root.asset.add("material", name=material, texture="grid", texrepeat=list(texrepeat), texuniform=texuniform)
    return root
