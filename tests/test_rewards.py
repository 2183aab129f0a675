"""vnl.rewards.tolerance equals dm_control's rewards.tolerance (linear sigmoid)."""

import numpy as np
import pytest
from dm_control.utils import rewards as dmc_rewards

from vnl import rewards


@pytest.mark.parametrize(
    "bounds,margin,value_at_margin",
    [((1.0, 1.0), 1.0, 0.0), ((6.0, float("inf")), 6.0, 0.0), ((0.5, 2.0), 0.3, 0.1), ((0.0, 0.0), 0.0, 0.0)],
)
def test_tolerance_matches_dm_control(bounds, margin, value_at_margin):
    x = np.linspace(-3, 14, 301)
    ours = np.asarray(rewards.tolerance(x, bounds, margin, value_at_margin))
    theirs = dmc_rewards.tolerance(x, bounds, margin, sigmoid="linear", value_at_margin=value_at_margin)
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


def test_tolerance_rejects_bad_arguments():
    with pytest.raises(ValueError, match="lower bound"):
        rewards.tolerance(np.zeros(2), (1.0, 0.0))
    with pytest.raises(ValueError, match="margin"):
        rewards.tolerance(np.zeros(2), (0.0, 1.0), margin=-1)
