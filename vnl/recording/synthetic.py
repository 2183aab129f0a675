"""A synthetic lab session as an NWB file: units with a known tuning to a pose variable, so that
vnl's analyses of a lab's NWB can be checked against the truth (the tests and
docs/how-to/your-nwb.md use it; no real data ships with vnl).

`python -m vnl.recording.synthetic lab.nwb [--seed N]` writes one (another seed: another
animal, other preferred directions). The session, written with pynwb and ndx-pose the way a lab's
pipeline writes one:

- the animal's pose: ndx-pose `PoseEstimation` of two keypoints, `snout` and `tail_base` (x, y in
  metres, a 1 m arena, 50 Hz), with their `Skeleton`; the snout wanders smoothly, the body 0.1 m
  long, its heading turning slowly;
- `speed`: the snout's speed (m/s), a `TimeSeries` in a `BehavioralTimeSeries`;
- `trials`: `trials` trials of `trial_seconds` with `gap_seconds` between them (the pose is tracked
  throughout);
- the units table: `tuned` units whose rate is linear in the snout's position,
  rate = baseline + gain (cos(φ) x' + sin(φ) y'), x' and y' the position scaled to [-1, 1]
  (baseline 20 and gain 14 spikes/s: between 1 and 39, never clipped), and `untuned` units firing at a constant 10
  spikes/s; spikes drawn from an inhomogeneous Poisson process at 1 ms. Its columns
  `preferred_direction` (φ, rad), `gain` (spikes/s per unit of x' or y') and `baseline` hold the
  truth.
"""

from __future__ import annotations

import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable

RATE_HZ = 50.0
BODY_LENGTH = 0.1
ARENA = 1.0


def pose(rng: np.random.Generator, seconds: float, rate_hz: float = RATE_HZ) -> tuple[np.ndarray, np.ndarray]:
    """A smooth walk in a 1 m arena: (timestamps (n,), keypoints (n, 2, 2): snout and tail base,
    x and y in metres)."""
    n = int(round(seconds * rate_hz))
    dt = 1.0 / rate_hz
    velocity = np.zeros((n, 2))
    pos = np.zeros((n, 2))
    pos[0] = rng.uniform(0.3, 0.7, 2)
    for t in range(1, n):  # an AR(1) velocity (time constant 1 s, 0.2 m/s), reflected at the walls
        velocity[t] = velocity[t - 1] * (1 - dt) + 0.2 * np.sqrt(2 * dt) * rng.normal(size=2)
        pos[t] = pos[t - 1] + velocity[t] * dt
        for d in range(2):
            if not 0.02 <= pos[t, d] <= ARENA - 0.02:
                pos[t, d] = np.clip(pos[t, d], 0.02, ARENA - 0.02)
                velocity[t, d] *= -1
    heading = np.cumsum(rng.normal(scale=0.05, size=n))
    tail = pos - BODY_LENGTH * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    return np.arange(n) * dt, np.stack([pos, tail], axis=1)


def rates(snout: np.ndarray, direction: np.ndarray, gain: np.ndarray, baseline: np.ndarray) -> np.ndarray:
    """Each unit's rate (n, units), spikes/s, from the snout's position (n, 2) in metres."""
    scaled = (snout - ARENA / 2) / (ARENA / 2)  # x', y' in [-1, 1]
    drive = scaled[:, :1] * np.cos(direction) + scaled[:, 1:] * np.sin(direction)
    return np.maximum(baseline + gain * drive, 0.0)


def spikes(rng: np.random.Generator, t: np.ndarray, rate: np.ndarray, resolution: float = 1e-3) -> list[np.ndarray]:
    """Poisson spike times per unit from `rate` (n, units) at times `t` (linearly interpolated,
    drawn per `resolution` s)."""
    fine = np.arange(t[0], t[-1], resolution)
    out = []
    for i in range(rate.shape[1]):
        p = np.interp(fine, t, rate[:, i]) * resolution
        hit = rng.random(len(fine)) < p
        out.append(np.sort(fine[hit] + rng.random(int(hit.sum())) * resolution))
    return out


def write_session(
    path: str | Path,
    seed: int = 0,
    trials: int = 8,
    trial_seconds: float = 20.0,
    gap_seconds: float = 2.0,
    tuned: int = 24,
    untuned: int = 6,
) -> dict[str, Any]:
    """Writes the synthetic session (module docstring) to `path` (atomically). Returns the truth:
    `preferred_direction`, `gain`, `baseline` (units,), `tuned` (units,) bool, and the pose
    (`timestamps` (n,), `keypoints` (n, 2, 2))."""
    from pynwb import NWBHDF5IO

    rng = np.random.default_rng(seed)
    t, keypoints = pose(rng, trials * (trial_seconds + gap_seconds))
    units = tuned + untuned
    truth = {
        "preferred_direction": rng.uniform(-np.pi, np.pi, units),
        "gain": np.where(np.arange(units) < tuned, 14.0, 0.0),
        "baseline": np.where(np.arange(units) < tuned, 20.0, 10.0),
    }
    trains = spikes(rng, t, rates(keypoints[:, 0], truth["preferred_direction"], truth["gain"], truth["baseline"]))
    nwb = _session(seed)
    _behaviour(nwb, t, keypoints)
    for i in range(trials):
        start = i * (trial_seconds + gap_seconds)
        nwb.add_trial(start_time=start, stop_time=start + trial_seconds)
    _units(nwb, trains, truth, (0.0, float(t[-1] + 1 / RATE_HZ)))

    def writer(tmp: Path) -> None:
        with NWBHDF5IO(str(tmp), "w") as io:
            io.write(nwb)

    durable.write_atomic(Path(path), writer=writer)
    return {**truth, "tuned": truth["gain"] > 0, "timestamps": t, "keypoints": keypoints}


def _session(seed: int) -> Any:
    from pynwb import NWBFile
    from pynwb.file import Subject

    nwb = NWBFile(
        session_description="A synthetic session: a rat's pose in an open arena and units tuned to its position",
        identifier=f"vnl-synthetic-{seed}",
        session_start_time=datetime(2026, 1, 1, tzinfo=UTC),
        experimenter=["Synthetic, Data"],
        institution="Virtual Neuroscience Lab (vnl)",
        experiment_description="Generated by vnl.recording.synthetic: spikes from a known linear tuning to position",
        keywords=["synthetic", "place tuning", "pose"],
    )
    nwb.subject = Subject(
        subject_id=f"synthetic-{seed}",
        species="Rattus norvegicus",
        sex="U",
        age="P90D",
        description="A simulated subject (vnl.recording.synthetic), not a recorded animal.",
    )
    return nwb


def _behaviour(nwb: Any, t: np.ndarray, keypoints: np.ndarray) -> None:
    """The pose (ndx-pose) and the speed, in the `behavior` processing module."""
    from ndx_pose import PoseEstimation, PoseEstimationSeries, Skeleton, Skeletons
    from pynwb import TimeSeries
    from pynwb.behavior import BehavioralTimeSeries

    behavior = nwb.create_processing_module("behavior", "the animal's pose and speed")
    skeleton = Skeleton(
        name="rat", nodes=["snout", "tail_base"], edges=np.array([[0, 1]], np.uint8), subject=nwb.subject
    )
    series = [
        PoseEstimationSeries(
            name=name,
            description=f"position of the {name}",
            data=keypoints[:, i],
            unit="meters",
            reference_frame="the arena's corner, x and y along its walls",
            starting_time=0.0,
            rate=RATE_HZ,
            confidence=np.ones(len(t)),
            confidence_definition="synthetic: exact positions",
        )
        for i, name in enumerate(("snout", "tail_base"))
    ]
    behavior.add(Skeletons(skeletons=[skeleton]))
    behavior.add(
        PoseEstimation(
            name="PoseEstimation",
            pose_estimation_series=series,
            description="synthetic keypoints",
            skeleton=skeleton,
            source_software="vnl.recording.synthetic",
        )
    )
    speed = np.linalg.norm(np.gradient(keypoints[:, 0], t, axis=0), axis=1)
    timeseries = TimeSeries(
        name="speed", data=speed, unit="m/s", starting_time=0.0, rate=RATE_HZ, description="snout speed"
    )
    behavior.add(BehavioralTimeSeries(name="BehavioralTimeSeries", time_series=[timeseries]))


def _units(nwb: Any, trains: list[np.ndarray], truth: dict[str, np.ndarray], observed: tuple[float, float]) -> None:
    """The units table: spike times, when they were recorded, the truth of each unit's tuning."""
    from pynwb.misc import Units

    nwb.units = Units(name="units", description="simulated units", resolution=1e-3)
    nwb.add_unit_column("preferred_direction", "φ of the tuning, rad (truth)")
    nwb.add_unit_column("gain", "spikes/s per unit of position scaled to [-1, 1] (truth; 0: untuned)")
    nwb.add_unit_column("baseline", "spikes/s at the arena's centre (truth)")
    for i, train in enumerate(trains):
        nwb.add_unit(spike_times=train, obs_intervals=[observed], **{k: float(v[i]) for k, v in truth.items()})


def main(argv: list[str]) -> int:
    """`python -m vnl.recording.synthetic OUT.nwb [--seed N]`."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m vnl.recording.synthetic", description=__doc__.split("\n")[0])
    parser.add_argument("out", help="the NWB file to write (.nwb)")
    parser.add_argument("--seed", type=int, default=0, help="another seed, another animal (default 0)")
    args = parser.parse_args(argv)
    if not args.out.endswith(".nwb"):
        parser.error("the file name must end in .nwb")
    truth = write_session(args.out, seed=args.seed)
    print(f"wrote {args.out}: {len(truth['gain'])} units ({int(truth['tuned'].sum())} tuned to position), 8 trials")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
