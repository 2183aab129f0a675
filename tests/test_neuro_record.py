"""Behaviour features of real recordings (the rat in the gaps corridor, MuJoCo C physics), their
NWB export read back with pynwb and pynapple, the analyses from the CLI, and the import cost that
`vnl train` must not pay."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_viewer import untrained_run  # tests/ is on sys.path (as for tiny_env)

from vnl import record
from vnl.cli import main
from vnl.neuro import nwb

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("neuro_record")]

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def gaps(tmp_path_factory):
    """An untrained rat in the gaps corridor: 3 episodes of 80 steps, the recording and its NWB file."""
    run = untrained_run(tmp_path_factory.mktemp("neuro") / "run", "rodent_run_gaps")
    ds = record.record(run, episodes=3, steps=80, seed=0)
    path = record.write(ds, run.run_dir / "record.nc")
    out = nwb.write(ds, run.run_dir / "record.nwb", config="env: rodent_run_gaps\n", command="test")
    return run, ds, path, out


def test_behaviour_features_agree_with_the_task(gaps):
    run, ds, _, _ = gaps
    active = ds["active"].values > 0
    # The task's x_velocity (the root subtree's COM velocity after step t, in JAX) is the host
    # replay's com_velocity of the next state.
    both = active[:, 1:] & active[:, :-1]
    np.testing.assert_allclose(
        ds["com_velocity"].values[:, 1:, 0][both], ds["x_velocity"].values[:, :-1][both], rtol=1e-3, atol=1e-3
    )
    # Facing +x at spawn: the forward speed starts as the x velocity.
    np.testing.assert_allclose(ds["forward_speed"].values[:, 0], ds["com_velocity"].values[:, 0, 0], atol=0.05)
    # A foot in contact is low: its lowest body point near the platforms' top (z = 0).
    contact = ds["foot_contact"].values > 0
    assert contact.any() and (~contact).any()
    feet = [list(ds["body"].values).index(b) for b in ds["end_effector"].values]
    z = ds["body_pos"].values[:, :, feet, 2]
    assert np.median(z[contact]) < np.median(z[~contact & active[..., None]])
    # Events are the task's measures while the episode runs; a fall ends the episode.
    assert ds["event_gap_crossed"].values.sum() == ds["measure_gaps_crossed"].values[active].sum()
    falls = ds["event_fall"].values
    assert (falls.sum(1) <= 1).all() and all(
        not active[e, t + 1 :].any() for e, t in zip(*np.nonzero(falls), strict=True)
    )
    # The gap distance is measured from the episode's own corridor.
    assert np.nanmin(ds["gap_distance"].values) >= 0 and np.isfinite(ds["gap_distance"].values[active]).any()
    assert ds.attrs["walker"] == "rodent" and ds["walker_body"].values.sum() > 30
    assert ds["joint_angle"].shape[-1] == len(ds["joint"]) > 30


def test_nwb_file_passes_the_inspector_and_holds_the_recording(gaps):
    from ndx_pose import PoseEstimation  # noqa: F401 (registers the extension's classes for reading)
    from pynwb import NWBHDF5IO

    run, ds, _, path = gaps
    messages = nwb.inspect(path)
    assert not nwb.serious(messages), nwb.report(messages)
    accepted = {"check_processing_module_name", "check_experimenter_exists", "check_column_binary_capability"}
    assert {m.check_function_name for m in messages} <= accepted, nwb.report(messages)
    active = ds["active"].values > 0
    with NWBHDF5IO(str(path), "r") as io:
        f = io.read()
        assert f.subject.species == "Rattus norvegicus" and "not a living animal" in f.subject.description
        assert json.loads(f.notes)["checkpoint_step"] == 0 and "rodent_run_gaps" in json.loads(f.notes)["config"]
        pose = f.processing["behavior"]["PoseEstimation"]
        bodies = list(ds["body"].values)
        for name in ("walker/torso", "walker/foot_L"):
            series = pose.pose_estimation_series[name.replace("/", ".")]
            np.testing.assert_array_equal(series.data[:], ds["body_pos"].values[:, :, bodies.index(name)][active])
            assert series.rate == pytest.approx(1 / ds.attrs["control_dt"])
        skeleton = pose.skeleton
        assert len(skeleton.nodes) == ds["walker_body"].values.sum() and len(skeleton.edges) == len(skeleton.nodes) - 1
        layer = f.processing["network"]["policy_hidden_1"]
        np.testing.assert_array_equal(layer.data[:], ds["policy_hidden_1"].values[active])
        units = f.processing["network"]["network_units"].to_dataframe()
        assert len(units) == sum(ds.sizes[f"{k}_unit"] for k in ds.data_vars if k.startswith(("policy_", "value_")))
        episodes = f.intervals["episodes"].to_dataframe()
        assert list(episodes["episode"]) == [0, 1, 2]
        np.testing.assert_allclose(
            episodes["stop_time"] - episodes["start_time"], active.sum(1) * ds.attrs["control_dt"]
        )
        joints = f.processing["behavior"]["joint_angles"].data[:]
        np.testing.assert_allclose(joints, ds["joint_angle"].values[active], rtol=1e-6)


def test_pynapple_opens_the_file_and_computes_a_tuning_curve(gaps):
    import pynapple as nap

    _, ds, _, path = gaps
    d = nap.load_file(str(path), lazy_loading=False)
    episodes = d["episodes"]
    assert len(episodes) == 3
    activity = d["policy_hidden_0"]
    speed = d["forward_speed"]
    assert activity.shape == (int((ds["active"].values > 0).sum()), ds.sizes["policy_hidden_0_unit"])
    tc = nap.compute_tuning_curves(
        activity[:, [0, 1]], speed, bins=8, epochs=episodes, fs=1 / ds.attrs["control_dt"], feature_names=["speed"]
    )
    assert tc.shape == (2, 8) and np.isfinite(tc.values).sum() >= 8
    # The tuning curve is the unit's mean activity in each speed bin.
    edges = tc.attrs["bin_edges"][0]
    unit0, v = activity.values[:, 0], speed.values
    inside = (v >= edges[3]) & (v < edges[4])
    assert tc.values[0, 3] == pytest.approx(unit0[inside].mean(), rel=1e-5)


def test_analyses_from_the_cli(gaps, tmp_path, capsys):
    _, _, path, _ = gaps
    for method, extra in (("encoding", []), ("decoding", ["--target", "gap_distance"]), ("states", ["--states", "3"])):
        out = tmp_path / f"{method}.png"
        assert main(["analyze", str(path), "--method", method, "--folds", "3", "--out", str(out), *extra]) == 0
        doc = json.loads(out.with_suffix(".json").read_text())
        assert out.stat().st_size > 5000 and doc["analysis"] == method and "control" in doc
    assert "held-out R²" in capsys.readouterr().out
    nwb_out = tmp_path / "converted.nwb"
    assert main(["record", "--from", str(path), "--out", str(nwb_out)]) == 0
    assert nwb_out.stat().st_size > 10_000 and "nwbinspector" in capsys.readouterr().out


HEAVY = ("pynwb", "hdmf", "ndx_pose", "nwbinspector", "pynapple", "sklearn", "rsatoolbox", "hmmlearn")


def test_vnl_train_imports_none_of_the_neuroscience_tools():
    # What `vnl train` imports: the CLI with every subcommand's parser, the train command and all
    # that training loads, an env built and stepped.
    code = (
        "import sys\n"
        "from vnl.cli import build_parser\n"
        "import vnl.cli.cmd_train, vnl.train.trainer, vnl.train.session, vnl.train.distributed\n"
        "import vnl.policy, vnl.rollout, vnl.envs.registry\n"
        "from vnl.train import config\n"
        "env = config.build('rodent_run', 'tiny', assignments=['env_config.impl=c']).make_env()\n"
        "build_parser().parse_args(['train', 'rodent_run'])\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]"
