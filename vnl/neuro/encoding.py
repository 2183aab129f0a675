"""Encoding models: how well behaviour predicts each unit (`vnl analyze REC --method encoding`).

For every layer, a ridge regression from the behaviour features (joint angles and velocities,
centre-of-mass velocity, forward speed, foot contacts: `vnl.recording.behaviour.ENCODING_FEATURES`;
for an NWB file, every behaviour variable it holds) to each unit's activity, fitted on some
episodes and scored on the others (`GroupKFold` by episode): the held-out R² of each unit. The
control fits and scores the same model on the features moved in time against the activity
(`shift` or `shuffle`, `vnl.neuro.crossval.control`): what R² a model reaches on features that
carry the same statistics but no alignment with the network. Each unit's tuning is the same
model fitted on every episode: its weights, the unit's activity per unit of each feature
(`crossval.ridge_weights`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.neuro import crossval as cv
from vnl.neuro.registry import Options
from vnl.recording import behaviour, model


@dataclasses.dataclass
class Encoding:
    """Held-out R² per unit of each layer: `r2[layer]` (units,), `control_r2[layer]` (units,)
    (NaN for a constant unit), each unit's tuning `weights[layer]` (units, features: its activity
    per unit of each feature, fitted on every episode), with what was fitted."""

    features: list[str]
    r2: dict[str, np.ndarray]
    control_r2: dict[str, np.ndarray]
    control: str
    folds: int
    samples: int
    episodes: int
    source: str
    weights: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def summary(self, layer: str) -> dict[str, Any]:
        """Median and 90th percentile of the layer's R² (and of its control), units scored."""
        out: dict[str, Any] = {"units": int(len(self.r2[layer]))}
        for key, values in (("r2", self.r2[layer]), ("control_r2", self.control_r2[layer])):
            ok = values[np.isfinite(values)]
            out[f"{key}_median"] = float(np.median(ok)) if len(ok) else None
            out[f"{key}_p90"] = float(np.percentile(ok, 90)) if len(ok) else None
        out["units_scored"] = int(np.isfinite(self.r2[layer]).sum())
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "analysis": "encoding",
            "model": "ridge regression from standardised behaviour features to each unit "
            "(penalty per unit chosen on the training episodes)",
            "cross_validation": f"GroupKFold by episode, {self.folds} folds",
            "control": self.control,
            "features": self.features,
            "samples": self.samples,
            "episodes": self.episodes,
            "recording": self.source,
            "layers": {
                layer: {
                    **self.summary(layer),
                    "r2": [_finite(v) for v in self.r2[layer]],
                    "control_r2": [_finite(v) for v in self.control_r2[layer]],
                    "weights": [[_short(v) for v in row] for row in self.weights.get(layer, [])],
                }
                for layer in self.r2
            },
        }


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _short(v: float) -> float | None:
    """A weight with 4 significant digits (a layer's weights are units x features numbers)."""
    return float(f"{v:.4g}") if np.isfinite(v) else None


def encode_arrays(
    x: np.ndarray, y: np.ndarray, episode: np.ndarray, n_folds: int = 5, control: str = "shift", seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Held-out R² per column of `y` (n, units) predicted from `x` (n, features), folds by
    `episode` (n,), and the same under the control. Returns (r2 (units,), control r2 (units,))."""
    s = cv.Samples(x, y, episode, np.zeros_like(episode), [], [])
    k = cv.folds(s, n_folds)
    real = cv.r2(y, cv.ridge_predict(x, y, episode, k))
    order = cv.control(s, control, np.random.default_rng(seed))
    ctrl = cv.r2(y, cv.ridge_predict(x[order], y, episode, k))
    return real, ctrl


def encode(
    ds: Any,
    layers: list[str] | None = None,
    features: list[str] | None = None,
    n_folds: int = 5,
    control: str = "shift",
    seed: int = 0,
) -> Encoding:
    """Encoding models of `layers` (default: every layer) from `features` (default:
    `vnl.recording.behaviour.default_features`: `ENCODING_FEATURES`, or an NWB file's behaviour
    variables) on the recording `ds`."""
    layers = layers or model.layers(ds)
    for layer in layers:
        model.check_layer(ds, layer)
    cv.check_control(control)
    x, labels = behaviour.features(ds, features or behaviour.default_features(ds))
    per_layer = {layer: cv.samples(ds, x, model.activity(ds, layer), labels, []) for layer in layers}
    if not any(cv.varies(s.y).any() for s in per_layer.values() if len(s.y)):
        raise VnlError(
            f"every unit of {', '.join(layers)} is constant over the usable steps: no encoding model can be "
            "scored; choose other layers (--layer) or record episodes in which the network's activity changes"
        )
    r2, ctrl, weights = {}, {}, {}
    n = episodes = 0
    for layer, s in per_layer.items():
        r2[layer], ctrl[layer] = encode_arrays(s.x, s.y, s.episode, n_folds, control, seed)
        n, episodes = len(s.episode), len(np.unique(s.episode))
        weights[layer] = cv.ridge_weights(s.x, s.y, s.episode, min(n_folds, episodes))
    k = min(n_folds, episodes)
    return Encoding(labels, r2, ctrl, control, k, n, episodes, model.description(ds), weights)


def analyze(ds: Any, options: Options) -> Encoding:
    """`encode` with the CLI's options (`vnl analyze --method encoding`)."""
    layers = [options.layer] if options.layer else None
    features = list(options.features) if options.features else None
    return encode(ds, layers, features, options.folds, options.control, options.seed)


def output_name(options: Options, ds: Any = None) -> str:
    return "encoding"


def report(result: Encoding) -> str:
    lines = []
    for layer in result.r2:
        s = result.summary(layer)
        lines.append(
            f"{layer:>16}: median held-out R² {_f(s['r2_median'])} (control {_f(s['control_r2_median'])}), "
            f"90th percentile {_f(s['r2_p90'])}, {s['units_scored']} units"
        )
    return "\n".join(lines)


def _f(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def figure(result: Encoding, out: str | Path, dt: float = 1.0) -> Path:
    """Per layer, the distribution of held-out R² over units (box and points) beside the
    control's (`dt` unused: nothing is drawn over time)."""
    from matplotlib.figure import Figure

    names = list(result.r2)
    fig = Figure(figsize=(max(6.0, 1.3 * len(names) + 2), 4.4))
    ax = fig.subplots()
    for i, layer in enumerate(names):
        for dx, values, color in ((-0.18, result.r2[layer], "C0"), (0.18, result.control_r2[layer], "0.6")):
            ok = values[np.isfinite(values)]
            if not len(ok):
                continue
            ax.boxplot(
                [ok],
                positions=[i + dx],
                widths=0.3,
                showfliers=False,
                patch_artist=True,
                boxprops={"facecolor": color, "alpha": 0.5},
                medianprops={"color": "k"},
            )
            jitter = np.random.default_rng(i).uniform(-0.08, 0.08, len(ok))
            ax.scatter(i + dx + jitter, ok, s=5, color=color, zorder=3)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("held-out R² per unit")
    ax.set_ylim(max(-1.0, ax.get_ylim()[0]), 1.02)
    ax.scatter([], [], color="C0", label="behaviour features")
    ax.scatter([], [], color="0.6", label=f"control ({result.control})")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(
        f"encoding: ridge from {len(result.features)} behaviour features, {result.folds}-fold by episode", fontsize=9
    )
    fig.suptitle(result.source, fontsize=10)
    fig.tight_layout()
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return out
