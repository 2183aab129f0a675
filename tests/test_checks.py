"""vnl.cli.checks: the outputs of `record`, `analyze`, `compare` and `view` are checked before any
work, a symbolic link as what the write would replace; inputs such as `.` are one line."""

import os

import pytest
from fsutil import read_only  # tests/fsutil.py
from recordings import synthetic  # tests/recordings.py

from vnl.cli import main


@pytest.fixture
def tree(tmp_path):
    """A recording, a run directory (a config, no checkpoint) and links of every kind."""
    synthetic().to_netcdf(tmp_path / "rec.nc", engine="h5netcdf")
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.yaml").write_text("env: ant_run\n")
    (tmp_path / "ro").mkdir()
    (tmp_path / "ro" / "old.png").write_bytes(b"old")
    for name, target in {
        "dangling.png": "missing_dir/x.png",
        "dangling.rrd": "nowhere.rrd",
        "dangling.nwb": "nowhere.nwb",
        "loop.png": "loop.png",
        "to_json.png": "data.json",
        "to_ro.png": "ro/old.png",
    }.items():
        (tmp_path / name).symlink_to(target)
    (tmp_path / "data.json").write_text("{}")
    return tmp_path


def outputs(t):
    """(argv, words in the error) of each command given each bad link as its output."""
    rec, run = str(t / "rec.nc"), str(t / "run")
    return [
        (["analyze", rec, "--out", str(t / "dangling.png")], "is a symbolic link (to nothing"),
        (["analyze", rec, "--method", "decoding", "--out", str(t / "loop.png")], "is a symbolic link (to nothing"),
        (["analyze", rec, "--out", str(t / "to_json.png")], "is a symbolic link (to "),
        (["view", rec, "--out", str(t / "dangling.rrd")], "is a symbolic link (to nothing"),
        (["record", "--from", rec, "--out", str(t / "dangling.nwb")], "is a symbolic link (to nothing"),
        (["compare", rec, run, "--out", str(t / "dangling.png")], "is a symbolic link (to nothing"),
    ]


def test_an_output_that_is_a_link_to_nothing_is_refused_before_any_work(tree, capsys):
    """Before: the checks passed, the analysis ran, then writing through the link failed (exit 1)."""
    before = sorted(os.listdir(tree))
    for argv, words in outputs(tree):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("vnl: error:") and err.count("\n") == 1 and words in err, (argv, err)
    assert sorted(os.listdir(tree)) == before and os.readlink(tree / "dangling.png") == "missing_dir/x.png"


def test_an_out_that_is_a_link_is_refused_and_what_it_points_to_is_left_alone(tree, capsys):
    """vnl never writes through a link (docs/developers/faults.md#links): an `--out` that is one is
    refused, here one into a read-only folder, whose file stays as it was."""
    with read_only(tree / "ro"):
        assert main(["analyze", str(tree / "rec.nc"), "--out", str(tree / "to_ro.png")]) == 2
    assert "is a symbolic link (to " in capsys.readouterr().err
    assert (tree / "ro" / "old.png").read_bytes() == b"old"


@pytest.mark.parametrize("path", [".", "..", "/"])
def test_a_directory_given_as_a_recording_or_a_network_is_one_line(tree, monkeypatch, capsys, path):
    monkeypatch.chdir(tree / "ro")
    for argv in (
        ["analyze", path],
        ["view", path],
        ["record", "--from", path],
        ["compare", path, path],
        ["compare", str(tree / "run"), str(tree / "run"), "--recording", path],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("vnl: error:") and err.count("\n") == 1, (argv, err)
