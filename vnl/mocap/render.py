"""Keypoints drawn beside a fitted walker: spheres and lines added to MuJoCo's scene per frame.

`vnl.io.clip_video.draw` renders frames of a fitted clip with its keypoints and writes them
(`vnl mocap render` calls it). `overlay` returns the function
`vnl.io.video.render_frames(..., decorate=...)` calls after each frame's scene is built: the
keypoints as red spheres, the fitted markers (where the walker's bodies carry them) as green ones,
and a grey line between each pair, whose length is the residual. Spheres are the renderer's own
extra geoms (`mjvScene.geoms`), not bodies of the model,
so the walker's qpos is unchanged.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

KEYPOINT_RGBA = np.array([0.9, 0.15, 0.1, 1.0], np.float32)
MARKER_RGBA = np.array([0.1, 0.8, 0.2, 1.0], np.float32)
LINE_RGBA = np.array([0.3, 0.3, 0.3, 1.0], np.float32)


def overlay(keypoints: np.ndarray, markers: np.ndarray | None = None,
            radius: float = 0.004) -> Callable[[int, mujoco.MjvScene], None]:  # fmt: skip
    """A `decorate(t, scene)` drawing frame t of `keypoints` (T, K, 3) and `markers` (T, K, 3);
    NaN points are skipped, and drawing stops when the scene has no room for more geoms."""
    size = np.array([radius, 0.0, 0.0])
    eye = np.eye(3).ravel()

    def add(scene: mujoco.MjvScene) -> mujoco.MjvGeom | None:
        if scene.ngeom >= scene.maxgeom:
            return None
        scene.ngeom += 1
        return scene.geoms[scene.ngeom - 1]

    def decorate(t: int, scene: mujoco.MjvScene) -> None:
        for k, point in enumerate(keypoints[t]):
            pairs = [(point, KEYPOINT_RGBA)]
            if markers is not None:
                pairs.append((markers[t, k], MARKER_RGBA))
            for x, rgba in pairs:
                g = add(scene) if np.isfinite(x).all() else None
                if g is not None:
                    mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_SPHERE, size, x.astype(np.float64), eye, rgba)
            if markers is not None and np.isfinite(point).all() and np.isfinite(markers[t, k]).all():
                g = add(scene)
                if g is not None:
                    mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), eye, LINE_RGBA)
                    mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, 2.0, point.astype(np.float64),
                                         markers[t, k].astype(np.float64))  # fmt: skip

    return decorate
