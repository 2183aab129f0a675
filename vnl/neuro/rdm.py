"""Representational dissimilarity matrices with rsatoolbox (`vnl compare --measure rdm`).

Each layer's activity on the same n steps (the conditions) gives an RDM (`rsatoolbox.rdm.calc_rdm`,
a dissimilarity such as `correlation` or `euclidean` between every two steps' population vectors);
the RDMs of two networks' layers are compared with rsatoolbox's comparison methods
(`rsatoolbox.rdm.compare`: `cosine`, `corr`, `spearman`, `tau-a`, `rho-a`, ...). Beside linear CKA
and the Spearman RSA of `vnl.neuro.rsa`, which compute their own.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vnl.errors import VnlError
from vnl.neuro.registry import Options
from vnl.recording import model

RDM_METHODS = ("correlation", "euclidean", "mahalanobis", "poisson")
COMPARISONS = ("cosine", "corr", "spearman", "tau-a", "rho-a", "kendall")
RANGE = (-1.0, 1.0)


def check_methods(rdm_method: str, comparison: str) -> None:
    """`VnlError` unless both are methods this module offers."""
    if rdm_method not in RDM_METHODS:
        raise VnlError(f"unknown RDM method {rdm_method!r}; choose one of {', '.join(RDM_METHODS)}")
    if comparison not in COMPARISONS:
        raise VnlError(f"unknown RDM comparison {comparison!r}; choose one of {', '.join(COMPARISONS)}")


def rdms(layers: dict[str, np.ndarray], method: str = "correlation") -> Any:
    """One `rsatoolbox.rdm.RDMs` holding an RDM per layer (rdm descriptor `layer`), from
    `layers`: name -> activity (n conditions, units), the same n conditions for all."""
    from rsatoolbox.data import Dataset
    from rsatoolbox.rdm import calc_rdm, concat

    out = []
    for name, x in layers.items():
        x = np.asarray(x, np.float64)
        ds = Dataset(x, descriptors={"layer": name}, obs_descriptors={"step": np.arange(len(x))})
        with np.errstate(invalid="ignore", divide="ignore"):
            rdm = calc_rdm(ds, method=method, descriptor="step")
        rdm.rdm_descriptors["layer"] = [name]
        out.append(rdm)
    return concat(out)


def compare_layers(
    a: dict[str, np.ndarray], b: dict[str, np.ndarray], method: str = "correlation", comparison: str = "cosine"
) -> np.ndarray:
    """The comparison of every layer of `a` with every layer of `b` (name -> (n, units), the same
    n conditions): a matrix (layers of a, layers of b); NaN where an RDM is undefined or constant
    (a constant layer)."""
    check_methods(method, comparison)
    from rsatoolbox.rdm import compare

    ra, rb = rdms(a, method), rdms(b, method)
    va, vb = ra.get_vectors(), rb.get_vectors()
    out = np.full((len(a), len(b)), np.nan)
    # An RDM with undefined or all-equal entries (a constant layer) has no comparison.
    ok_a = np.isfinite(va).all(1) & (np.ptp(va, axis=1) > 0)
    ok_b = np.isfinite(vb).all(1) & (np.ptp(vb, axis=1) > 0)
    if ok_a.any() and ok_b.any():
        with np.errstate(invalid="ignore", divide="ignore"):
            values = compare(ra[np.nonzero(ok_a)[0]], rb[np.nonzero(ok_b)[0]], method=comparison)
        out[np.ix_(ok_a, ok_b)] = values
    return out


def check(options: Options) -> None:
    """`VnlError` unless `options.distance` and `.comparison` are methods rsatoolbox offers here."""
    check_methods(options.distance, options.comparison)


def label(options: Options) -> str:
    return f"rsatoolbox {options.comparison} of {options.distance} RDMs"


def parameters(options: Options) -> dict[str, Any]:
    return {"distance": options.distance, "rdm_comparison": options.comparison}


def steps(mask: np.ndarray, options: Options) -> np.ndarray:
    """At most `options.max_samples` of the active steps, evenly spaced (RDMs grow with the
    square of the steps)."""
    return model.subsample(mask, options.max_samples)


def matrix(a: dict[str, np.ndarray], b: dict[str, np.ndarray], options: Options) -> np.ndarray:
    return compare_layers(a, b, options.distance, options.comparison)
