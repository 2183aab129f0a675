"""`vnl analyze`: dispatch through the registry of analyses, its input checks (no heavy imports,
exit 2 with one line) and, on a real recording, every method from the command line."""

import json

import pytest
from recordings import synthetic  # tests/recordings.py

from vnl.cli import main


def test_analyze_rejects_mistakes_with_one_line(tmp_path, capsys):
    rec = tmp_path / "rec.nc"
    synthetic().to_netcdf(rec, engine="h5netcdf")
    cases = [
        (["analyze", str(rec), "--method", "decoding", "--target", "nope"], "no target 'nope'"),
        (["analyze", str(rec), "--method", "encoding", "--layer", "nope"], "no layer 'nope'"),
        (["analyze", str(rec), "--method", "states", "--color", "reward"], "--color colours the PCA"),
        (["analyze", str(tmp_path / "x.nwb"), "--method", "encoding"], "not found"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (argv, err)


@pytest.mark.slow
@pytest.mark.xdist_group("neuro_record")
def test_analyses_from_the_cli(rat_recording, tmp_path, capsys):
    _, _, path, _ = rat_recording
    for method, extra in (("encoding", []), ("decoding", ["--target", "gap_distance"]), ("states", ["--states", "3"])):
        out = tmp_path / f"{method}.png"
        assert main(["analyze", str(path), "--method", method, "--folds", "3", "--out", str(out), *extra]) == 0
        doc = json.loads(out.with_suffix(".json").read_text())
        assert out.stat().st_size > 5000 and doc["analysis"] == method and "control" in doc
    assert "held-out R²" in capsys.readouterr().out
    nwb_out = tmp_path / "converted.nwb"
    assert main(["record", "--from", str(path), "--out", str(nwb_out)]) == 0
    assert nwb_out.stat().st_size > 10_000 and "nwbinspector" in capsys.readouterr().out
