"""Pixel observations: any registered env, seen through an in-graph camera.

`VisionEnv(env, VisionConfig(enabled=True))` turns an env's flat observation into a dict

    {"state": the env's observation (observation_size,),
     "pixels/<camera>": uint8 image (height, width, channels)}

rendered by `vnl.vision.Camera` from the physics state of that very step, inside jit (so the
image always shows the current state). Keys follow Brax's vision convention (`pixels/` prefix:
its vision networks run a CNN on those keys, and its observation normalizer skips them).
`channels` is 3 for `rgb`, 1 for `depth` (metres mapped linearly from [0, depth_max] to [0, 255],
farther = 255), 4 for `rgbd`. uint8 keeps the training rollout 4x smaller than float32; the
networks (`vnl.ppo.networks`) scale it to [0, 1].

In training, `vnl.envs.wrappers.wrap_for_training` steps the blind env batched and renders all
environments' images with `Camera.render_batch` (a few images at a time: faster on a CPU than
rendering inside the vmapped step).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import jax
import jax.numpy as jp
import mujoco

from vnl.errors import VnlError
from vnl.tasks.contract import Env, State
from vnl.vision.camera import Camera, camera_names

CHANNELS = {"rgb": 3, "depth": 1, "rgbd": 4}


@dataclasses.dataclass(frozen=True)
class VisionConfig:
    """The camera the policy sees through (the `vision:` section of a training config).

    `camera` None picks the model's egocentric camera (a camera named `egocentric` or
    `<prefix>/egocentric`); any named camera of the model works (`vnl render --list-cameras`).
    """

    enabled: bool = False
    camera: str | None = None
    width: int = 64
    height: int = 64
    mode: Literal["rgb", "depth", "rgbd"] = "rgb"
    depth_max: float = 10.0  # metres mapped to 255 in depth images
    chunk: int | None = None  # images rendered at a time in training (None: Camera.render_batch's default)

    def validate(self) -> None:
        for key in ("width", "height"):
            if not 8 <= getattr(self, key) <= 512:
                raise VnlError(f"{key} must be in [8, 512] pixels, got {getattr(self, key)}")
        if not self.depth_max > 0:
            raise VnlError(f"depth_max must be > 0 metres, got {self.depth_max}")
        if self.chunk is not None and not 1 <= self.chunk <= 2**16:
            raise VnlError(
                f"chunk (images rendered at a time) must be in 1..65,536, got {self.chunk:,}; use a smaller chunk "
                "(null: the renderer's default)"
            )


def default_camera(model: mujoco.MjModel) -> str:
    """The model's egocentric camera; a `VnlError` listing the cameras when there is none."""
    names = camera_names(model)
    for name in names:
        if name == "egocentric" or name.endswith("/egocentric"):
            return name
    raise VnlError(
        f"this model has no egocentric camera; set vision.camera to one of: {', '.join(names) or 'none (add one)'}"
    )


class VisionEnv(Env):
    """`env` with a dict observation {"state", "pixels/<camera>"}; everything else is `env`'s.

    Args:
      env: any vnl `Env` with a flat observation.
      config: the camera settings (`enabled` is not read: wrapping means vision is on).

    Raises `VnlError` (before anything is compiled) for an unknown camera or geoms the camera
    cannot draw (meshes).
    """

    def __init__(self, env: Env, config: VisionConfig) -> None:
        config.validate()
        if isinstance(env.observation_shape, dict):
            raise VnlError(f"{type(env).__name__} already has a dict observation; vision wraps flat observations")
        self.blind = env
        self.vision = config
        self.camera_name = config.camera or default_camera(env.mj_model)
        self.camera = Camera(env.mj_model, self.camera_name, config.width, config.height)
        self.pixels_key = "pixels/" + self.camera_name.rsplit("/", 1)[-1]
        # Not Env.__init__: the wrapped env owns the model (no second mjx.put_model).
        self._config = env.config
        self._mj_model = env.mj_model
        self._mjx_model = env.mjx_model
        self._n_substeps = env.n_substeps

    # Rendering -----------------------------------------------------------------------------------
    def _image(self, rgb: jax.Array, depth: jax.Array) -> jax.Array:
        """uint8 (..., H, W, C) in the configured mode, from `Camera.render` outputs."""
        if self.vision.mode == "rgb":
            return rgb
        d = jp.round(jp.clip(depth / self.vision.depth_max, 0.0, 1.0) * 255).astype(jp.uint8)[..., None]
        return d if self.vision.mode == "depth" else jp.concatenate([rgb, d], axis=-1)

    def pixels(self, data: Any) -> jax.Array:
        """The image for one state: uint8 (height, width, channels)."""
        rgb, depth, _ = self.camera.render(data)
        return self._image(rgb, depth)

    def pixels_batch(self, data: Any) -> jax.Array:
        """Images for a batch of states (leading axis B): uint8 (B, height, width, channels)."""
        rgb, depth, _ = self.camera.render_batch(data, self.vision.chunk)
        return self._image(rgb, depth)

    def add_pixels(self, state: State, batched: bool = False) -> State:
        """`state` with its observation turned into the dict observation."""
        image = self.pixels_batch(state.data) if batched else self.pixels(state.data)
        return state.replace(obs={"state": state.obs, self.pixels_key: image})

    # The Env contract ----------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        return self.add_pixels(self.blind.reset(rng))

    def step(self, state: State, action: jax.Array) -> State:
        blind = self.blind.step(state.replace(obs=state.obs["state"]), action)
        return self.add_pixels(blind)

    @property
    def observation_shape(self) -> dict[str, tuple[int, ...]]:
        channels = CHANNELS[self.vision.mode]
        return {
            "state": tuple(self.blind.observation_shape),
            self.pixels_key: (self.vision.height, self.vision.width, channels),
        }

    def observation_layout(self) -> list[tuple[str, int]]:
        h, w, c = self.observation_shape[self.pixels_key]
        return [*self.blind.observation_layout(), (f"{self.pixels_key} (uint8 {h}x{w}x{c})", h * w * c)]

    @property
    def unwrapped(self) -> Env:
        return self.blind.unwrapped

    @property
    def backend(self) -> str:
        return self.blind.backend

    @property
    def previous_state_reads(self) -> tuple[str, ...] | None:
        """The blind env's: the camera draws the state a step returns."""
        return self.blind.previous_state_reads

    def __getattr__(self, name: str) -> Any:  # task attributes (cameras, walker, ...) of the blind env
        if name == "blind":
            raise AttributeError(name)
        return getattr(self.blind, name)
