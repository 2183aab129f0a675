"""Headless video of a trajectory with MuJoCo's renderer (OpenGL via EGL or OSMesa on CPU)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import mujoco
import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.vision.camera import camera_names


def resolve_camera(model: mujoco.MjModel, camera: str | None) -> int:
    """Camera id for `camera`; accepts `walker/<name>` or `<name>`. None: the default camera.

    The default frames the animal: `walker/tracking` (vnl's camera following an attached walker
    from behind, to its left and above, at its `view_distance`), else `side` (a standalone
    walker's), else -1 (MuJoCo's free camera).
    """
    names = camera_names(model)
    if camera is None:
        for default in ("walker/tracking", "side", "walker/side"):
            i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, default)
            if i >= 0:
                return i
        return -1
    for candidate in (camera, f"walker/{camera}"):
        i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, candidate)
        if i >= 0:
            return i
    raise VnlError(f"unknown camera {camera!r}; cameras of this model: {', '.join(names)}")


def render_frames(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    camera: str | None = None,
    width: int = 480,
    height: int = 360,
    mocap_pos: np.ndarray | None = None,
    decorate: Callable[[int, mujoco.MjvScene], None] | None = None,
) -> np.ndarray:
    """Renders one frame per row of `qpos` (shape (T, nq)); returns uint8 (T, height, width, 3).

    `mocap_pos` (T, nmocap, 3) places mocap bodies per frame (e.g. the gaps corridor's platforms).
    `decorate(t, scene)` may add geoms to frame t's scene before it is drawn (keypoints beside a
    fitted walker: `vnl.mocap.render.overlay`).

    Raises `VnlError` with the fix when no OpenGL context can be made.
    """
    cam = resolve_camera(model, camera)
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    try:
        renderer = mujoco.Renderer(model, height=height, width=width)
    except Exception as e:  # noqa: BLE001 - every GL failure means the same fix
        raise VnlError(
            f"cannot render video: no OpenGL ({type(e).__name__}: {str(e).splitlines()[0]}). "
            "Install EGL or OSMesa (Debian: apt-get install libegl1 libgl1-mesa-dri libosmesa6) "
            "and set MUJOCO_GL=egl or MUJOCO_GL=osmesa"
        ) from None
    data = mujoco.MjData(model)
    frames = np.empty((len(qpos), height, width, 3), dtype=np.uint8)
    try:
        for t, q in enumerate(qpos):
            data.qpos[:] = q
            if mocap_pos is not None and model.nmocap:
                data.mocap_pos[:] = mocap_pos[t]
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera=cam)
            if decorate is not None:
                decorate(t, renderer.scene)
            frames[t] = renderer.render()
    finally:
        renderer.close()
    return frames


def write_mp4(frames: Sequence[np.ndarray] | np.ndarray, path: str | Path, fps: float) -> Path:
    """Writes uint8 frames (T, H, W, 3) as an H.264 .mp4 (ffmpeg from imageio-ffmpeg)."""
    mediapy = _mediapy()
    return durable.write_atomic(
        Path(path), writer=lambda tmp: mediapy.write_video(str(tmp), np.asarray(frames), fps=fps)
    )


def show(frames: Sequence[np.ndarray] | np.ndarray, fps: float, width: int | None = None) -> None:
    """Shows uint8 frames (T, H, W, 3) as a video in a notebook (mediapy, with imageio-ffmpeg's
    ffmpeg when none is on PATH)."""
    _mediapy().show_video(np.asarray(frames), fps=fps, width=width)


def read_mp4(path: str | Path) -> np.ndarray:
    """Frames of a video as uint8 (T, H, W, 3).

    Runs imageio-ffmpeg's ffmpeg directly: mediapy 1.2.7's reader passes `-vsync`, which ffmpeg 9
    removed, and imageio-ffmpeg's reader starts ffmpeg with a `preexec_fn`, which forces a fork of
    this process: a process holding gigabytes (a test worker with compiled programs) got ENOMEM.
    """
    import re
    import subprocess

    import imageio_ffmpeg

    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-nostdin", "-i", str(path), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"]
    p = subprocess.run(cmd, capture_output=True, check=False)
    size = re.search(rb"Stream #\S+.*?Video: .*?[ ,](\d{2,5})x(\d{2,5})[ ,\[\n]", p.stderr)
    if p.returncode != 0 or size is None:
        tail = p.stderr.decode(errors="replace").strip().splitlines()[-1:]
        raise OSError(f"ffmpeg could not read {str(path)!r}: {tail[0] if tail else 'no output'}")
    width, height = int(size.group(1)), int(size.group(2))
    return np.frombuffer(p.stdout, np.uint8).reshape(-1, height, width, 3)


def _mediapy():  # noqa: ANN202 - returns the mediapy module
    """mediapy, pointed at imageio-ffmpeg's bundled ffmpeg when none is on PATH."""
    import shutil

    import imageio_ffmpeg
    import mediapy

    if shutil.which("ffmpeg") is None:
        mediapy.set_ffmpeg(imageio_ffmpeg.get_ffmpeg_exe())
    return mediapy
