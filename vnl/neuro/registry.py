"""The analysis methods by name: what `vnl analyze --method` and `vnl compare --measure` offer.

Adding a method is one module and one line in `ANALYSES` or `MEASURES` (the steps:
docs/developers/index.md, "Add an analysis method"). The CLI takes its choices and their help from
these tables and imports a method's module only when it is asked for.

An analysis (`vnl analyze`: one recording) is a module that defines

    analyze(ds, options: Options) -> result     raises VnlError, before fitting, when it cannot estimate
    report(result) -> str                       the lines `vnl analyze` prints
    figure(result, out: Path, dt: float) -> Path
    output_name(options: Options, ds=None) -> str    the default figure's name, without its suffix

and whose result has `to_json() -> dict`, written beside the figure (`json_text`: NaN and
infinities become null).

A measure (`vnl compare`: the layers of two networks on the same steps) is a module that defines

    matrix(a, b, options: Options) -> (len(a), len(b)) array    a, b: layer -> (steps, units)
    label(options: Options) -> str              what the numbers are, for tables and figures
    RANGE = (low, high)                         the heatmap's colour range

and, where it needs them: `check(options)` (refuse options before anything is computed),
`steps(mask, options) -> mask` (which of the recording's (episode, time) steps it compares; all
active ones by default), `parameters(options) -> dict` (for its JSON) and `DISTANCE = True` (0
means the same: the heatmap's colours run the other way).

This module imports nothing heavy: the CLI reads it before JAX is imported.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import math
from types import ModuleType
from typing import Any

from vnl.errors import VnlError

ANALYSES = {  # name -> (module, what it does: the --method help)
    "pca": ("vnl.neuro.pca", "a layer's PCA over time"),
    "encoding": ("vnl.neuro.encoding", "ridge from behaviour features to each unit (held-out R² per unit, per layer)"),
    "decoding": ("vnl.neuro.decoding", "--target from --layer's units (held-out R²)"),
    "states": ("vnl.neuro.states", "segment the kinematics into --states states and average each layer per state"),
    "embedding": (
        "vnl.neuro.embedding",
        "the behaviour's time-frequency content clustered into --states behaviours and mapped by t-SNE",
    ),
    "rhythm": (
        "vnl.neuro.rhythm",
        "units oscillating with the gait: spectral index at the feet's frequency, phase locking against --control",
    ),
    "tasks": (
        "vnl.neuro.tasks",
        "a suite's recording of several tasks: each layer's task-modulated units and its RSA of --states "
        "behaviours across tasks",
    ),
    "dynamics": (
        "vnl.neuro.task_dynamics",
        "a suite's recording of several tasks: each layer's dynamics (DSA) compared between tasks, against "
        "the distance between two halves of one task",
    ),
}
DEFAULT_STATES = {"tasks": 10}
"""--states when it is not given, by method (else 4)."""

MEASURES = {  # name -> (module, what it does: the --measure help)
    "cka": ("vnl.neuro.cka", "linear CKA (default)"),
    "rsa": ("vnl.neuro.rsa", "Spearman of scipy RDMs (--distance)"),
    "rdm": (
        "vnl.neuro.rdm",
        "rsatoolbox's RDMs (--distance: correlation, euclidean, ...) compared with --rdm-comparison",
    ),
    "dsa": (
        "vnl.neuro.dsa",
        "Dynamical Similarity Analysis of each layer's time series (an angular distance: 0 for the same dynamics)",
    ),
}


@dataclasses.dataclass(frozen=True)
class Options:
    """Every method's options (the CLI's flags); a method reads the ones it uses.

    analyze: `layer` (None: the method's default), `color` (pca), `target` (decoding), `features`
    (encoding and states; None: `vnl.recording.behaviour.default_features`, the pose for states),
    `states` and `segmentation` (states), `control`, `folds`, `repeats` (decoding's control fits),
    `seed`.
    compare: `distance` (rsa, rdm), `comparison` (rdm), `delays` and `rank` (dsa), `max_samples`
    (rsa, rdm), `trials` (dsa: the compared steps are this many trials of equal length; set by
    `vnl.compare`).
    """

    layer: str | None = None
    color: str | None = None
    target: str = "forward_speed"
    features: tuple[str, ...] | None = None
    states: int = 4
    segmentation: str = "hmm"
    control: str = "shift"
    folds: int = 5
    repeats: int = 5
    seed: int = 0
    distance: str = "correlation"
    comparison: str = "cosine"
    delays: int = 10
    rank: int = 20
    max_samples: int = 2000
    trials: int = 1


def _load(table: dict[str, tuple[str, str]], name: str, what: str) -> ModuleType:
    if name not in table:
        raise VnlError(f"unknown {what} {name!r}; choose one of {', '.join(table)}")
    return importlib.import_module(table[name][0])


def analysis(name: str) -> ModuleType:
    """The module of the analysis `name` (`ANALYSES`)."""
    return _load(ANALYSES, name, "analysis method")


def measure(name: str) -> ModuleType:
    """The module of the similarity measure `name` (`MEASURES`)."""
    return _load(MEASURES, name, "similarity measure")


def finite(value: Any) -> Any:
    """`value` with every NaN or infinity (in nested dicts and lists) replaced by None: JSON has no
    NaN, and a number that could not be estimated is null."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


def json_text(doc: dict[str, Any]) -> str:
    """A result's JSON document as text: strict JSON (`finite`), indented."""
    return json.dumps(finite(doc), indent=1, allow_nan=False)
