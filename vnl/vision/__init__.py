"""In-graph cameras: images rendered from an `mjx.Data` inside jit (`camera.py`), and pixel
observations for any env (`env.py`)."""

from vnl.vision.camera import Camera
from vnl.vision.env import VisionConfig, VisionEnv

__all__ = ["Camera", "VisionConfig", "VisionEnv"]
