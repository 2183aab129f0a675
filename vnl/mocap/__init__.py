"""Motion capture: keypoints in, fitted reference clips out (docs/reference/clip-format.md)."""
