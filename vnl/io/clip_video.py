"""A fitted clip drawn beside its keypoints, to a video or a strip of frames (`vnl mocap render`).

Here, above `vnl.mocap`, because it writes files with the renderer of `vnl.io.video`;
`vnl.mocap.render.overlay` draws the keypoints and markers into each frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.io import video
from vnl.mocap import body, maps
from vnl.mocap.clips import Clip
from vnl.mocap.render import overlay


def draw(clip: Clip, out: str | Path, frames: tuple[int, int | None] | None = None, camera: str | None = None,
         width: int = 480, height: int = 360, where: str = "the clip") -> int:  # fmt: skip
    """Draws `clip` (its walker, keypoints in red, fitted markers in green) to `out`: an .mp4 of
    frames START:END (`frames`; None: all), or a .png of 4 of them side by side. Needs OpenGL
    (`vnl.cli.process.configure_process` sets it up). Returns the number of frames drawn."""
    out = Path(out)
    start, end = frames or (0, None)
    rows = np.arange(clip.frames)[start:end]
    if rows.size == 0:
        raise VnlError(f"frames {start}:{end} are outside the clip's {clip.frames} frames")
    if out.suffix == ".png":
        rows = rows[np.linspace(0, rows.size - 1, min(4, rows.size)).round().astype(int)]
    model = body.fit_model(clip.walker, floor=True)
    marks = None
    if clip.marker_offsets is not None:
        ids = maps.resolve_bodies(model, clip.marker_bodies, where)
        marks = body.markers(model, clip.qpos[rows], ids, clip.marker_offsets)
    decorate = overlay(clip.keypoints[rows], marks) if clip.keypoints is not None else None
    images = video.render_frames(model, clip.qpos[rows], camera, width, height, decorate=decorate)
    if out.suffix == ".png":
        from matplotlib import image

        durable.write_atomic(out, writer=lambda tmp: image.imsave(tmp, np.concatenate(list(images), axis=1),
                                                                  format="png"))  # fmt: skip
    else:
        video.write_mp4(images, out, clip.fps)
    return int(rows.size)
