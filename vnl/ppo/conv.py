"""Convolutions as patches x matrix: a workaround for slow convolution gradients in XLA:CPU loops.

On XLA:CPU (jax 0.8), the kernel gradient of a convolution is ~10-20x slower inside a while loop
(every `lax.scan` of a training step) than outside: XLA keeps its non-canonical dimension layout
(`f01b_i01o->01bf`) there instead of rewriting it into the Eigen convolution it uses at the top
level (measured: 774 ms vs 41 ms per gradient of a 4x4 stride-2 convolution on 1280 32x32 images;
see also jax-ml/jax#12868). Brax's vision PPO networks run their CNN inside PPO's scans, so vision
training on a CPU was 10x slower than its parts.

`im2col_conv` computes the same convolution as a matrix product of image patches (strided slices
of the padded input) with the kernel; its gradients are slices, pads and matrix products, which
XLA runs at full speed in loops. `cpu_convolutions()` swaps it into every `flax.linen.Conv` called
in its context (the parameters are unchanged, so networks and checkpoints are Brax's own) — vnl
uses it on the CPU backend only; GPUs keep XLA's convolution.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from typing import Any

import jax
import jax.numpy as jp
from jax import lax


def im2col_conv(
    x: jax.Array, kernel: jax.Array, strides: Sequence[int], padding: str | Sequence[tuple[int, int]]
) -> jax.Array:
    """2-D convolution of x (B, H, W, C) with kernel (kh, kw, C, O) -> (B, H', W', O).

    Equals `lax.conv_general_dilated(x, kernel, strides, padding, dimension_numbers=("NHWC",
    "HWIO", "NHWC"))` (no dilation, one feature group); `padding` is "SAME", "VALID" or
    ((top, bottom), (left, right)).
    """
    kh, kw, c, o = kernel.shape
    if isinstance(padding, str):
        padding = lax.padtype_to_pads(x.shape[1:3], (kh, kw), tuple(strides), padding)
    x = jp.pad(x, ((0, 0), tuple(padding[0]), tuple(padding[1]), (0, 0)))
    sh, sw = strides
    ho = (x.shape[1] - kh) // sh + 1
    wo = (x.shape[2] - kw) // sw + 1
    cols = [x[:, i : i + sh * (ho - 1) + 1 : sh, j : j + sw * (wo - 1) + 1 : sw] for i in range(kh) for j in range(kw)]
    patches = jp.concatenate(cols, axis=-1)  # (B, H', W', kh * kw * C), ordered (i, j, c) like the kernel
    return patches @ kernel.reshape(kh * kw * c, o)


def _conv_general_dilated(
    lhs: jax.Array,
    rhs: jax.Array,
    window_strides: Sequence[int],
    padding: Any,
    lhs_dilation: Any = None,
    rhs_dilation: Any = None,
    dimension_numbers: Any = None,
    feature_group_count: int = 1,
    precision: Any = None,
    **kwargs: Any,
) -> jax.Array:
    """`lax.conv_general_dilated` as flax's 2-D Conv calls it, through `im2col_conv` when it can."""
    nhwc = lax.conv_dimension_numbers(lhs.shape, rhs.shape, ("NHWC", "HWIO", "NHWC"))
    plain = all(d in (None, 1) for d in (*(lhs_dilation or ()), *(rhs_dilation or ())))
    if lhs.ndim == 4 and plain and feature_group_count == 1 and dimension_numbers == nhwc and not kwargs:
        return im2col_conv(lhs, rhs, window_strides, padding)
    return lax.conv_general_dilated(
        lhs,
        rhs,
        window_strides,
        padding,
        lhs_dilation=lhs_dilation,
        rhs_dilation=rhs_dilation,
        dimension_numbers=dimension_numbers,
        feature_group_count=feature_group_count,
        precision=precision,
        **kwargs,
    )


@contextlib.contextmanager
def cpu_convolutions() -> Iterator[None]:
    """Within this context, `flax.linen.Conv` modules convolve with `im2col_conv`."""
    from flax import linen

    def interceptor(next_fun: Any, args: Any, kwargs: Any, context: Any) -> Any:
        module = context.module
        if not (isinstance(module, linen.Conv) and context.method_name == "__call__"):
            return next_fun(*args, **kwargs)
        if module.conv_general_dilated is not None or module.conv_general_dilated_cls is not None:
            return next_fun(*args, **kwargs)  # the module already has its own convolution
        # Flax modules are frozen dataclasses: set the field for this call only.
        object.__setattr__(module, "conv_general_dilated", _conv_general_dilated)
        try:
            return next_fun(*args, **kwargs)
        finally:
            object.__setattr__(module, "conv_general_dilated", None)

    with linen.intercept_methods(interceptor):
        yield
