"""Pure-JAX reward primitives (dm_control's `utils.rewards`, for use inside jit)."""

from __future__ import annotations

import jax
import jax.numpy as jp


def tolerance(
    x: jax.Array,
    bounds: tuple[float, float] = (0.0, 0.0),
    margin: float = 0.0,
    value_at_margin: float = 0.0,
) -> jax.Array:
    """1 inside `bounds`, falling linearly outside them to `value_at_margin` at distance `margin`
    (and to 0 at `margin / (1 - value_at_margin)`); elementwise, same shape as `x`.

    dm_control's `rewards.tolerance(x, bounds, margin, sigmoid="linear", value_at_margin)`.
    Bounds may be infinite.
    """
    lower, upper = bounds
    if lower > upper:
        raise ValueError(f"lower bound {lower} > upper bound {upper}")
    if margin < 0:
        raise ValueError(f"margin must be >= 0, got {margin}")
    if not 0 <= value_at_margin < 1:
        raise ValueError(f"value_at_margin must be in [0, 1), got {value_at_margin}")
    in_bounds = (lower <= x) & (x <= upper)
    if margin == 0:
        return jp.where(in_bounds, 1.0, 0.0)
    d = jp.where(x < lower, lower - x, x - upper) / margin
    scaled = d * (1.0 - value_at_margin)
    outside = jp.where(jp.abs(scaled) < 1, 1 - scaled, 0.0)
    return jp.where(in_bounds, 1.0, outside)
