"""`vnl compare`: dispatch through the registry of measures and its input checks (no heavy
imports, exit 2 with one line); recorded activity (a lab's NWB file beside a recording) on matched
conditions and by DSA, from the command line."""

import json

from recordings import synthetic  # tests/recordings.py

from vnl.cli import main


def test_compare_rejects_mistakes_with_one_line(capsys):
    cases = [
        (["compare", "a", "b", "--measure", "rdm", "--rdm-comparison", "nope"], "unknown RDM comparison"),
        (["compare", "a", "b", "--measure", "dsa", "--rsa", "euclidean"], "cannot be combined"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (argv, err)


def _fixtures(tmp_path):
    rec = tmp_path / "rec.nc"
    synthetic().to_netcdf(rec, engine="h5netcdf")
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("env: ant_run\n")
    return str(rec), str(run)


def test_compare_of_recorded_activity_refuses_what_is_not_defined_in_one_line(lab_session, tmp_path, capsys):
    lab = str(lab_session[0])
    rec, run = _fixtures(tmp_path)
    cases = [
        (["compare", lab, rec], "is an NWB file of a lab's session (not vnl's export): there is no network"),
        (
            ["compare", rec, lab, "--measure", "rdm"],
            "compare recorded activity on matched conditions with --conditions",
        ),
        (["compare", lab, run, "--conditions", "speed"], "is a run directory; comparing recorded activity takes"),
        (["compare", lab, rec, "--measure", "dsa", "--conditions", "speed"], "leave --conditions out"),
        (["compare", lab, rec, "--conditions", "speed", "--recording", rec], "leave --recording out"),
        (["compare", run, run, "--recording", lab], "it holds no observations to show the networks"),
        (["compare", run, run, "--bin", "0.1"], "--bin and --intervals read NWB files for their recorded activity"),
        (["compare", rec, rec, "--conditions", "reward", "--bin", "0.1"], "none of the recordings is an NWB file"),
        (["compare", lab, rec, "--conditions", "nope"], "lab.nwb: no target 'nope' in the recording"),
        (["compare", lab, rec, "--conditions", "a,b,c"], "--conditions names 3 variables for 2 recordings"),
        (["compare", lab, rec, "--conditions", "snout,forward_speed"], "snout has 2 columns"),
    ]
    for argv, message in cases:
        assert main([*argv, "--out", str(tmp_path / "c.png")]) == 2, argv
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (argv, err)
    assert not list(tmp_path.glob("c.*"))


def test_compare_a_lab_session_with_a_recording_on_conditions_and_dynamics(lab_session, tmp_path, capsys):
    lab = str(lab_session[0])
    rec, _ = _fixtures(tmp_path)
    out = tmp_path / "c.png"
    argv = ["compare", lab, rec, "--conditions", "speed,forward_speed", "--condition-bins", "5", "--out", str(out)]
    assert main(argv) == 0
    doc = json.loads(out.with_suffix(".json").read_text())
    assert doc["measure"] == "cka" and doc["conditions"]["variables"] == {"lab.nwb": "speed", "rec.nc": "forward_speed"}
    assert [p["layers_a"] for p in doc["pairs"]] == [["units"]] and out.stat().st_size > 5000
    text = capsys.readouterr().out
    assert "[vnl] read lab.nwb" in text and "linear CKA on 5 conditions of speed / forward_speed" in text
    out = tmp_path / "d.png"
    assert main(["compare", lab, rec, "--measure", "dsa", "--delays", "3", "--rank", "5", "--out", str(out)]) == 0
    doc = json.loads(out.with_suffix(".json").read_text())
    assert "lab.nwb 8 x 1000; rec.nc 6 x 130 steps of 0.02 s" in doc["observations"]
    assert all(v is not None for p in doc["pairs"] for row in p["similarity"] for v in row)
