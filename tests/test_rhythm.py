"""Rhythmic units (`vnl analyze --method rhythm`, vnl.neuro.rhythm) on a recording with planted
rhythms: units locked to the stride at known phases, units of noise, a unit oscillating at
another frequency."""

import json

import numpy as np
import pytest
import xarray as xr

from vnl.cli import main
from vnl.errors import VnlError
from vnl.neuro import rhythm
from vnl.neuro.registry import Options
from vnl.recording import behaviour

E, T, DT = 6, 400, 0.02
GAIT_HZ = 4.0
LOCKED = {0: 0.0, 1: 0.25, 2: 0.6}  # unit -> preferred phase (cycles)


def gait_recording(seed=0, units=6):
    """Two feet alternating at ~4 Hz (stride period jittered 10%); units 0-2 follow the stride at
    the phases of LOCKED, unit 3 oscillates at 9 Hz unrelated to it, units 4-5 are smooth noise."""
    rng = np.random.default_rng(seed)
    active = np.ones((E, T), bool)
    contact = np.zeros((E, T, 2))
    for e in range(E):
        t = 0.0
        while t < T:
            period = (1 / GAIT_HZ / DT) * rng.uniform(0.9, 1.1)
            a, half = int(t), int(t + period / 2)
            contact[e, a:half, 0], contact[e, half : int(t + period), 1] = 1, 1
            t += period
    phase = behaviour.gait_phase(contact[..., 0], active)
    y = np.zeros((E, T, units))
    for u, p in LOCKED.items():
        y[..., u] = np.cos(2 * np.pi * (phase - p))
    y[..., 3] = np.sin(2 * np.pi * 9.0 * DT * np.arange(T) + rng.uniform(0, 6, (E, 1)))
    for u in (4, 5):
        noise = np.zeros((E, T))
        for t in range(1, T):
            noise[:, t] = 0.9 * noise[:, t - 1] + rng.normal(size=E)
        y[..., u] = noise
    y = y + 0.2 * rng.normal(size=y.shape)
    ok = np.isfinite(phase)
    y[~ok] = 0.0  # before the first and after the last touchdown: no phase, activity at rest
    et = ("episode", "time")
    return xr.Dataset(
        {
            "active": (et, active.astype(float)),
            "foot_contact": (et + ("end_effector",), contact),
            "gait_phase": (et, phase),
            "policy_hidden_0": (et + ("policy_hidden_0_unit",), y),
        },
        coords={"episode": np.arange(E), "time": np.arange(T) * DT, "end_effector": ["left", "right"]},
        attrs={"env": "synthetic", "checkpoint_step": 0, "control_dt": DT},
    )


def test_rhythmic_units_are_the_planted_ones_with_their_phases():
    result = rhythm.analyze(gait_recording(), Options())
    assert result.gait_frequency == pytest.approx(GAIT_HZ, abs=0.4)
    keep = result.rhythmic("policy_hidden_0")
    assert list(np.nonzero(keep)[0]) == sorted(LOCKED)
    index = result.index["policy_hidden_0"]
    assert index[list(LOCKED)].min() > 5 and index[3] < rhythm.RHYTHMIC_INDEX  # 9 Hz: not the gait's
    for u, p in LOCKED.items():
        d = (result.phase["policy_hidden_0"][u] - p + 0.5) % 1.0 - 0.5
        assert abs(d) < 0.05, (u, result.phase["policy_hidden_0"][u])
    doc = result.to_json()["layers"]["policy_hidden_0"]
    assert doc["rhythmic_units"] == 3 and json.dumps(result.to_json(), allow_nan=False)


def test_the_control_breaks_phase_locking():
    """The shift control's R² is far below the locked units' (a control that could not fail would
    score them alike)."""
    result = rhythm.analyze(gait_recording(seed=1), Options(control="shift"))
    r2, ctrl = result.r2["policy_hidden_0"], result.control_r2["policy_hidden_0"]
    assert r2[list(LOCKED)].min() > 0.8 and np.nanmax(ctrl[list(LOCKED)]) < 0.3


def test_a_recording_without_feet_or_gait_is_refused_with_the_fix():
    ds = gait_recording()
    with pytest.raises(VnlError, match="no foot_contact"):
        rhythm.analyze(ds.drop_vars("foot_contact"), Options())
    still = ds.assign(foot_contact=ds["foot_contact"] * 0 + 1)
    with pytest.raises(VnlError, match="do not change"):
        rhythm.analyze(still, Options())


def test_vnl_analyze_method_rhythm_writes_its_figure_and_json(tmp_path, capsys):
    path = tmp_path / "rec.nc"
    gait_recording().to_netcdf(path)
    assert main(["analyze", str(path), "--method", "rhythm"]) == 0
    out = capsys.readouterr().out
    assert "gait frequency" in out and "3/6 rhythmic units" in out
    doc = json.loads((tmp_path / "rhythm.json").read_text())
    assert doc["analysis"] == "rhythm" and (tmp_path / "rhythm.png").stat().st_size > 10_000
