"""Linear CKA (`vnl compare --measure cka`, the default): centered kernel alignment, Kornblith et
al. 2019. For activity matrices X (n, p) and Y (n, q) over the same n steps, with centred columns,
||YᵀX||²_F / (||XᵀX||_F ||YᵀY||_F): 1 when one is a rotation (or isotropic scaling) of the other,
near 0 for unrelated representations; NaN for a constant layer."""

from __future__ import annotations

import numpy as np

from vnl.errors import VnlError
from vnl.neuro.registry import Options

RANGE = (0.0, 1.0)


def linear_cka(x: np.ndarray, y: np.ndarray) -> float:
    """Linear CKA of activity matrices x (n, p) and y (n, q) over the same n samples."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    if x.ndim != 2 or y.ndim != 2 or x.shape[0] != y.shape[0]:
        raise VnlError(f"CKA needs two (samples, units) matrices with the same samples, got {x.shape} and {y.shape}")
    x = x - x.mean(axis=0)
    y = y - y.mean(axis=0)
    cross = np.linalg.norm(y.T @ x) ** 2
    norm = np.linalg.norm(x.T @ x) * np.linalg.norm(y.T @ y)
    return float(cross / norm) if norm > 0 else float("nan")


def label(options: Options) -> str:
    return "linear CKA"


def matrix(a: dict[str, np.ndarray], b: dict[str, np.ndarray], options: Options) -> np.ndarray:
    """Linear CKA of every layer of `a` with every layer of `b` (name -> (steps, units))."""
    return np.array([[linear_cka(x, y) for y in b.values()] for x in a.values()])
