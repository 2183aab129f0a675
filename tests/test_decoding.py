"""vnl.neuro.decoding on recordings with a planted readout, and the targets it reads."""

import numpy as np
import pytest
from recordings import E, T, synthetic  # tests/recordings.py

from vnl.cli import main
from vnl.errors import VnlError
from vnl.neuro import decoding
from vnl.recording import behaviour, model


def test_decoding_reads_the_planted_target_against_its_control(tmp_path):
    ds = synthetic()
    result = decoding.decode(ds, "policy_hidden_1", "forward_speed", n_folds=3, repeats=3)
    assert result.r2 > 0.95
    assert np.all(result.control_r2 < 0.3)
    assert len(result.control_r2) == 3
    # Only active steps enter: episode 0 contributes T - 20.
    assert (result.episode == 0).sum() == T - 20
    # A population that does not carry it decodes nothing.
    assert decoding.decode(ds, "policy_hidden_0", "forward_speed", n_folds=3).r2 < 0.1
    assert decoding.figure(result, tmp_path / "dec.png", 0.02).stat().st_size > 5000
    assert result.to_json()["control_r2_mean"] == pytest.approx(float(np.mean(result.control_r2)))


def test_decoding_targets_and_errors():
    ds = synthetic()
    y, labels = behaviour.target(ds, "joint:j2")  # a joint by its short name
    np.testing.assert_array_equal(y[..., 0], ds["joint_angle"].values[..., 2])
    ds["gait_phase"] = (("episode", "time"), np.tile(np.arange(T) % 10 / 10, (E, 1)))
    y, labels = behaviour.target(ds, "gait_phase")
    assert labels == ["cos(gait_phase)", "sin(gait_phase)"]
    np.testing.assert_allclose(y[0, 3], [np.cos(0.6 * np.pi), np.sin(0.6 * np.pi)])
    y, labels = behaviour.target(ds, "joint_angle[walker/j3]")  # one column of a variable, by its label
    assert labels == ["joint_angle[walker/j3]"]
    np.testing.assert_array_equal(y[..., 0], ds["joint_angle"].values[..., 3])
    obs = np.random.default_rng(0).normal(size=(E, T, 2))  # labels with brackets of their own (observations')
    ds = ds.assign(observation=(("episode", "time", "observation_feature"), obs))
    ds = ds.assign_coords(observation_feature=["ref_root_pos[0]", "ref_root_pos[1]"])
    y, labels = behaviour.target(ds, "observation[ref_root_pos[1]]")
    assert labels == ["observation[ref_root_pos[1]]"]
    np.testing.assert_array_equal(y[..., 0], obs[..., 1])
    with pytest.raises(
        VnlError, match=r"no target 'nope' .* behaviour variables: joint_angle, joint_velocity, forward"
    ):
        decoding.decode(ds, "policy_hidden_0", "nope")
    for name in ("policy_hidden_0", "joint_angle[walker/j9]"):  # a layer is not a target; no such column
        with pytest.raises(VnlError, match="no target"):
            behaviour.target(ds, name)
    with pytest.raises(VnlError, match="no joint 'knee'"):
        behaviour.target(ds, "joint:knee")
    with pytest.raises(VnlError, match="no layer"):
        decoding.decode(ds, "policy_hidden_9")
    with pytest.raises(VnlError, match="at least 2 episodes"):
        decoding.decode(ds.isel(episode=[1]), "policy_hidden_1")
    assert model.last_hidden_layer(ds) == "policy_hidden_1" == model.default_layer(ds)
    lab = ds.drop_vars(["policy_hidden_0", "policy_hidden_1"]).assign(units=ds["policy_hidden_1"])
    assert model.default_layer(lab) == "units"  # a lab's units, read from an NWB file
    name = decoding.output_name(decoding.Options(target="snout[x]"))
    assert (
        name == "decoding_snout_x"
        and decoding.output_name(decoding.Options(target="joint:hip_L")) == "decoding_joint_hip_L"
    )


def test_a_constant_target_is_refused_not_scored_nan(tmp_path, capsys):
    """Before: "held-out R² nan" printed and `NaN` written into the JSON (not JSON)."""
    ds = synthetic()
    ds["reward"] = ds["reward"] * 0 + 0.5
    with pytest.raises(VnlError, match="the target reward is constant over the 880 usable steps .0.5."):
        decoding.decode(ds, "policy_hidden_1", "reward", n_folds=3)
    rec = tmp_path / "rec.nc"
    ds.to_netcdf(rec, engine="h5netcdf")
    assert main(["analyze", str(rec), "--method", "decoding", "--target", "reward"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "choose another --target" in err and not list(tmp_path.glob("*.json"))
