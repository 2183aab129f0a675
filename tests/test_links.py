"""Links, late checks, leftovers and API types (issue 53): the fast tests.

A run copied with `cp -as` (or kept by DVC or git-annex) is a folder of links to another run's
files; nothing vnl writes into it may change that other run. The copies here are made as `cp -as`
makes them (real folders, every file a symbolic link to the original's, `_copy_as_links`), or
with hard links, or with a folder that is itself a link. The generated fuzz of the CLI
(tests/test_cli_fuzz.py) runs the same classes as subprocesses.
"""

import os
import stat
import warnings
from pathlib import Path

import numpy as np
import pytest
from fsutil import snapshot
from test_hardening import ARRAYS, PARAMS, _meta, _one_error, _run

from vnl import durable
from vnl import typed_config as config_lib
from vnl.cli import checks
from vnl.errors import VnlError
from vnl.io import checkpoint, layout, runlock
from vnl.io import metrics as metrics_io
from vnl.train import config as train_config
from vnl.train import rundir


def _copy_as_links(src: Path, dst: Path) -> None:
    """What `cp -as SRC DST` makes: the same folders, each file a symbolic link to the original."""
    for dirpath, _, filenames in os.walk(src):
        here = dst / Path(dirpath).relative_to(src)
        here.mkdir(parents=True, exist_ok=True)
        for name in filenames:
            os.symlink(Path(dirpath, name).absolute(), here / name)


def _original(tmp_path: Path) -> Path:
    """A run with checkpoints 0, 2, 4, their metrics and its lock file (written by its session)."""
    run = _run(tmp_path, "orig")
    for step in (2, 4):
        checkpoint.save(run, step, PARAMS, 0, ARRAYS, _meta(step))
    metrics_io.rewrite(run / layout.METRICS, [{"step": s, "eval/episode_reward": float(s)} for s in (0, 2, 4)])
    with runlock.hold(run):
        pass
    return run


def test_resuming_a_copy_made_of_links_never_changes_the_original(tmp_path):
    """Each write a resume (and the end of its session) makes to the run directory, in order, on
    a `cp -as` copy: the original keeps every byte, mode and mtime; the copy's files are its own."""
    orig = _original(tmp_path)
    copy = tmp_path / "copy"
    _copy_as_links(orig, copy)
    before = snapshot(orig)
    say = lambda line: None  # noqa: E731
    checkpoint.tidy(copy)
    with runlock.hold(copy):
        values = config_lib.load_yaml(str(copy / layout.CONFIG))
        config_lib.dump_yaml({**values, "ppo": {**values["ppo"], "num_timesteps": 99}}, str(copy / layout.CONFIG))
        rundir.set_aside_later_checkpoints(copy, 2, say)
        rundir.truncate_metrics(copy, 2, None, say)
        writer = metrics_io.JsonlWriter(copy / layout.METRICS)
        writer.write({"step": 4, "eval/episode_reward": 9.0})
        writer.close()
        checkpoint.save(copy, 2, PARAMS, 1, ARRAYS, _meta(2))  # replaces the linked step 2
        checkpoint.save(copy, 4, PARAMS, 1, ARRAYS, _meta(4))  # rotates step 2 out
        durable.write_atomic(copy / layout.LEARNING_CURVE, b"png")
        durable.write_atomic(copy / layout.FINAL_VIDEO, b"mp4")
        durable.write_atomic(copy / "eval.json", b"{}")
    assert snapshot(orig) == before
    for name in (layout.CONFIG, layout.METRICS, layout.LOCK, layout.LEARNING_CURVE, layout.FINAL_VIDEO):
        assert stat.S_ISREG((copy / name).lstat().st_mode), name
    assert [r["step"] for r in metrics_io.read(copy / layout.METRICS)] == [0, 2, 4]
    assert checkpoint.steps(copy) == [0, 4] and checkpoint.load_train_state(copy)[0] == 4
    assert config_lib.load_yaml(str(copy / layout.CONFIG))["ppo"]["num_timesteps"] == 99


@pytest.mark.parametrize("link", ["symbolic", "hard"])
def test_metrics_appended_to_a_linked_file_go_to_a_copy_of_its_own(tmp_path, link):
    shared = tmp_path / "shared.jsonl"
    metrics_io.rewrite(shared, [{"step": 0}])
    before = shared.read_bytes()
    path = tmp_path / "run" / layout.METRICS
    path.parent.mkdir()
    (os.symlink if link == "symbolic" else os.link)(shared, path)
    writer = metrics_io.JsonlWriter(path)
    writer.write({"step": 1})
    writer.close()
    assert shared.read_bytes() == before and shared.stat().st_nlink == 1
    assert stat.S_ISREG(path.lstat().st_mode) and [r["step"] for r in metrics_io.read(path)] == [0, 1]


@pytest.mark.parametrize("link", ["symbolic", "hard", "dangling"])
def test_a_lock_file_that_is_a_link_is_replaced_and_what_it_shared_is_left_alone(tmp_path, link):
    """A linked `.vnl-lock` had its target truncated (the holder is written into the locked file)."""
    orig, copy = tmp_path / "orig", tmp_path / "copy"
    orig.mkdir(), copy.mkdir()
    (orig / layout.LOCK).write_text('{"pid": 1, "host": "the original"}')
    if link == "hard":
        os.link(orig / layout.LOCK, copy / layout.LOCK)
    else:
        os.symlink(orig / (layout.LOCK if link == "symbolic" else "missing"), copy / layout.LOCK)
    before = snapshot(orig)
    with runlock.hold(copy, command="vnl train --resume copy"):
        assert runlock.holder(copy)["command"] == "vnl train --resume copy"
        assert stat.S_ISREG((copy / layout.LOCK).lstat().st_mode) and (copy / layout.LOCK).lstat().st_nlink == 1
    assert snapshot(orig) == before and (orig / layout.LOCK).stat().st_nlink == 1


def test_the_copy_of_a_running_run_is_a_run_of_its_own(tmp_path, capsys):
    """Its lock file links to the original's, which the original's session holds: the copy is
    not refused as "being written by" that session."""
    orig = _original(tmp_path)
    copy = tmp_path / "copy"
    _copy_as_links(orig, copy)
    with runlock.hold(orig, command="vnl train --resume orig"):
        assert runlock.holder(copy) is None
        with runlock.hold(copy):
            assert runlock.holder(orig)["command"] == "vnl train --resume orig"


def test_checkpoints_that_are_links_are_removed_as_links_and_a_linked_folder_is_refused(tmp_path, capsys):
    orig = _original(tmp_path)
    before = snapshot(orig)
    copy = tmp_path / "copy"
    copy.mkdir()
    (copy / layout.CONFIG).symlink_to(orig / layout.CONFIG)
    (copy / layout.CHECKPOINTS).mkdir()
    for step in (0, 2, 4):  # each step's folder a link (what `ln -s` of the step folders makes)
        (copy / layout.CHECKPOINTS / f"{step:012d}").symlink_to(checkpoint.step_dir(orig, step))
    (copy / layout.CHECKPOINTS / ".tmp-000000000006-99").symlink_to(checkpoint.step_dir(orig, 4))
    checkpoint.save(copy, 4, PARAMS, 0, ARRAYS, _meta(4))  # replaces a linked step
    checkpoint.save(copy, 6, PARAMS, 1, ARRAYS, _meta(6))  # rotates linked steps 2 and 4 out
    assert checkpoint.steps(copy) == [0, 6]
    assert sorted(p.name for p in (copy / layout.CHECKPOINTS).iterdir()) == ["000000000000", "000000000006"]
    assert snapshot(orig) == before
    # a `checkpoints` folder that is itself a link: refused before anything is written through it
    linked = tmp_path / "linked"
    _copy_as_links(orig, linked)
    os.rename(linked / layout.CHECKPOINTS, tmp_path / "aside")
    (linked / layout.CHECKPOINTS).symlink_to(orig / layout.CHECKPOINTS)
    _one_error(["train", "--resume", linked], capsys, "checkpoints is a symbolic link", "cp -as")
    with pytest.raises(VnlError, match="symbolic link"):
        checkpoint.save(linked, 6, PARAMS, 1, ARRAYS, _meta(6))
    with pytest.raises(VnlError, match="symbolic link"):
        checkpoint.tidy(linked)
    assert snapshot(orig) == before


def test_outputs_given_as_links_are_refused_before_the_work_and_default_ones_replaced(tmp_path, capsys):
    run = _run(tmp_path)
    (tmp_path / "mine.json").write_text("keep")
    (tmp_path / "link.json").symlink_to(tmp_path / "mine.json")
    (tmp_path / "dangling.json").symlink_to(tmp_path / "nowhere" / "x.json")
    (tmp_path / "dangling.mp4").symlink_to(tmp_path / "nowhere.mp4")
    (tmp_path / "dangling_dir").symlink_to(tmp_path / "nowhere")
    for argv, words in [
        (["eval", run, "--out", tmp_path / "link.json"], ["symbolic link (to", "mine.json"]),
        (["eval", run, "--out", tmp_path / "dangling.json"], ["symbolic link (to nothing"]),
        (["render", run, "--out", tmp_path / "dangling.mp4"], ["symbolic link (to nothing"]),
        (["train", "ant_run", "--out", tmp_path / "dangling_dir"], ["symbolic link to nothing"]),
    ]:
        _one_error(argv, capsys, *words)
    assert (tmp_path / "mine.json").read_text() == "keep"
    # a default output in a copy made of links: the new file replaces the link
    (run / "eval.json").symlink_to(tmp_path / "mine.json")
    checks.output(run / "eval.json", (".json",), given=False)
    durable.write_atomic(run / "eval.json", "{}")
    assert (tmp_path / "mine.json").read_text() == "keep" and (run / "eval.json").read_text() == "{}"


def test_a_new_run_refused_or_failed_before_its_first_checkpoint_leaves_nothing_behind(tmp_path):
    config = train_config.build("ant_run", "tiny")
    out = tmp_path / "a" / "b" / "run"
    with pytest.raises(VnlError, match="refused"), rundir.new_run(out, config):
        assert (out / layout.CONFIG).is_file() and (out / layout.LOCK).is_file()
        raise VnlError("refused")
    assert list(tmp_path.iterdir()) == []  # the directories it created are gone too
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("x")
    with pytest.raises(KeyboardInterrupt), rundir.new_run(mine, config):  # a second Ctrl-C while compiling
        metrics_io.JsonlWriter(mine / layout.METRICS).close()
        (mine / "tensorboard").mkdir()
        raise KeyboardInterrupt
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    (mine / layout.CONFIG).write_text("# my notes\n")  # refused: the folder holds a user's config.yaml
    with pytest.raises(VnlError, match="already holds a run"), rundir.new_run(mine, config):
        pass
    assert sorted(p.name for p in mine.iterdir()) == [layout.CONFIG, "notes.txt"]
    kept = tmp_path / "kept"  # a run with a checkpoint can be resumed: it stays
    with pytest.raises(RuntimeError), rundir.new_run(kept, config):
        checkpoint.save(kept, 0, PARAMS, 0, ARRAYS, _meta(0))
        raise RuntimeError
    assert (kept / layout.CONFIG).is_file() and checkpoint.steps(kept) == [0]


def test_a_train_refused_by_the_disk_estimate_leaves_nothing_in_out(tmp_path, point_envs):
    """The real refusal: a 32 MB tmpfs is below the estimate's 64 MB margin. It came after
    config.yaml and the lock were written, so the corrected command was refused as "already holds
    a run"."""
    from fsutil import tmpfs

    from vnl.train import trainer

    config = train_config.build("test_point", "tiny", {"env_config": {"impl": "c"}, "log": {"video": False}})
    with tmpfs("32m") as root:
        with pytest.raises(VnlError, match="not enough free disk space"):
            trainer.train(config, root / "new" / "run", say=lambda line: None)
        assert list(root.iterdir()) == []
        (root / "mine").mkdir()
        with pytest.raises(VnlError, match="not enough free disk space"):
            trainer.train(config, root / "mine", say=lambda line: None)
        assert list((root / "mine").iterdir()) == []


# --- temporary files of interrupted writes ------------------------------------------------------


def _dead_pid() -> int:
    """A pid no process has now."""
    for pid in range(4_194_000, 4_194_304):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return pid
        except OSError:
            continue
    pytest.skip("no free pid found")


def test_the_next_write_removes_the_temporary_files_of_killed_writes(tmp_path):
    """A SIGKILL (or a power cut) mid-write leaves `.rec.tmp-<pid>-<host>-<random>.nwb`; the next
    write of rec.nwb removes those of processes that no longer run, and only those."""
    path = tmp_path / "rec.nwb"
    dead, host = _dead_pid(), durable.temporary_name(path).name.split("-")[2]
    stale = [f".rec.tmp-{dead}-{host}-0123abcd.nwb", f".rec.tmp-{dead}-89abcdef.nwb"]  # this vnl's, an older's
    kept = [
        f".rec.tmp-{os.getppid()}-{host}-0123abcd.nwb",  # a write in progress
        f".rec.tmp-{dead}-{'0000' if host != '0000' else '1111'}-0123abcd.nwb",  # another host's (NFS)
        f".rec.tmp-{dead}-{host}-0123abcd.nc",  # another file's
        f".other.tmp-{dead}-{host}-0123abcd.nwb",
    ]
    for name in stale + kept:
        (tmp_path / name).write_bytes(b"half")
    durable.write_atomic(path, b"new")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*kept, "rec.nwb"])


def test_sigterm_during_a_write_removes_its_temporary_file(tmp_path):
    """SIGTERM's default action ended the process inside the write and left the temporary file
    (an NWB export's hidden `.rec.tmp-*.nwb`); during a write it raises `durable.Terminated`, the
    file is removed and the process exits with 143."""
    import signal
    import time

    path = tmp_path / "rec.nwb"
    path.write_bytes(b"old")

    def writer(tmp: Path) -> None:
        tmp.write_bytes(b"half")
        assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL  # (else the signal would end pytest)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler runs here
        raise AssertionError("SIGTERM did not interrupt the write")

    with pytest.raises(durable.Terminated) as caught:
        durable.write_atomic(path, writer=writer)
    assert caught.value.code == 143 and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    assert path.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["rec.nwb"]


def test_a_sigterm_during_a_command_s_write_is_one_line_and_exit_143(monkeypatch, capsys):
    from vnl import cli
    from vnl.cli import cmd_list

    def terminated(args):
        raise durable.Terminated()

    monkeypatch.setattr(cmd_list, "run", terminated)
    assert cli.main(["list"]) == 143
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vnl: terminated (SIGTERM)")


@pytest.mark.slow
def test_a_sigterm_from_outside_during_a_write_leaves_no_temporary_file(tmp_path):
    """The real signal, sent by another process (a job scheduler's, `timeout`'s) mid-write."""
    import signal
    import subprocess
    import sys

    script = (
        "import sys, time\nfrom pathlib import Path\nfrom vnl import durable\n"
        "def writer(tmp):\n    Path(tmp).write_bytes(b'half')\n    print('writing', flush=True)\n    time.sleep(60)\n"
        "durable.write_atomic(sys.argv[1], writer=writer)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    proc = subprocess.Popen(
        [sys.executable, "-c", script, str(tmp_path / "rec.nwb")], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        assert proc.stdout.readline() == "writing\n"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 143
    finally:
        proc.kill()
        proc.stdout.close()
    assert list(tmp_path.iterdir()) == []


# --- handled faults print nothing of their own ---------------------------------------------------


TRUNCATED = """
import sys, warnings
from pathlib import Path
import numpy as np, jax.numpy as jp
from brax.training.acme import running_statistics, specs
from vnl.io import checkpoint

rng = np.random.default_rng(0)
def mlp(sizes):
    layer = lambda a, b: {"w": rng.normal(size=(a, b)).astype(np.float32), "b": np.zeros(b, np.float32)}
    return {"params": {f"h{i}": layer(a, b) for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:]))}}
normalizer = running_statistics.init_state(specs.Array((27,), jp.float32))
params = (normalizer, mlp([27, 32, 32, 32, 32, 16]), mlp([27, 256, 256, 256, 256, 256, 1]))  # vnl's sizes
run = Path(sys.argv[1])
for step in (0, 2):
    checkpoint.save(run, step, params, 0, None, {"training_steps_per_epoch": 1})
for f in (checkpoint.step_dir(run, 2) / checkpoint.PARAMS / "d").iterdir():  # orbax's data, cut in half
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
print("loading", file=sys.stderr, flush=True)
warnings.showwarning = lambda message, *args, **kwargs: print(f"warning: {message}", file=sys.stderr)
print(checkpoint.load(run)[0])
"""


@pytest.mark.slow
def test_a_truncated_newest_checkpoint_falls_back_without_tracebacks(tmp_path):
    """orbax closed its event loop at the first failed read while tensorstore finished the
    others: `vnl eval` fell back to the older checkpoint correctly, but printed a "RuntimeError:
    Event loop is closed" traceback per array (and asyncio's "exception was never retrieved")."""
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    done = subprocess.run(
        [sys.executable, "-c", TRUNCATED, str(tmp_path / "run")], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0 and done.stdout.strip().splitlines()[-1] == "0", done.stderr[-2000:]
    err = done.stderr.split("loading\n", 1)[1]
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: checkpoint") and "unreadable" in lines[0], err[-3000:]
    assert len(lines[0]) < 600  # tensorstore's spec (kilobytes) is cut


# --- the Python API's arguments -------------------------------------------------------------------


def test_load_policy_takes_integer_steps_best_and_latest_and_names_them_for_anything_else(tmp_path):
    """`step=4096.0` ended in "ValueError: Unknown format code 'd'"; `step="4096"` and `"best"`
    were looked up as keys and refused with a list of steps holding the one asked for."""
    import vnl
    from vnl.policy import checkpoint_step

    run = _run(tmp_path)
    checkpoint.save(run, 4096, PARAMS, 0, ARRAYS, _meta(4096))
    for bad in (4096.0, "4096", True, np.bool_(False), -1, "newest", [4096], np.float32(4096)):
        with pytest.raises(VnlError, match=r"step must be a checkpoint step .*'best'.*'latest'"):
            vnl.load_policy(run, step=bad)
    assert checkpoint_step(run, 4096) == 4096 and checkpoint_step(run, np.int64(4096)) == 4096
    assert checkpoint_step(run, "latest") is None and checkpoint_step(run, None) is None
    assert checkpoint_step(run, "best") == 4096  # the highest eval/episode_reward
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the toy parameters are unreadable: "trying an older one"
        for good in (np.int32(4096), "best", "latest"):  # accepted, then the parameters are read
            with pytest.raises(VnlError, match="no readable checkpoint"):
                vnl.load_policy(run, step=good)
    with pytest.raises(VnlError, match=r"no checkpoint at step 7 in .*; available steps: 0, 4096$"):
        vnl.load_policy(run, step=7)
    with pytest.raises(VnlError, match="step must be"):
        checkpoint.load_train_state(run, 4096.0)  # the library below the API too


@pytest.mark.parametrize(
    "call, words",
    [
        (lambda vnl, run: vnl.make(["ant_run"]), "name is a string"),
        (lambda vnl, run: vnl.make(None), "name is a string"),
        (lambda vnl, run: vnl.load_policy(None), "run_dir must be the path"),
        (lambda vnl, run: vnl.load_policy(run, deterministic="no"), "deterministic must be True or False"),
        (lambda vnl, run: vnl.policy.load_run(run, env_set="env_config.incline=5"), "env_set must be a list"),
        (lambda vnl, run: vnl.policy.load_run(run, env_set=[3]), "env_set must be a list"),
        (lambda vnl, run: vnl.policy.load_run(run, env=object()), "env must be a vnl Env"),
    ],
)
def test_the_api_s_other_arguments_are_checked(tmp_path, call, words):
    import vnl

    with pytest.raises(VnlError, match=words):
        call(vnl, _run(tmp_path))


# --- size-like config keys are bounded ------------------------------------------------------------

BIG_STAGES = "curriculum=[" + ", ".join(["{steps: 1}"] * 1001) + "]"


@pytest.mark.parametrize(
    "env, assignment, words",
    [
        ("ant_run", "network.core_size=100000000", ["core_size", "65,536", "smaller recurrent core"]),
        ("ant_run", "network.policy_hidden_layer_sizes=[70000]", ["policy_hidden_layer_sizes", "65,536", "smaller"]),
        ("ant_run", "network.cnn_channels=[10000, 64, 64]", ["cnn_channels", "4,096", "smaller"]),
        ("ant_run", "network.cnn_kernel_sizes=[1000, 4, 3]", ["cnn_kernel_sizes", "512", "smaller"]),
        ("ant_run", "ppo.num_minibatches=100000000", ["num_minibatches", "65,536", "fewer minibatches"]),
        ("ant_run", "ppo.unroll_length=1000000", ["unroll_length", "10,000", "shorter unrolls"]),
        ("ant_run", "ppo.num_updates_per_batch=1000000", ["num_updates_per_batch", "10,000", "fewer"]),
        ("ant_run", "ppo.action_repeat=100000", ["action_repeat", "1,000", "fewer times"]),
        ("ant_run", "ppo.num_evals=10000000", ["num_evals", "100,000", "less often"]),
        ("ant_run", f"ppo.num_timesteps={2**62 + 1}", ["num_timesteps", "4,611,686,018,427,387,904"]),
        (
            "ant_run",
            "ppo={batch_size: 1048576, num_minibatches: 256, unroll_length: 10}",
            ["batch_size × num_minibatches × unroll_length", "2,147,483,648", "make one of them smaller"],
        ),
        ("find_target", "vision.chunk=100000000", ["chunk", "65,536", "smaller chunk"]),
        ("ant_run", "log.video_width=10000", ["video_width", "4,096", "10,000"]),
        ("cue_memory", "env_config.episode_length=100000000", ["episode_length", "10,000,000"]),
        ("ant_run_gaps", "env_config.ground_scan=[" + ", ".join(["0.1"] * 2000) + "]", ["ground_scan", "1,024"]),
        ("ant_escape_bowl", "env_config.terrain_scan=[" + ", ".join(["[0, 0]"] * 2000) + "]", ["terrain_scan"]),
        ("ant_run_gaps", "env_config.corridor.max_geom_pairs=10000000", ["max_geom_pairs", "100,000"]),
        ("ant_run", BIG_STAGES, ["curriculum", "1,000 (each builds its own world)", "merge stages"]),
    ],
    ids=lambda v: v if len(str(v)) < 40 else str(v)[:40],
)
def test_size_like_config_keys_are_bounded_with_the_key_the_bound_and_the_fix(env, assignment, words, capsys):
    """A huge `network.core_size` was caught only by the disk estimate, after the env was built;
    the others not at all (or by the memory running out). Checked by `--print-config`: before
    anything is built."""
    line = _one_error(["train", env, "--preset", "tiny", "--print-config", "--set", assignment], capsys, *words)
    assert "; " in line.split("vnl: error: ", 1)[1], line  # the fix, after the problem


def test_the_nwb_export_checks_its_output_before_building_the_file(tmp_path):
    """`vnl.neuro.nwb.write` built the whole NWB file in memory before its write failed on a
    missing folder or a directory in the way; now nothing of the recording is read first."""
    pytest.importorskip("pynwb")
    from vnl.neuro import nwb

    (tmp_path / "a_dir.nwb").mkdir()
    for path, words in [
        (tmp_path / "missing" / "rec.nwb", "does not exist"),
        (tmp_path / "a_dir.nwb", "is a directory"),
        (tmp_path / "rec.nwb" / "x.nwb", "does not exist"),
    ]:
        with pytest.raises(VnlError, match=words):
            nwb.write(None, path)  # the recording is not looked at


@pytest.mark.slow
def test_a_resume_refused_for_a_checkpoint_of_another_setup_writes_nothing(tmp_path, point_envs):
    """The training state was checked against the env only after the lock was taken, the later
    checkpoints set aside and metrics.jsonl cut back (found by the fuzz of a copy made of links)."""
    from vnl.train import trainer

    run = tmp_path / "run"
    run.mkdir()
    config = train_config.build("test_point", "tiny", {"env_config": {"impl": "c"}, "log": {"video": False}})
    config_lib.dump_yaml(train_config.resolved(config), str(run / layout.CONFIG))
    metrics_io.rewrite(run / layout.METRICS, [{"step": 0}, {"step": 10}])
    checkpoint.save(run, 0, PARAMS, 0, ARRAYS, _meta(0))  # arrays of another setup
    checkpoint.save(run, 10, PARAMS, 0, ARRAYS, _meta(10))
    before = snapshot(run)
    with pytest.raises(VnlError, match="does not match this env and config"):
        trainer.resume(run, 0, say=lambda line: None)
    assert snapshot(run) == before


@pytest.mark.slow
def test_a_real_resume_of_a_cp_as_copy_finishes_and_leaves_the_original_as_it_was(tmp_path, point_envs, capsys):
    """`vnl train --resume COPY` of a run copied with `cp -as`: it continues (config.yaml
    rewritten for the new length, metrics appended, checkpoints rotated, the learning curve
    redrawn) and its original keeps every byte, mode and mtime."""
    import subprocess

    from vnl import cli

    orig, copy = tmp_path / "orig", tmp_path / "copy"
    train = ["train", "test_point", "--preset", "tiny", "--set", "env_config.impl=c", "--no-video"]
    sets = ["--set", "ppo.num_evals=3", "--set", "log.keep_checkpoints=1"]
    assert cli.main([*train, *sets, "--steps", "2048", "--out", str(orig)]) == 0
    subprocess.run(["cp", "-as", str(orig), str(copy)], check=True)
    before = snapshot(orig)
    assert cli.main(["train", "--resume", str(copy), "--steps", "4096"]) == 0
    assert snapshot(orig) == before
    steps = [r["step"] for r in metrics_io.read(copy / layout.METRICS)]
    assert steps[-1] == 4096 and steps == sorted(set(steps))
    assert config_lib.load_yaml(str(copy / layout.CONFIG))["ppo"]["num_timesteps"] == 4096
    for name in (layout.CONFIG, layout.METRICS, layout.LOCK, layout.LEARNING_CURVE):
        assert stat.S_ISREG((copy / name).lstat().st_mode), name
    capsys.readouterr()
