"""The behavioural embedding (`vnl analyze --method embedding`, vnl.neuro.embedding) on a
recording with planted behaviours that the poses alone cannot tell apart."""

import json

import numpy as np
import pytest
import xarray as xr
from sklearn.metrics import adjusted_rand_score

from vnl.cli import main
from vnl.errors import VnlError
from vnl.neuro import embedding
from vnl.neuro.registry import Options

E, T, DT, J = 4, 600, 0.02, 6


@pytest.fixture(autouse=True)
def fewer_points(monkeypatch):
    monkeypatch.setattr(embedding, "MAX_POINTS", 400)  # t-SNE and silhouettes on 400 steps: seconds


def two_gaits(seed=0):
    """Blocks of 2-4 s alternating between a slow (2 Hz) and a fast (8 Hz) oscillation of the
    same joints with the same amplitude, and the same pose distribution; forward speed 0.2 or
    1.0 m/s with the gait. Returns (dataset, planted label (E, T))."""
    rng = np.random.default_rng(seed)
    label = np.zeros((E, T), int)
    for e in range(E):
        t, g = 0, int(rng.integers(2))
        while t < T:
            n = int(rng.integers(100, 200))
            label[e, t : t + n], t, g = g, t + n, 1 - g
    freq = np.where(label == 1, 8.0, 2.0)
    phase = 2 * np.pi * np.cumsum(freq * DT, axis=1)
    offsets = rng.uniform(0, 2 * np.pi, J)
    angle = np.sin(phase[..., None] + offsets) + 0.1 * rng.normal(size=(E, T, J))
    speed = np.where(label == 1, 1.0, 0.2) + 0.05 * rng.normal(size=(E, T))
    com = np.stack([speed, 0 * speed, 0 * speed], -1) + 0.01 * rng.normal(size=(E, T, 3))
    et = ("episode", "time")
    ds = xr.Dataset(
        {
            "active": (et, np.ones((E, T))),
            "joint_angle": (et + ("joint",), angle),
            "com_velocity": (et + ("axis",), com),
            "forward_speed": (et, speed),
            "policy_hidden_0": (et + ("policy_hidden_0_unit",), rng.normal(size=(E, T, 3))),
        },
        coords={
            "episode": np.arange(E),
            "time": np.arange(T) * DT,
            "joint": [f"j{i}" for i in range(J)],
            "axis": ["x", "y", "z"],
        },  # fmt: skip
        attrs={"env": "synthetic", "checkpoint_step": 0, "control_dt": DT},
    )
    return ds, label


def test_the_behaviours_found_are_the_planted_gaits_and_beat_the_control():
    ds, label = two_gaits()
    result = embedding.analyze(ds, Options(states=2, features=("joint_angle",)))
    found = np.zeros_like(label)
    found[result.episode, result.time] = result.labels
    assert adjusted_rand_score(label.ravel(), found.ravel()) > 0.8
    assert result.silhouette > result.control_silhouette + 0.1
    fast = max(result.behaviours(), key=lambda b: b["mean_forward_speed"])
    assert fast["mean_forward_speed"] == pytest.approx(1.0, abs=0.15) and fast["mean_dwell_s"] > 0.6
    assert result.xy.shape == (len(result.shown), 2)


def test_morlet_amplitude_peaks_at_the_signals_frequency():
    t = np.arange(500) * DT
    x = np.stack([np.sin(2 * np.pi * 3.0 * t), np.sin(2 * np.pi * 12.0 * t)], 1)
    amp = embedding.morlet_amplitude(x, 1 / DT, [3.0, 12.0]).reshape(500, 2, 2)[100:-100].mean(0)
    assert amp[0, 0] > 5 * amp[0, 1] and amp[1, 1] > 5 * amp[1, 0]
    assert amp[0, 0] == pytest.approx(0.5, rel=0.1)  # a unit-L1 wavelet: half the sine's amplitude


def test_an_episode_shorter_than_the_slowest_wavelet_keeps_its_length():
    """A 1-Hz wavelet spans about 5 s (250 steps here): an episode that ended after 60 steps (an
    animal that escaped early) has 60 rows of amplitudes, as `np.convolve(..., "same")` gives for
    longer episodes."""
    x = np.sin(np.arange(60) * DT * 2 * np.pi * 3.0)[:, None]
    amp = embedding.morlet_amplitude(x, 1 / DT, [1.0, 3.0])
    assert amp.shape == (60, 2)
    long = np.sin(np.arange(400) * DT * 2 * np.pi * 3.0)[:, None]
    w = embedding.morlet_amplitude(long, 1 / DT, [3.0])
    sd = embedding.MORLET_CYCLES / (2 * np.pi * 3.0)
    t = np.arange(-3 * sd, 3 * sd + DT, DT)
    kernel = np.exp(2j * np.pi * 3.0 * t) * np.exp(-(t**2) / (2 * sd**2))
    np.testing.assert_allclose(w[:, 0], np.abs(np.convolve(long[:, 0], kernel / np.abs(kernel).sum(), "same")))


def test_too_short_a_recording_is_refused_and_the_cli_writes_figure_and_json(tmp_path, capsys):
    ds, _ = two_gaits()
    with pytest.raises(VnlError, match="at least 50"):
        embedding.analyze(ds.isel(time=slice(0, 10)), Options(states=2))
    path = tmp_path / "rec.nc"
    ds.isel(episode=slice(0, 2), time=slice(0, 300)).to_netcdf(path)
    assert main(["analyze", str(path), "--method", "embedding", "--states", "2", "--color", "forward_speed"]) == 0
    assert "2 behaviours, silhouette" in capsys.readouterr().out
    doc = json.loads((tmp_path / "embedding.json").read_text())
    assert doc["analysis"] == "embedding" and len(doc["behaviours"]) == 2
    assert (tmp_path / "embedding.png").stat().st_size > 10_000
