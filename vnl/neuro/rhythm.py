"""Rhythmic units: which units oscillate with the gait (`vnl analyze REC --method rhythm`).

Merel et al. 2020 found units of the virtual rodent's network whose activity follows the stride.
This method asks it of every layer, two ways, each against a control:

- **Spectrum.** The gait frequency is the peak of the feet's contact spectrum (Welch's power
  spectral density of each foot's 0/1 contact, averaged over feet and episodes, between 0.5 Hz and
  a quarter of the sampling rate); the same index as the units' (below) says how clear that peak
  is (`gait_peak_index`: a walker without a gait has none near 1). For each unit, its *spectral
  index* is its power density in the band of +-`BAND` Hz around the gait frequency over what a
  power law fitted to the rest of its spectrum predicts there: the unit's own spectrum is the
  control, and a smooth spectrum, 1/f included, scores about 1.
- **Phase locking.** A ridge model predicts each unit from the cosine and sine of the gait phase
  (`vnl.recording.behaviour`), fitted on some episodes and scored on others (held-out R²); the
  control scores it on the phase moved in time against the activity (`--control`, default shift:
  each signal keeps its own rhythm, their alignment is broken).

A unit is *rhythmic* when its spectral index is at least `RHYTHMIC_INDEX` and its phase-locking
R² is positive and exceeds the 95th percentile of the layer's control R². Its preferred phase is where its
fitted cosine-sine tuning peaks (0 = touchdown of the reference foot).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.neuro import crossval as cv
from vnl.neuro import encoding
from vnl.neuro.registry import Options
from vnl.recording import behaviour, model, stack

BAND = 0.5
"""Half-width (Hz) of the band around the gait frequency."""
RHYTHMIC_INDEX = 2.0
"""A rhythmic unit's least spectral index: twice its usual density at the gait frequency."""
MIN_FREQUENCY = 0.5


@dataclasses.dataclass
class Rhythm:
    """`gait_peak_index`: the feet's contact spectrum's index at the gait frequency. Per layer:
    `index[layer]` (units,) spectral index, `r2`/`control_r2[layer]` (units,)
    phase-locking held-out R², `phase[layer]` (units,) preferred phase in cycles [0, 1); the
    gait frequency (Hz) and the feet's mean spectrum `frequencies`, `contact_psd` (f,)."""

    gait_frequency: float
    gait_peak_index: float
    frequencies: np.ndarray
    contact_psd: np.ndarray
    index: dict[str, np.ndarray]
    r2: dict[str, np.ndarray]
    control_r2: dict[str, np.ndarray]
    phase: dict[str, np.ndarray]
    control: str
    folds: int
    source: str

    def rhythmic(self, layer: str) -> np.ndarray:
        """Which units (units,) are rhythmic (see the module docstring)."""
        ctrl = self.control_r2[layer][np.isfinite(self.control_r2[layer])]
        bar = float(np.percentile(ctrl, 95)) if len(ctrl) else np.inf
        with np.errstate(invalid="ignore"):
            return (self.index[layer] >= RHYTHMIC_INDEX) & (self.r2[layer] > max(bar, 0.0))

    def to_json(self) -> dict[str, Any]:
        def listed(v: np.ndarray) -> list[float | None]:
            return [float(f"{x:.4g}") if np.isfinite(x) else None for x in v]

        layers = {}
        for layer in self.index:
            keep = self.rhythmic(layer)
            layers[layer] = {
                "units": int(len(keep)),
                "rhythmic_units": int(keep.sum()),
                "rhythmic_fraction": float(keep.mean()) if len(keep) else None,
                "spectral_index_median": float(np.nanmedian(self.index[layer])),
                "r2_median": _median(self.r2[layer]),
                "control_r2_median": _median(self.control_r2[layer]),
                "spectral_index": listed(self.index[layer]),
                "r2": listed(self.r2[layer]),
                "control_r2": listed(self.control_r2[layer]),
                "preferred_phase": listed(self.phase[layer]),
            }
        return {
            "analysis": "rhythm",
            "gait_frequency_hz": self.gait_frequency,
            "gait_peak_index": self.gait_peak_index,
            "band_hz": BAND,
            "rhythmic_index": RHYTHMIC_INDEX,
            "phase_locking": f"ridge from cos/sin of gait_phase, GroupKFold by episode, {self.folds} folds",
            "control": self.control,
            "recording": self.source,
            "layers": layers,
        }


def _median(v: np.ndarray) -> float | None:
    ok = v[np.isfinite(v)]
    return float(np.median(ok)) if len(ok) else None


def spectra(x: np.ndarray, active: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Welch's power spectral density of `x` (episode, time, k), over each episode's active
    steps, averaged over episodes weighted by their length: (frequencies (f,), psd (f, k)).
    Segments are the median length of the episodes of 16 steps or more, at most 256 steps; shorter
    episodes are left out."""
    from scipy.signal import welch

    lengths = [int(a.sum()) for a in active]
    if max(lengths) < 16:
        raise VnlError("no episode has 16 active steps: a spectrum needs longer episodes (`vnl record --steps`)")
    # Segments as long as the median episode allows: one short episode (a fall) must not coarsen the
    # spectrum of all; episodes shorter than a segment are left out.
    nperseg = min(256, int(np.median([n for n in lengths if n >= 16])))
    usable = [e for e, n in enumerate(lengths) if n >= nperseg]
    total, weight = 0.0, 0
    freqs = np.zeros(0)
    for e in usable:
        seg = x[e, active[e]]
        seg = np.where(np.isfinite(seg), seg, np.nanmean(seg, axis=0))
        freqs, p = welch(seg, fs=fs, nperseg=nperseg, axis=0, detrend="constant")
        total, weight = total + p * lengths[e], weight + lengths[e]
    return freqs, total / weight


def gait_frequency(ds: Any, fs: float) -> tuple[float, np.ndarray, np.ndarray]:
    """(the gait frequency (Hz), frequencies (f,), the feet's mean contact psd (f,))."""
    if "foot_contact" not in ds:
        raise VnlError("the recording has no foot_contact: record it again with this vnl (a walker's recording)")
    active = np.asarray(ds["active"].values) > 0
    contact = np.asarray(ds["foot_contact"].values, np.float64)
    freqs, psd = spectra(contact, active, fs)
    mean = psd.mean(axis=1)
    band = (freqs >= MIN_FREQUENCY) & (freqs <= fs / 4)
    if not band.any() or not mean[band].max() > 0:
        raise VnlError(
            "the feet's contacts do not change over the recorded steps: no gait to find; record a walker "
            "that moves (a trained run), with longer episodes"
        )
    return float(freqs[band][np.argmax(mean[band])]), freqs, mean


def spectral_index(freqs: np.ndarray, psd: np.ndarray, f0: float, fs: float) -> np.ndarray:
    """Per column of `psd` (f, units): mean density within +-BAND of `f0` over what a power law
    fitted to the rest of [MIN_FREQUENCY, fs/2] (a line in log-log, least squares, as FOOOF's
    aperiodic fit) predicts there; NaN for a unit with no power. A smooth spectrum, 1/f-like
    included, scores about 1 at any frequency: only a peak at the gait frequency scores high."""
    analysed = (freqs >= MIN_FREQUENCY) & (freqs > 0)
    distance = np.abs(freqs - f0)
    near = analysed & (distance <= BAND)
    if not near.any():
        near = analysed & (distance == distance[analysed].min())
    rest = analysed & ~near
    if rest.sum() < 3:
        raise VnlError(
            "the spectrum has too few frequencies beside the gait's: record longer episodes (`vnl record --steps`)"
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        logp = np.log10(np.maximum(psd, 1e-30))
        design = np.stack([np.ones(rest.sum()), np.log10(freqs[rest])], axis=1)
        coef, *_ = np.linalg.lstsq(design, logp[rest], rcond=None)  # (2, units)
        fitted = 10 ** (coef[0] + np.log10(freqs[near])[:, None] * coef[1])
        index = psd[near].mean(0) / fitted.mean(0)
    return np.where(psd[analysed].max(0) > 1e-30, index, np.nan)


def analyze(ds: Any, options: Options) -> Rhythm:
    """The rhythm of `options.layer` (default: every layer) against the gait of the recording."""
    if stack.tasks(ds):
        raise VnlError(
            f"the recording holds several tasks ({', '.join(stack.tasks(ds))}), each with its own gait: analyse "
            "one task's episodes (`vnl analyze REC --method rhythm --task NAME`, `vnl.recording.stack.select`)"
        )
    layers = [options.layer] if options.layer else model.layers(ds)
    for layer in layers:
        model.check_layer(ds, layer)
    fs = 1.0 / float(ds.attrs.get("control_dt", np.diff(ds["time"].values[:2])[0]))
    f0, freqs, contact = gait_frequency(ds, fs)
    peak = float(spectral_index(freqs, contact[:, None], f0, fs)[0])
    x, labels = behaviour.features(ds, ["gait_phase"])
    active = np.asarray(ds["active"].values) > 0
    index, r2, ctrl, phase = {}, {}, {}, {}
    folds = 0
    for layer in layers:
        y = model.activity(ds, layer)
        f, psd = spectra(y, active, fs)
        index[layer] = spectral_index(f, psd, f0, fs)
        s = cv.samples(ds, x, y, labels, [])
        folds = cv.folds(s, options.folds)
        r2[layer], ctrl[layer] = encoding.encode_arrays(s.x, s.y, s.episode, folds, options.control, options.seed)
        w = cv.ridge_weights(s.x, s.y, s.episode, folds)  # (units, 2): cos, sin
        phase[layer] = (np.arctan2(w[:, 1], w[:, 0]) / (2 * np.pi)) % 1.0
    return Rhythm(f0, peak, freqs, contact, index, r2, ctrl, phase, options.control, folds, model.description(ds))


def output_name(options: Options, ds: Any = None) -> str:
    return f"rhythm_{options.layer}" if options.layer else "rhythm"


def report(result: Rhythm) -> str:
    """The lines `vnl analyze --method rhythm` prints: the gait frequency, each layer's rhythmic units."""
    peak = f"the feet's contact spectrum, peak index {result.gait_peak_index:.1f}"
    lines = [f"gait frequency {result.gait_frequency:.2f} Hz ({peak})"]
    if not result.gait_peak_index >= RHYTHMIC_INDEX:
        lines.append(
            "no clear gait: the feet's contacts have no spectral peak; the units are measured against a rhythm"
        )
    for layer in result.index:
        keep = result.rhythmic(layer)
        lines.append(
            f"{layer:>18}: {int(keep.sum())}/{len(keep)} rhythmic units; median spectral index "
            f"{np.nanmedian(result.index[layer]):.2f}, phase-locking R² {_f(_median(result.r2[layer]))} "
            f"(control {_f(_median(result.control_r2[layer]))})"
        )
    return "\n".join(lines)


def _f(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def figure(result: Rhythm, out: str | Path, dt: float = 1.0) -> Path:
    """The feet's spectrum with the gait frequency; per layer the spectral indices and the
    phase-locking R² beside the control; the rhythmic units' preferred phases."""
    from matplotlib.figure import Figure

    names = list(result.index)
    fig = Figure(figsize=(14, 4.2))
    ax, bx, cx, dx = fig.subplots(1, 4)
    ax.semilogy(result.frequencies[1:], result.contact_psd[1:] + 1e-12)
    ax.axvline(result.gait_frequency, color="C3", ls="--", label=f"gait {result.gait_frequency:.2f} Hz")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("feet's contact power")
    ax.legend(fontsize=8)
    for i, layer in enumerate(names):
        v = result.index[layer]
        bx.scatter(
            np.full(np.isfinite(v).sum(), i) + np.random.default_rng(i).uniform(-0.2, 0.2, np.isfinite(v).sum()),
            v[np.isfinite(v)],
            s=5,
        )
        for d, values, color in ((-0.15, result.r2[layer], "C0"), (0.15, result.control_r2[layer], "0.6")):
            ok = values[np.isfinite(values)]
            cx.scatter(i + d + np.random.default_rng(i).uniform(-0.06, 0.06, len(ok)), ok, s=5, color=color)
        keep = result.rhythmic(layer)
        if keep.any():
            dx.hist(result.phase[layer][keep], bins=12, range=(0, 1), alpha=0.5, label=layer)
    bx.axhline(RHYTHMIC_INDEX, color="C3", lw=0.8)
    bx.set_yscale("log")
    bx.set_ylabel("spectral index at the gait frequency")
    cx.axhline(0, color="k", lw=0.6)
    cx.set_ylabel("phase-locking held-out R² (grey: control)")
    for axis in (bx, cx):
        axis.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=7)
    dx.set_xlabel("preferred gait phase (cycles)")
    dx.set_ylabel("rhythmic units")
    if dx.get_legend_handles_labels()[0]:
        dx.legend(fontsize=7)
    fig.suptitle(result.source, fontsize=10)
    fig.tight_layout()
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return out
