"""RSA, representational similarity analysis (`vnl compare --measure rsa`): the Spearman
correlation of two layers' representational dissimilarity matrices (pairwise distances between
the n steps, any `scipy.spatial.distance.pdist` metric: correlation, euclidean, cosine, ...).
`vnl.neuro.rdm` makes and compares the RDMs with rsatoolbox instead."""

from __future__ import annotations

from typing import Any

import numpy as np

from vnl.errors import VnlError
from vnl.neuro.registry import Options
from vnl.recording import model

RANGE = (-1.0, 1.0)


def rsa(x: np.ndarray, y: np.ndarray, distance: str = "correlation") -> float:
    """Spearman correlation between the representational dissimilarity matrices of x (n, p) and
    y (n, q): `scipy.spatial.distance.pdist(·, distance)` over the n samples."""
    from scipy.spatial.distance import pdist
    from scipy.stats import spearmanr

    with np.errstate(invalid="ignore", divide="ignore"):
        a = pdist(np.asarray(x, np.float64), distance)
        b = pdist(np.asarray(y, np.float64), distance)
    ok = np.isfinite(a) & np.isfinite(b)  # e.g. the correlation distance of a constant row
    if ok.sum() < 3:
        return float("nan")
    return float(spearmanr(a[ok], b[ok]).statistic)


def check_distance(distance: str) -> None:
    """`VnlError` unless `distance` is a metric `scipy.spatial.distance.pdist` knows."""
    from scipy.spatial.distance import pdist

    try:
        pdist(np.eye(3), distance)
    except ValueError:
        raise VnlError(
            f"unknown distance {distance!r} for RSA; e.g. correlation, euclidean, cosine, cityblock "
            "(any metric of scipy.spatial.distance.pdist)"
        ) from None


def check(options: Options) -> None:
    check_distance(options.distance)


def label(options: Options) -> str:
    return f"RSA (Spearman of {options.distance} RDMs)"


def parameters(options: Options) -> dict[str, Any]:
    return {"distance": options.distance}


def steps(mask: np.ndarray, options: Options) -> np.ndarray:
    """At most `options.max_samples` of the active steps, evenly spaced (RDMs grow with the
    square of the steps)."""
    return model.subsample(mask, options.max_samples)


def matrix(a: dict[str, np.ndarray], b: dict[str, np.ndarray], options: Options) -> np.ndarray:
    """RSA of every layer of `a` with every layer of `b` (name -> (steps, units))."""
    return np.array([[rsa(x, y, options.distance) for y in b.values()] for x in a.values()])
