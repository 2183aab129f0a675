"""`vnl record`: its input checks (no heavy imports, exit 2 with one line)."""

from recordings import synthetic  # tests/recordings.py

from vnl.cli import main


def test_record_rejects_mistakes_with_one_line(tmp_path, capsys):
    rec = tmp_path / "rec.nc"
    synthetic().to_netcdf(rec, engine="h5netcdf")
    cases = [
        (["record", "--from", str(rec), "--format", "netcdf"], "--from converts"),
        (["record", str(tmp_path), "--format", "nwb", "--out", str(tmp_path / "r.nc")], "ends in .nc"),
        (["record"], "give the run directory"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (argv, err)
