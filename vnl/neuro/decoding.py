"""Decoding: how well a layer's population tells a behavioural variable (`vnl analyze REC --method
decoding`).

A ridge regression from a layer's units to the target (forward speed, a joint angle, gait phase
as its cosine and sine, the distance to the next gap, any per-step variable:
`vnl.recording.behaviour.target`), fitted on some episodes and scored on the others (`GroupKFold` by
episode): the held-out R² (averaged over the target's columns). The control repeats the fit with
the target moved in time against the activity (`shift` or `shuffle`) `repeats` times: its mean and
standard deviation are the chance level to read the real R² against.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.neuro import crossval as cv
from vnl.neuro.registry import Options
from vnl.recording import behaviour, model


@dataclasses.dataclass
class Decoding:
    """Held-out R² of `target` from `layer`, the control's R² per repeat, and the held-out
    predictions (`truth`, `prediction` (n, k), with each sample's `episode` and `time` index)."""

    layer: str
    target: str
    r2: float
    control_r2: np.ndarray
    control: str
    folds: int
    truth: np.ndarray
    prediction: np.ndarray
    episode: np.ndarray
    time: np.ndarray
    units: int
    source: str

    def to_json(self) -> dict[str, Any]:
        return {
            "analysis": "decoding",
            "model": "ridge regression from the layer's standardised units, penalty chosen on the training episodes",
            "cross_validation": f"GroupKFold by episode, {self.folds} folds",
            "layer": self.layer,
            "units": self.units,
            "target": self.target,
            "r2": self.r2,  # finite: `decode` refuses a target it cannot score
            "control": self.control,
            "control_r2_mean": float(np.mean(self.control_r2)),
            "control_r2_std": float(np.std(self.control_r2)),
            "control_r2": [float(v) for v in self.control_r2],
            "samples": int(len(self.episode)),
            "episodes": int(len(np.unique(self.episode))),
            "recording": self.source,
        }


def _score(truth: np.ndarray, pred: np.ndarray) -> float:
    """R² averaged over the target's non-constant columns."""
    values = cv.r2(truth, pred)
    return float(np.nanmean(values)) if np.isfinite(values).any() else float("nan")


def decode(
    ds: Any,
    layer: str | None = None,
    target: str = "forward_speed",
    n_folds: int = 5,
    control: str = "shift",
    repeats: int = 5,
    seed: int = 0,
) -> Decoding:
    """Decodes `target` from `layer` (default: the policy's last hidden layer; a lab's `units`) of
    the recording."""
    layer = layer or model.default_layer(ds)
    model.check_layer(ds, layer)
    cv.check_control(control)
    y, labels = behaviour.target(ds, target)
    s = cv.samples(ds, model.activity(ds, layer), y, [], labels)
    k = cv.folds(s, n_folds)
    cv.check_target(s, target)
    pred = cv.ridge_predict(s.x, s.y, s.episode, k)
    rng = np.random.default_rng(seed)
    ctrl = []
    for _ in range(max(1, repeats)):
        order = cv.control(s, control, rng)
        ctrl.append(_score(s.y[order], cv.ridge_predict(s.x, s.y[order], s.episode, k)))
    return Decoding(
        layer,
        target,
        _score(s.y, pred),
        np.asarray(ctrl),
        control,
        k,
        s.y,
        pred,
        s.episode,
        s.time,
        int(s.x.shape[1]),
        model.description(ds),
    )


def analyze(ds: Any, options: Options) -> Decoding:
    """`decode` with the CLI's options (`vnl analyze --method decoding`)."""
    return decode(ds, options.layer, options.target, options.folds, options.control, options.repeats, options.seed)


def output_name(options: Options, ds: Any = None) -> str:
    """decoding_<target>, its characters other than letters, digits, `.`, `_` and `-` written `_`
    (`joint:hip` -> decoding_joint_hip, `snout[x]` -> decoding_snout_x)."""
    return "decoding_" + re.sub(r"[^A-Za-z0-9._-]+", "_", options.target).strip("_")


def report(result: Decoding) -> str:
    doc = result.to_json()
    return (
        f"{result.target} from {result.layer}: held-out R² {result.r2:.3f}; control ({result.control}) "
        f"{doc['control_r2_mean']:.3f} ± {doc['control_r2_std']:.3f}"
    )


def figure(result: Decoding, out: str | Path, dt: float = 1.0) -> Path:
    """Left: the target and its held-out prediction over one held-out episode (the longest);
    right: the R² beside the control's (mean ± std over repeats)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.2))
    ax, bx = fig.subplots(1, 2, gridspec_kw={"width_ratios": [3, 1]})
    episodes, counts = np.unique(result.episode, return_counts=True)
    e = episodes[np.argmax(counts)]
    sel = result.episode == e
    t = result.time[sel] * dt
    ax.plot(t, result.truth[sel, 0], color="k", lw=1.2, label=f"{result.target} (recorded)")
    ax.plot(t, result.prediction[sel, 0], color="C0", lw=1.0, label="decoded (held-out episode)")
    ax.set_xlabel("time (s)" if dt != 1.0 else "step")
    ax.set_ylabel(result.target if result.truth.shape[1] == 1 else f"{result.target}: first component")
    ax.set_title(f"episode {e}: {result.target} from {result.layer} ({result.units} units)", fontsize=9)
    ax.legend(fontsize=8)
    bx.bar(
        [0, 1],
        [result.r2, float(np.mean(result.control_r2))],
        yerr=[0, float(np.std(result.control_r2))],
        color=["C0", "0.6"],
        capsize=4,
    )
    bx.set_xticks([0, 1], [result.layer, f"control\n({result.control})"], fontsize=8)
    bx.axhline(0, color="k", lw=0.6)
    bx.set_ylabel(f"held-out R² ({result.folds}-fold by episode)")
    for x, v in ((0, result.r2), (1, float(np.mean(result.control_r2)))):
        bx.text(x, max(v, 0) + 0.02, f"{v:.2f}", ha="center", fontsize=8)
    bx.set_ylim(min(-0.1, float(np.min(result.control_r2)) - 0.1), 1.05)
    fig.suptitle(result.source, fontsize=10)
    fig.tight_layout()
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return out
