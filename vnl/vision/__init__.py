"""In-graph cameras: images rendered from an `mjx.Data` inside jit (see `camera.py`)."""

from vnl.vision.camera import Camera

__all__ = ["Camera"]
