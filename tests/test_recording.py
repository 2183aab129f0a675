"""vnl.recording: files told apart by their content, never their suffix; every other file given
where a recording is read is one line naming what it is and what the command wants. NWB files are
read by `vnl analyze` and `vnl compare` (tests/test_nwb_reader.py), not by `view` or `record --from`."""

from datetime import UTC, datetime

import h5py
import numpy as np
import pytest
import xarray as xr
from recordings import synthetic  # tests/recordings.py

from vnl import recording
from vnl.cli import main
from vnl.errors import VnlError
from vnl.recording import formats


def nwb_file(path):
    """A small NWB file written with pynwb (a lab's session, not a vnl recording)."""
    from pynwb import NWBHDF5IO, NWBFile, TimeSeries

    f = NWBFile(session_description="a session", identifier="x", session_start_time=datetime.now(UTC))
    f.add_acquisition(TimeSeries(name="lfp", data=np.zeros(10), unit="V", rate=1000.0))
    with NWBHDF5IO(str(path), "w") as io:
        io.write(f)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """One file (or directory) of every kind `identify` tells apart, named to mislead."""
    root = tmp_path_factory.mktemp("kinds")
    synthetic().to_netcdf(root / "rec.data", engine="h5netcdf")  # a recording with another suffix
    nwb_file(root / "session.nwb").rename(root / "session.NWB")
    nwb_file(root / "lab.nwb").rename(root / "lab.nc")  # NWB named as NetCDF
    with h5py.File(root / "foreign.nc", "w") as f:
        f["x"] = np.arange(5)
    with h5py.File(root / "userblock.h5", "w", userblock_size=512) as f:
        f["x"] = np.arange(5)
    xr.Dataset({"a": ("x", np.arange(3))}).to_netcdf(root / "classic.nc", engine="scipy")
    xr.Dataset({"a": ("x", np.arange(3))}).to_netcdf(root / "plain.nc", engine="h5netcdf")
    (root / "empty.nc").write_bytes(b"")
    (root / "text.nc").write_text("env: ant_run\n")
    (root / "damaged.nc").write_bytes(formats.HDF5_SIGNATURE + b"\0" * 100)
    (root / "run").mkdir()
    (root / "run" / "config.yaml").write_text("env: ant_run\n")
    (root / "folder").mkdir()
    return root


KINDS = [
    ("rec.data", "recording", "a vnl recording"),
    ("session.NWB", "nwb", "an NWB file (NWB 2."),
    ("lab.nc", "nwb", "an NWB file"),
    ("foreign.nc", "hdf5", "neither NetCDF-4 nor NWB"),
    ("userblock.h5", "hdf5", "neither NetCDF-4 nor NWB"),
    ("classic.nc", "netcdf3", "NetCDF-3 (classic)"),
    ("plain.nc", "netcdf", "a NetCDF-4 file that is not a vnl recording (no active, time)"),
    ("empty.nc", "empty", "an empty file"),
    ("text.nc", "other", "it starts with 'env: ant'"),
    ("damaged.nc", "damaged", "a damaged HDF5 file"),
    ("run", "run", "a vnl run directory"),
    ("folder", "directory", "not a vnl run directory"),
    ("missing.nc", "missing", "does not exist"),
]


@pytest.mark.parametrize("name, kind, words", KINDS)
def test_identify_tells_each_kind_by_its_content(files, name, kind, words):
    found = formats.identify(files / name)
    assert found.kind == kind and words in found.what, found


@pytest.mark.parametrize("name, kind, words", [k for k in KINDS if k[1] not in ("recording", "missing", "nwb")])
def test_read_refuses_every_other_kind_naming_it_and_what_it_wants(files, name, kind, words):
    with pytest.raises(VnlError) as e:
        recording.read(files / name)
    assert words in str(e.value) and "this command reads a vnl recording (NetCDF" in str(e.value)


@pytest.mark.parametrize("name", ["session.NWB", "lab.nc"])
def test_an_nwb_file_is_read_by_the_nwb_reader_or_refused_where_netcdf_is_needed(files, name):
    with pytest.raises(VnlError, match=r"is an NWB file \(NWB 2\..*`vnl analyze` and `vnl compare` read NWB files"):
        recording.read(files / name, kinds=formats.NETCDF_ONLY)
    with pytest.raises(VnlError, match="is an NWB file with no units"):  # its lfp is no unit (tests/test_nwb_reader.py)
        recording.read(files / name)


def test_a_recording_is_read_whatever_its_suffix(files):
    ds = recording.read(files / "rec.data")
    assert ds.sizes["episode"] == 6 and "policy_hidden_1" in ds


def test_every_command_that_reads_a_recording_names_an_nwb_or_foreign_file(files, tmp_path, capsys):
    """Before: xarray read NWB as NetCDF and raised `TypeError: object of type
    'h5py.h5r.Reference' has no len()` (upper-case suffixes passed `analyze`'s suffix check)."""
    out = tmp_path / "out"
    for source, words in (("session.NWB", "an NWB file"), ("lab.nc", "an NWB file"), ("foreign.nc", "HDF5 file")):
        path = str(files / source)
        for argv in (
            ["analyze", path, "--out", f"{out}.png"],
            ["analyze", path, "--method", "decoding", "--out", f"{out}.png"],
            ["view", path, "--out", f"{out}.rrd"],
            ["record", "--from", path, "--out", f"{out}.nwb"],
            ["compare", path, str(files / "rec.data"), "--out", f"{out}.png"],
            ["compare", str(files / "run"), str(files / "run"), "--recording", path, "--out", f"{out}.png"],
        ):
            assert main(argv) == 2, argv
            err = capsys.readouterr().err
            assert err.startswith("vnl: error:") and err.count("\n") == 1 and words in err, (argv, err)
    assert not list(tmp_path.iterdir())


def test_a_path_of_dot_is_a_run_directory_or_one_line(files, tmp_path, monkeypatch, capsys):
    """Before: `vnl compare . .` raised `ValueError: PosixPath('.') has an empty name`."""
    monkeypatch.chdir(files / "folder")
    for argv in (["compare", ".", "."], ["compare", "..", "."], ["view", "."], ["analyze", "."]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("vnl: error:") and err.count("\n") == 1, (argv, err)
