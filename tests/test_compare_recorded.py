"""vnl.compare_recorded: recordings compared on what each recorded. On matched conditions, two
populations with the same tuning in other coordinates score as the same and a population tuned to
something else does not; DSA runs on each recording's own episodes; what is not defined is refused."""

import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from recordings import lds, oscillator  # tests/recordings.py
from scipy.stats import ortho_group

from vnl import compare, compare_recorded
from vnl.errors import VnlError
from vnl.neuro import registry


def tuned(seed, variable, offset=0.0, episodes=6, steps=200, units=10, rotate=False, other=False, dt=0.02):
    """A recording whose layer's units are a fixed nonlinear tuning to `variable` (uniform in
    [offset, offset + 1]), read out in random coordinates (`rotate`: an orthogonal turn of the same
    readout), or tuned to an unrelated variable (`other`)."""
    rng = np.random.default_rng(seed)
    v = offset + rng.uniform(0, 1, (episodes, steps))
    drive = rng.uniform(0, 1, (episodes, steps)) if other else v
    basis = np.stack([drive, drive**2, np.sin(4 * drive), np.cos(3 * drive)], axis=-1)
    readout = np.random.default_rng(99).normal(size=(4, units))  # the same readout in every recording
    act = basis @ readout
    if rotate:
        act = act @ ortho_group.rvs(units, random_state=seed)
    act = act + 0.05 * rng.normal(size=act.shape)
    et = ("episode", "time")
    return xr.Dataset(
        {
            "active": (et, np.ones((episodes, steps), np.int8)),
            variable: (et, v, {"units": "m/s"}),
            "pose": (et + ("xy",), rng.normal(size=(episodes, steps, 2))),
            "units": (et + ("units_unit",), act),
        },
        coords={"time": np.arange(steps) * dt, "xy": ["x", "y"]},
        attrs={"control_dt": dt},
    )


def rec(name, ds):
    return compare_recorded.Recorded(name, Path(name), ds)


def test_the_same_tuning_in_other_coordinates_matches_and_another_tuning_does_not():
    a = rec("a", tuned(0, "speed"))
    b = rec("b", tuned(1, "forward_speed", offset=0.5, rotate=True))
    c = rec("c", tuned(2, "forward_speed", offset=0.5, other=True))
    options = registry.Options()
    result = compare_recorded.on_conditions([a, b, c], ["speed", "forward_speed", "forward_speed"], 10, "cka", options)
    same, other = result.pairs[(0, 1)][0, 0], result.pairs[(0, 2)][0, 0]
    assert same > 0.95 and other < 0.6, (same, other)
    edges = np.array(result.details["conditions"]["edges"])
    assert 0.5 < edges[0] < 0.52 and 0.98 < edges[-1] < 1.0  # the range all three cover
    assert "10 conditions of speed / forward_speed" in compare.table(result) and "m/s" in result.source
    doc = json.loads(registry.json_text(result.to_json()))
    assert doc["conditions"]["variables"] == {"a": "speed", "b": "forward_speed", "c": "forward_speed"}
    assert min(min(v) for v in doc["conditions"]["steps"].values()) >= compare_recorded.MIN_STEPS
    euclidean = registry.Options(distance="euclidean")  # the correlation distance is not rotation-invariant
    rsa = compare_recorded.on_conditions([a, b, c], ["speed", "forward_speed", "forward_speed"], 10, "rsa", euclidean)
    assert rsa.pairs[(0, 1)][0, 0] > 0.9 > rsa.pairs[(0, 2)][0, 0]


def test_conditions_that_are_not_defined_are_refused():
    a = rec("a", tuned(0, "speed"))
    far = rec("far", tuned(1, "speed", offset=5.0))
    options = registry.Options()
    with pytest.raises(VnlError, match="do not overlap .*same quantity, in the same unit"):
        compare_recorded.on_conditions([a, far], ["speed"], 10, "cka", options)
    with pytest.raises(VnlError, match=r"pose has 2 columns .*--conditions NAME\[column\], e.g. pose\[x\]"):
        compare_recorded.on_conditions([a, a], ["pose"], 10, "cka", options)
    with pytest.raises(VnlError, match=r"a: no target 'nope' .* choose one with --conditions"):
        compare_recorded.on_conditions([a, a], ["nope"], 10, "cka", options)
    short = rec("short", tuned(0, "speed", episodes=2, steps=20))
    with pytest.raises(VnlError, match=r"only [0-3] of 20 conditions .* fewer --condition-bins"):
        compare_recorded.on_conditions([short, short], ["speed"], 20, "cka", options)
    with pytest.raises(VnlError, match="names 2 variables for 3 recordings"):
        compare_recorded.on_conditions([a, a, a], ["speed", "speed"], 10, "cka", options)
    assert compare_recorded.on_conditions([a, a], ["pose[x]"], 5, "cka", options).pairs[(0, 1)].shape == (1, 1)


def dynamic(seed, a, trials, steps, dt=0.02):
    rng = np.random.default_rng(seed)
    x = lds(a, rng, trials=trials, steps=steps, units=8)
    et = ("episode", "time")
    return xr.Dataset(
        {"active": (et, np.ones((trials, steps), np.int8)), "units": (et + ("u",), x)},
        coords={"time": np.arange(steps) * dt},
        attrs={"control_dt": dt},
    )


def test_dynamics_compare_each_recordings_own_episodes_and_refuse_other_step_lengths():
    rng = np.random.default_rng(3)
    x = dynamic(0, oscillator(rng, d=4), trials=3, steps=120)
    x["active"][1, 100:] = 0  # the trials are cut to the shortest episode: 100 steps
    turned = x.copy()
    turned["units"] = (("episode", "time", "u"), x["units"].values @ ortho_group.rvs(8, random_state=4))
    other = dynamic(1, oscillator(rng, d=4), trials=5, steps=80)
    options = registry.Options(delays=3, rank=6)
    result = compare_recorded.dynamics([rec("x", x), rec("xr", turned), rec("z", other)], options)
    assert result.pairs[(0, 1)][0, 0] < 0.05 < result.pairs[(0, 2)][0, 0]  # the same dynamics, rotated units
    assert "x 3 x 100; xr 3 x 100; z 5 x 80 steps of 0.02 s" in result.source and result.samples == 1000
    also = other
    slower = other.assign_attrs(control_dt=0.04)
    with pytest.raises(VnlError, match=r"control steps differ \(x: 0.02 s, y: 0.04 s\)$"):
        compare_recorded.dynamics([rec("x", x), rec("y", slower)], options)
    lab = x.assign_attrs(nwb_file="lab.nwb")  # an NWB file is read on the other's steps
    with pytest.raises(VnlError, match=r"steps differ \(x: 0.02 s, y: 0.04 s\); read the NWB files with --bin 0.04"):
        compare_recorded.dynamics([rec("x", lab), rec("y", slower)], options)
    with pytest.raises(VnlError, match="cannot determine a rank-400 operator"):
        compare_recorded.dynamics([rec("x", x), rec("y", also)], registry.Options(delays=3, rank=400))
