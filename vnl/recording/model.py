"""What a recording holds: the names every writer, reader and method of vnl uses.

A recording is an `xarray.Dataset` (`vnl.record.record` makes one) whose variables are indexed by
`episode` and `time` (the control step, in seconds): every network layer's activity
(`policy_<...>`, `value_<...>`: (episode, time, units)), the observation, the action, the reward
and its terms, the env's metrics, the body's pose (`qpos`, `qvel`, `body_pos`, `body_quat`) and the
behaviour features of `vnl.recording.behaviour`; `active` (episode, time) is 1 up to and including
the step at which the episode ended. Its attributes name the run (`run_dir`, `env`,
`checkpoint_step`, `control_dt`, `seed`, ...).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vnl.errors import VnlError

LAYER_PREFIXES = ("policy_", "value_", "encoder_", "core_", "units")
"""What a layer's name starts with: a network's (`policy_hidden_0`, ...; Merel's network's shared
`encoder_hidden_0`, `core_h`, ...) or a lab's units (`units`, `units_<series>`, read from an NWB
file by `vnl.recording.nwb_reader`)."""
STEP_DIMS = ("episode", "time")
REQUIRED = ("active", "time")


def layers(ds: Any) -> list[str]:
    """The recorded network layers (`policy_hidden_0`, ..., `value_output`), in the file's order."""
    return [v for v in ds.data_vars if v.startswith(LAYER_PREFIXES)]


def units(ds: Any, layer: str) -> int:
    """The number of units of `layer` (its last axis)."""
    return int(ds[layer].shape[-1])


def check_layer(ds: Any, layer: str) -> None:
    """`VnlError` unless `layer` is one of the recording's layers."""
    if layer not in layers(ds):
        raise VnlError(f"no layer {layer!r} in the recording; layers: {', '.join(layers(ds))}")


def last_hidden_layer(ds: Any) -> str:
    """The policy's last hidden layer (the default population to decode from): its MLP's last, or
    the state of the last of Merel's policy cores (`policy_core_<i>_h`)."""
    hidden = sorted((v for v in layers(ds) if v.startswith("policy_hidden_")), key=lambda n: int(n.rsplit("_", 1)[1]))
    if not hidden:
        cores = [v for v in layers(ds) if v.startswith("policy_core_") and v.endswith("_h") and v[12:-2].isdigit()]
        hidden = sorted(cores, key=lambda n: int(n[12:-2]))
    if not hidden:
        raise VnlError("the recording has no policy hidden layer; choose one with --layer")
    return hidden[-1]


def default_layer(ds: Any) -> str:
    """The population decoded by default: the policy's last hidden layer, else the first layer (a
    lab's `units`, read from an NWB file)."""
    if any(v.startswith(("policy_hidden_", "policy_core_")) for v in layers(ds)) or not layers(ds):
        return last_hidden_layer(ds)
    return layers(ds)[0]


def activity(ds: Any, layer: str) -> Any:
    """`layer`'s activity (episode, time, units) as a float64 numpy array."""
    import numpy as np

    check_layer(ds, layer)
    return np.asarray(ds[layer].values, np.float64)


def per_step(ds: Any) -> list[str]:
    """The variables with one value per (episode, time) step (`reward`, `x_velocity`, ...)."""
    return [v for v in ds.data_vars if ds[v].dims == STEP_DIMS]


def missing(ds: Any) -> str | None:
    """What keeps `ds` from being a vnl recording (the variables it lacks), or None."""
    absent = [v for v in REQUIRED if v not in ds.variables]
    if absent:
        return f"no {', '.join(absent)}"
    if not layers(ds):
        return "no network layers (policy_*, value_*)"
    return None


def recorded_run(ds: Any, recording: str | Path | None = None) -> Path:
    """The run directory a recording was made of: its `run_dir` attribute (absolute since vnl
    records it so); for an older recording with a relative one that does not resolve from here,
    that path relative to the recording's folder, or the recording's folder itself (`vnl record`
    writes into the run directory by default)."""
    attr = ds.attrs.get("run_dir")
    if not attr:
        raise VnlError(
            "the recording does not say which run it recorded (no run_dir attribute); is it a vnl recording?"
        )
    path = Path(str(attr))
    if path.is_dir() or path.is_absolute() or recording is None:
        return path
    here = Path(recording).parent
    for candidate in (here / path, here):
        if (candidate / "config.yaml").is_file():
            return candidate
    return path


def description(ds: Any) -> str:
    """A one-line description of the recording for figure titles and the analyses' JSON: the env
    and checkpoint of a vnl recording; an NWB file's name and what its episodes are (trials,
    epochs, or contiguous blocks when it has neither)."""
    if "env" not in ds.attrs and "nwb_file" in ds.attrs:
        return f"{Path(str(ds.attrs['nwb_file'])).name}, episodes: {ds.attrs.get('episodes', '?')}"
    return f"{ds.attrs.get('env', '?')} @ step {ds.attrs.get('checkpoint_step', '?')}"


def subsample(mask: Any, n: int) -> Any:
    """`mask` (episodes, time) keeping at most `n` of its True steps, evenly spaced."""
    import numpy as np

    total = int(mask.sum())
    if n < 1 or total <= n:
        return mask
    keep = np.zeros(total, bool)
    keep[np.linspace(0, total - 1, n).astype(int)] = True
    out = mask.copy()
    out[mask] = keep
    return out
