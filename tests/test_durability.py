"""Nothing lost and nothing silent, with real processes (issue 47): a second writer of a run, a
run that diverges, a disk that fills up at each write of a run, and SIGKILL at named points of
a checkpoint write and of a resume.

Every run trains the point mass of tests/tiny_env.py on MuJoCo C physics through `vnl`'s own
`main` (a launcher script) in a subprocess. The launcher can stop the run at a named point of its
writes (`VNL_TEST_POINT=name:k`, the k-th time it is reached): it prints `[point] name` and waits
for a line on stdin, so the test kills it there exactly, or fills the disk and lets it go on.
A killed or failed run is then resumed to its end and compared with an uninterrupted one: the
same metrics (steps unique and in order) and the same final training state, bit for bit.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from fsutil import fill, tmpfs
from resumecheck import assert_same_as_reference

from vnl.io import checkpoint
from vnl.io import metrics as metrics_io

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("durability")]

TESTS = Path(__file__).resolve().parent
EPOCH = 1024  # env steps between evaluations: 8192 / (9 - 1)
TOTAL = 8192
TRAIN = [
    "train",
    "test_point",
    "--preset",
    "tiny",
    "--steps",
    str(TOTAL),
    "--set",
    "ppo.num_evals=9",
    "--set",
    "env_config.impl=c",
    "--set",
    "log.video=false",
    "--set",
    "log.keep_checkpoints=3",
]

LAUNCHER = """
import json, os, sys
sys.path[:0] = [{tests!r}, {root!r}]  # this checkout's vnl, and tiny_env
import tiny_env
tiny_env.register()

POINT, _, NTH = os.environ.get("VNL_TEST_POINT", "").partition(":")
seen = {{}}

def point(name):
    seen[name] = seen.get(name, 0) + 1
    if name == POINT and seen[name] == int(NTH or 1):
        print(f"[point] {{name}}", flush=True)
        sys.stdin.readline()  # killed here, or let go on (the disk filled meanwhile)

def before(owner, attr, name, when=lambda *a, **k: True):
    real = getattr(owner, attr)
    def wrapper(*args, **kwargs):
        if when(*args, **kwargs):
            point(name)
        return real(*args, **kwargs)
    setattr(owner, attr, wrapper)

def after(owner, attr, name, when=lambda *a, **k: True):
    real = getattr(owner, attr)
    def wrapper(*args, **kwargs):
        out = real(*args, **kwargs)
        if when(*args, **kwargs):
            point(name)
        return out
    setattr(owner, attr, wrapper)

if POINT:
    import numpy as np
    from orbax.checkpoint._src.path import atomicity
    from vnl import durable
    from vnl.io import checkpoint, metrics, plot
    from vnl.train import rundir

    finalize = atomicity.AtomicRenameTemporaryPath.finalize
    async def paused_finalize(self, *args, **kwargs):  # orbax wrote its files, not yet renamed them
        point("inside-orbax")
        return await finalize(self, *args, **kwargs)
    atomicity.AtomicRenameTemporaryPath.finalize = paused_finalize
    make = checkpoint._checkpointer
    class Paused:
        def __init__(self, real): self.real = real
        def save(self, *args, **kwargs):
            point("orbax")
            return self.real.save(*args, **kwargs)
    checkpoint._checkpointer = lambda: Paused(make())
    before(np, "savez_compressed", "npz")
    class Json:
        loads, load, dumps = json.loads, json.load, json.dumps
        def dump(self, *args, **kwargs):
            point("meta")
            return json.dump(*args, **kwargs)
    checkpoint.json = Json()
    after(durable, "fsync_tree", "written")  # the whole temporary checkpoint on disk, not renamed
    is_final = lambda src, dst: os.path.basename(str(dst)).isdigit() and ".tmp-" in str(src)
    after(durable, "rename", "renamed", is_final)  # the new checkpoint in place, rotation not done
    after(durable, "rename", "rotating", lambda src, dst: ".deleting-" in str(dst))
    real_write = metrics.JsonlWriter.write
    def write(self, record):
        point("metrics")
        if POINT == "half-line" and record.get("step", 0) >= {half_at}:  # half a line on disk, then killed
            line = (json.dumps(record) + "\\n").encode()
            os.write(self._fd, line[: len(line) // 2])
            os.fsync(self._fd)
            point("half-line")
        return real_write(self, record)
    metrics.JsonlWriter.write = write
    before(plot, "learning_curve", "curve")
    after(rundir, "set_aside_later_checkpoints", "set-aside")
    after(rundir, "truncate_metrics", "cut")
    before(durable, "replace", "cutting", lambda src, dst: str(dst).endswith("metrics.jsonl"))

DIVERGE = int(os.environ.get("VNL_TEST_DIVERGE_AT", "0"))
if DIVERGE:  # the DIVERGE-th epoch's parameters become NaN (as a too large step would make them)
    import jax, jax.numpy as jp
    from vnl.ppo.loop import PPOLoop
    epoch, calls = PPOLoop.epoch, [0]
    def diverging(self, state):
        state, metrics = epoch(self, state)
        calls[0] += 1
        if calls[0] == DIVERGE:
            nan = lambda x: jp.full_like(x, jp.nan) if jp.issubdtype(x.dtype, jp.floating) else x
            training = state.training.replace(params=jax.tree.map(nan, state.training.params))
            state = state.replace(training=training)
        return state, metrics
    PPOLoop.epoch = diverging

from vnl.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.fixture(scope="module")
def launcher(tmp_path_factory):
    """(script, environment) for `vnl` runs: a shared compilation cache, so that only the first
    run compiles."""
    root = tmp_path_factory.mktemp("durability")
    script = root / "vnl_launcher.py"
    script.write_text(LAUNCHER.format(tests=str(TESTS), root=str(TESTS.parent), half_at=3 * EPOCH))
    cache = root / "cache"
    cache.mkdir(mode=0o700)
    env = {**os.environ, "VNL_COMPILE_CACHE": str(cache), "PYTHONUNBUFFERED": "1"}
    env.pop("VNL_TEST_POINT", None)
    return script, env


def _vnl(launcher, argv, point: str = "", diverge: int = 0, timeout: float = 300) -> subprocess.CompletedProcess:
    script, env = launcher
    env = {**env, "VNL_TEST_POINT": point, "VNL_TEST_DIVERGE_AT": str(diverge)}
    return subprocess.run(
        [sys.executable, str(script), *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        cwd=TESTS.parent,
        stdin=subprocess.DEVNULL,
    )


def _start(launcher, argv, point: str) -> subprocess.Popen:
    script, env = launcher
    return subprocess.Popen(
        [sys.executable, str(script), *map(str, argv)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**env, "VNL_TEST_POINT": point},
        cwd=TESTS.parent,
    )


def _wait_for_point(proc: subprocess.Popen) -> str:
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if line.startswith("[point] "):
            return "".join(lines)
    proc.wait(timeout=60)
    raise AssertionError(f"the run ended (exit {proc.returncode}) before its point:\n{''.join(lines)[-3000:]}")


def _errors(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("vnl: error:")]


@pytest.fixture(scope="module")
def reference(launcher, tmp_path_factory):
    """A run never interrupted: what every interrupted run must end as."""
    run = tmp_path_factory.mktemp("reference") / "run"
    done = _vnl(launcher, [*TRAIN, "--out", run])
    assert done.returncode == 0, done.stdout + done.stderr
    return run


def _same_as_reference(run: Path, reference: Path) -> None:
    assert_same_as_reference(run, reference, TOTAL, EPOCH)


def _check_resumable(run: Path) -> int:
    """The newest checkpoint loads without falling back, and metrics.jsonl holds every evaluation
    up to it (its own record may be missing: it is written after the checkpoint)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        step, arrays, meta = checkpoint.load_train_state(run)
    assert step == checkpoint.steps(run)[-1] and meta["step"] == step and arrays
    recorded = [r["step"] for r in metrics_io.read(run / "metrics.jsonl")]
    assert recorded in (list(range(0, step + 1, EPOCH)), list(range(0, step, EPOCH))), (recorded, step)
    return step


# --- 1. one writer ------------------------------------------------------------------------------


def test_two_resumes_at_once_one_refuses_naming_the_other(launcher, reference, tmp_path):
    """Two `vnl train --resume R` started together (a SLURM requeue while the job still runs, a
    double launch): exactly one trains; the other exits 2 with one line naming the first's
    process, and the run ends as the uninterrupted one, its metrics' steps unique and in order."""
    run = tmp_path / "run"
    proc = _start(launcher, [*TRAIN, "--out", run], "renamed:4")  # killed after the checkpoint of step 3072
    _wait_for_point(proc)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    script, env = launcher
    procs = [
        subprocess.Popen(
            [sys.executable, str(script), "train", "--resume", str(run)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            text=True,
            env={**env, "VNL_TEST_POINT": ""},
            cwd=TESTS.parent,
        )
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    codes = sorted(p.returncode for p in procs)
    assert codes == [0, 2], [(p.returncode, o[1][-2000:]) for p, o in zip(procs, outs, strict=True)]
    loser = next(o for p, o in zip(procs, outs, strict=True) if p.returncode == 2)
    winner = next(p for p in procs if p.returncode == 0)
    err = [line for line in loser[1].splitlines() if line.strip()]
    assert len(err) == 1 and f"is being written by process {winner.pid}" in err[0], err
    _same_as_reference(run, reference)


# --- 2. divergence --------------------------------------------------------------------------------


def test_a_diverging_run_stops_with_one_line_and_its_last_finite_checkpoint_evaluates(launcher, tmp_path):
    run = tmp_path / "run"
    done = _vnl(launcher, [*TRAIN, "--out", run], diverge=4)  # the 4th epoch's parameters turn NaN
    errors = _errors(done.stderr)
    assert done.returncode == 3, done.stdout + done.stderr
    assert len(errors) == 1 and "Traceback" not in done.stderr, done.stderr
    assert f"training diverged before step {4 * EPOCH:,}" in errors[0], errors
    last = 3 * EPOCH
    assert f"The last finite checkpoint is step {last:,}: `vnl eval {run} --step {last}`" in errors[0], errors
    assert checkpoint.steps(run)[-1] == last
    assert [r["step"] for r in metrics_io.read(run / "metrics.jsonl")] == list(range(0, last + 1, EPOCH))
    meta = json.loads((checkpoint.step_dir(run, last) / "meta.json").read_text())
    assert meta["versions"]["jax"] and meta["versions"]["mujoco"] and meta["format"] == checkpoint.META_FORMAT
    evaluated = _vnl(launcher, ["eval", run, "--episodes", "2", "--out", tmp_path / "e.json"])
    assert evaluated.returncode == 0, evaluated.stderr
    assert json.loads((tmp_path / "e.json").read_text())["checkpoint_step"] == last


def test_a_learning_rate_of_1e30_diverges_in_its_first_epoch_and_says_so(launcher, tmp_path):
    run = tmp_path / "run"
    done = _vnl(launcher, [*TRAIN, "--out", run, "--set", "ppo.learning_rate=1e30"])
    errors = _errors(done.stderr)
    assert done.returncode == 3 and len(errors) == 1, done.stdout + done.stderr
    assert f"training diverged before step {EPOCH:,}" in errors[0] and "step 0: `vnl eval" in errors[0], errors
    assert checkpoint.steps(run) == [0]
    assert _vnl(launcher, ["eval", run, "--episodes", "1", "--out", tmp_path / "e.json"]).returncode == 0


# --- 6/8. a full disk at each write -------------------------------------------------------------


@pytest.mark.parametrize("point", ["orbax:3", "npz:3", "meta:3", "metrics:3", "curve:1"])
def test_a_disk_that_fills_at_each_write_loses_nothing_and_resumes_to_the_end(launcher, reference, tmp_path, point):
    """The run's disk (a real tmpfs) is filled just before the write at `point`: the run stops
    with one line naming the last good checkpoint; once space is freed, `--resume` ends where
    the uninterrupted run ends."""
    with tmpfs("160m") as disk:
        run = disk / "run"
        proc = _start(launcher, [*TRAIN, "--out", run], point)
        _wait_for_point(proc)
        filler = fill(disk)
        out, _ = proc.communicate("\n", timeout=300)
        errors = _errors(out)
        assert proc.returncode == 2 and len(errors) == 1 and "Traceback" not in out, out[-3000:]
        assert "No space left on device" in errors[0] and "--resume" in errors[0], errors
        assert not [p for p in checkpoint.checkpoint_dir(run).iterdir() if p.name.startswith(".tmp-")]
        _check_resumable(run)
        filler.unlink()
        done = _vnl(launcher, ["train", "--resume", run])
        assert done.returncode == 0, done.stdout + done.stderr
        _same_as_reference(run, reference)
        assert (run / "learning_curve.png").stat().st_size > 1000


# --- 8. SIGKILL at named points ------------------------------------------------------------------

KILL_POINTS = [
    "inside-orbax:3",  # orbax's files written, its own rename not done
    "npz:3",
    "meta:2",
    "written:3",  # the whole temporary checkpoint fsynced, not renamed
    "renamed:4",  # the new checkpoint in place, the rotation not done
    "rotating:1",  # an old checkpoint renamed to .deleting-, not deleted
    "half-line:1",  # half a metrics line on disk
]


@pytest.mark.parametrize("point", KILL_POINTS)
def test_sigkill_at_a_named_point_loses_nothing_and_resumes_exactly(launcher, reference, tmp_path, point):
    run = tmp_path / "run"
    proc = _start(launcher, [*TRAIN, "--out", run], point)
    _wait_for_point(proc)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    _check_resumable(run)
    done = _vnl(launcher, ["train", "--resume", run])
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stdout + done.stderr
    _same_as_reference(run, reference)
    assert not [p for p in checkpoint.checkpoint_dir(run).iterdir() if p.name.startswith((".tmp-", ".deleting-"))]


@pytest.mark.parametrize("point", ["set-aside:1", "cutting:1", "cut:1"])
def test_sigkill_inside_a_resume_s_rewind_loses_nothing(launcher, reference, tmp_path, point):
    """`--resume --from-step` sets the later checkpoints aside and cuts metrics.jsonl back:
    killed between the two, while the cut file is renamed into place, or right after the cut,
    the next plain resume starts from the same step and the run ends as the uninterrupted one
    (the later records kept in a backup, the later checkpoints in superseded-*). (Cutting the
    metrics first, as vnl did, a kill after the cut left the later checkpoints in place: the next
    resume went on from the newest one with the metrics between them lost.)"""
    run = tmp_path / "run"
    shutil.copytree(reference, run)
    middle = checkpoint.steps(reference)[1]  # the oldest kept checkpoint but step 0 (keep_checkpoints: 3)
    assert middle < TOTAL - EPOCH
    proc = _start(launcher, ["train", "--resume", run, "--from-step", middle], point)
    _wait_for_point(proc)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    assert checkpoint.steps(run)[-1] == middle
    recorded = [r["step"] for r in metrics_io.read(run / "metrics.jsonl")]
    assert recorded in (list(range(0, TOTAL + 1, EPOCH)), list(range(0, middle + 1, EPOCH))), recorded
    done = _vnl(launcher, ["train", "--resume", run])
    assert done.returncode == 0, done.stdout + done.stderr
    _same_as_reference(run, reference)
    superseded = list(checkpoint.checkpoint_dir(run).glob("superseded-*"))
    assert len(superseded) == 1 and sorted(p.name for p in superseded[0].iterdir())[-1] == f"{TOTAL:012d}"
    assert list(run.glob("metrics.jsonl.*.bak"))


# --- 9. pinning --------------------------------------------------------------------------------


def test_a_recording_finds_its_run_from_any_working_directory(launcher, reference, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    shutil.copytree(reference, work / "run")
    script, env = launcher
    done = subprocess.run(
        [sys.executable, str(script), "record", "run", "--episodes", "1", "--steps", "5", "--out", "rec.nc"],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=work,
    )
    assert done.returncode == 0, done.stderr
    import xarray as xr

    with xr.open_dataset(work / "rec.nc", engine="h5netcdf") as ds:
        assert ds.attrs["run_dir"] == str(work / "run")
    elsewhere = subprocess.run(
        [sys.executable, str(script), "compare", str(work / "rec.nc"), str(work / "run"), "--out", tmp_path / "c.png"],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=tmp_path,
    )
    assert elsewhere.returncode == 0, elsewhere.stderr
