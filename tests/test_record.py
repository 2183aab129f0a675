"""vnl.record: how a rollout's arrays become the recording's variables."""

import numpy as np


def test_a_pixel_env_s_observation_is_recorded_as_state_and_images():
    """`vnl record` on a --vision run: the dict observation (episode-major, as the rollout engine
    gives it) becomes the labelled state and one (episode, time, row, column, channel) array per
    camera (it assumed a flat observation)."""
    from vnl.record import _observation_variables

    class Env:
        def observation_layout(self):
            return [("joints", 2), ("gyro", 1), ("pixels/egocentric (uint8 4x4x3)", 48)]

    obs = {"state": np.zeros((2, 5, 3)), "pixels/egocentric": np.zeros((2, 5, 4, 4, 3), np.uint8)}
    data, labels = _observation_variables(Env(), obs)
    assert labels == ["joints[0]", "joints[1]", "gyro[0]"]
    assert data["observation"][1].shape == (2, 5, 3)  # (episode, time, feature)
    dims, image = data["pixels_egocentric"]
    assert dims == ("episode", "time", "pixel_row", "pixel_column", "channel") and image.shape == (2, 5, 4, 4, 3)
