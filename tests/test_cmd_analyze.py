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


def test_analyze_reads_a_lab_nwb_file_and_says_what_it_read(lab_session, tmp_path, capsys):
    path, _ = lab_session
    out = tmp_path / "d.png"
    argv = ["analyze", str(path), "--method", "decoding", "--target", "snout[x]", "--bin", "0.1", "--out", str(out)]
    assert main(argv) == 0
    doc = json.loads(out.with_suffix(".json").read_text())
    assert (
        doc["r2"] > 0.6
        and doc["layer"] == "units"
        and doc["recording"] == "lab.nwb, episodes: 8 rows of intervals/trials"
    )
    text = capsys.readouterr().out
    assert "[vnl] read lab.nwb: units (30 units); behaviour: speed, snout, tail_base" in text
    assert "bins of 0.1 s (--bin)" in text and "snout[x] from units: held-out R²" in text


def test_analyze_of_an_nwb_file_names_its_targets_and_its_flags_in_one_line(lab_session, tmp_path, capsys):
    path, _ = lab_session
    rec = tmp_path / "rec.nc"
    synthetic().to_netcdf(rec, engine="h5netcdf")
    cases = [
        (
            ["--method", "decoding"],
            "no target 'forward_speed' in the recording; its behaviour variables: speed, snout,",
        ),
        (["--method", "encoding", "--features", "nose"], "the recording has no nose: choose others with --features"),
        (["--intervals", "nope"], "no intervals table 'nope' in the file (its tables: trials; or `blocks`)"),
    ]
    for extra, message in cases:
        assert main(["analyze", str(path), *extra, "--out", str(tmp_path / "x.png")]) == 2, extra
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (extra, err)
    for value in ("0", "nan", "-1", "1e9"):  # the parser's: it exits with 2
        with pytest.raises(SystemExit) as e:
            main(["analyze", str(path), "--bin", value])
        err = capsys.readouterr().err
        assert e.value.code == 2 and "argument --bin: must be above 0" in err and err.count("\n") == 1
    assert main(["analyze", str(rec), "--bin", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "--bin read an NWB file's times" in err and "a vnl recording (NetCDF-4)" in err
    assert not list(tmp_path.glob("x.*"))
