"""Nothing lost and nothing silent (issue 47): the fast tests, at least one per item of the issue.

Each uses the real failure where the machine allows it: a run's lock held by a real open file, a
tmpfs that really fills up, a read-only bind mount, XLA's own error for a failing host function,
MuJoCo's own allocation failure. The tests that need subprocesses, training runs or SIGKILL are
in tests/test_durability.py (slow); the generated fuzz of the CLI is in tests/test_cli_fuzz.py.
"""

import errno
import json
import os
import stat
import time
from pathlib import Path

import numpy as np
import pytest
from fsutil import fill, read_only, tmpfs

from vnl import cli
from vnl import typed_config as config_lib
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.train import config as train_config
from vnl.train import rundir
from vnl.train.config_changes import task_variant

PARAMS = ({"mean": np.zeros(2, np.float32)}, {"w": np.ones(3, np.float32)}, {"w": np.ones(1, np.float32)})
ARRAYS = {".training.params.policy['w']": np.ones(3, np.float32), ".env.x": np.zeros(2, np.float32)}


def _meta(step: int) -> dict:
    return {"training_steps_per_epoch": 1, "record": {"step": step, "eval/episode_reward": float(step)}}


def _run(root: Path, name: str = "run") -> Path:
    """A run directory as `vnl train` leaves it (config, metrics, one checkpoint of toy arrays):
    enough for every command's checks, which run before anything reads the arrays."""
    run = root / name
    run.mkdir(parents=True)
    config_lib.dump_yaml(train_config.resolved(train_config.build("ant_run", "tiny")), str(run / "config.yaml"))
    metrics_io.rewrite(run / "metrics.jsonl", [{"step": 0, "eval/episode_reward": 1.0}])
    checkpoint.save(run, 0, PARAMS, 0, ARRAYS, _meta(0))
    return run


def _tree(root: Path) -> dict[str, tuple]:
    return {
        str(p.relative_to(root)): (p.is_dir(), p.lstat().st_size, p.lstat().st_mtime_ns)
        for p in sorted(root.rglob("*"))
    }


def _main(argv: list[str], capsys) -> tuple[int, list[str]]:
    """Runs `vnl argv` in this process: (exit code, the stderr lines)."""
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as e:  # argparse's own errors
        code = e.code
    return code, [line for line in capsys.readouterr().err.splitlines() if line.strip()]


def _one_error(argv: list[str], capsys, *words: str, code: int = 2) -> str:
    got, err = _main(argv, capsys)
    assert got == code and len(err) == 1 and err[0].startswith("vnl: error:"), (argv, got, err)
    for word in words:
        assert word in err[0], (argv, err[0])
    return err[0]


# --- 1. one writer per run ----------------------------------------------------------------------


def test_a_run_another_process_writes_is_refused_naming_it(tmp_path, capsys):
    """The lock is a real flock on an open file (a second open file description conflicts even
    in this process); `--resume` is refused before anything is imported, naming the holder."""
    from vnl.io import runlock

    run = _run(tmp_path)
    with runlock.hold(run):  # the lock file exists from the run's first session on
        pass
    before = _tree(tmp_path)
    with runlock.hold(run, command="vnl train --resume elsewhere"):
        assert runlock.holder(run)["pid"] == os.getpid()
        _one_error(["train", "--resume", run], capsys, f"process {os.getpid()}", "vnl train --resume elsewhere")
        with pytest.raises(VnlError, match="is being written by"), runlock.hold(run):
            pass
    assert runlock.holder(run) is None  # released with the file; nothing else changed
    assert {k: v for k, v in _tree(tmp_path).items() if ".vnl-lock" not in k} == {
        k: v for k, v in before.items() if ".vnl-lock" not in k
    }


# --- 2. non-finite and unchecked numbers --------------------------------------------------------


@pytest.mark.parametrize(
    "env, assignment, key",
    [
        ("ant_run", "ppo.entropy_cost=.nan", "entropy_cost"),
        ("ant_run", "ppo.entropy_cost=nan", "entropy_cost"),
        ("ant_run", "ppo.max_grad_norm=.inf", "max_grad_norm"),
        ("ant_run", "env_config.reset_noise_scale=1e999", "reset_noise_scale"),
        ("ant_run", "log.video_seconds=.inf", "video_seconds"),
        ("ant_run", "ppo.clipping_epsilon=0", "clipping_epsilon"),
        ("ant_run", "ppo.clipping_epsilon=2.5", "clipping_epsilon"),
        ("ant_run", "env_config.threads=100000", "threads"),
        ("ant_run", "seed=4294967296", "seed"),
        ("ant_run", "seed=99999999999999999999999", "seed"),
        ("ant_run", "ppo.num_eval_envs=100000000", "num_eval_envs"),
        ("ant_run", "network.policy_hidden_layer_sizes=[1000000]", "policy_hidden_layer_sizes"),
        ("ant_run", "log.video_seconds=1e9", "video_seconds"),
        ("ant_escape_bowl", "env_config.bowl.bump_scale=0", "bump_scale"),
        ("ant_escape_bowl", "env_config.bowl.terrain_seed=-1", "terrain_seed"),
        ("ant_run_gaps", "env_config.corridor.platform_length=[0.000000001, 1]", "platform_length"),
    ],
)
def test_non_finite_and_unchecked_numbers_are_one_line(env, assignment, key, capsys):
    _one_error(["train", env, "--print-config", "--set", assignment], capsys, key)


def test_non_finite_numbers_in_a_config_file_and_seeds_beyond_32_bits(tmp_path, capsys):
    path = tmp_path / "c.yaml"
    path.write_text("ppo:\n  learning_rate: .nan\n")
    _one_error(["train", "ant_run", "--config", path], capsys, "learning_rate", "finite")
    for command in (["train", "ant_run", "--print-config"], ["eval", tmp_path]):
        _one_error([*command, "--seed", str(2**64)], capsys, "--seed", "4294967295")
    with pytest.raises(VnlError, match="seed must be in 0..4294967295"):
        train_config.build("ant_run", "tiny", {"seed": 2**40})


# --- 3. config shapes that used to end in a traceback or a hang --------------------------------

BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{b}: &{b} [{', '.join([f'*{a}'] * 9)}]\n" for a, b in zip("abcdefgh", "bcdefghi", strict=True)
)


@pytest.mark.parametrize(
    "text, words",
    [
        ("ppo: 3\n", ["ppo"]),  # a scalar where a section goes (TypeError in build)
        ("1: 2\nzz: 3\n", ["key 1", "not a string"]),  # a non-string key (TypeError sorting the keys)
        ("ppo: {null: 1, zz: 2}\n", ["key None"]),
        (BOMB, ["expands to more than"]),  # the billion laughs: minutes and gigabytes, once expanded
        ("a: " + "[" * 5000 + "]" * 5000 + "\n", ["nested more than 64"]),  # RecursionError
        ("ppo: " + "{b: " * 5000 + "1" + "}" * 5000 + "\n", ["nested more than 64"]),
    ],
    ids=["scalar-section", "int-key", "null-key", "alias-bomb", "deep-lists", "deep-mappings"],
)
def test_config_shapes_are_one_line_and_fast(tmp_path, capsys, text, words):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    start = time.monotonic()
    _one_error(["train", "ant_run", "--print-config", "--config", path], capsys, *words)
    assert time.monotonic() - start < 10


def test_yaml_numbers_are_yaml_1_2_and_quoted_ones_stay_strings(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("ppo: {learning_rate: 3e-4}\nlog: {wandb_name: '1.0', wandb_project: '2e3'}\n")
    config = train_config.build("ant_run", "tiny", config_lib.load_yaml(str(path)))
    assert config.ppo.learning_rate == 3e-4
    assert (config.log.wandb_name, config.log.wandb_project) == ("1.0", "2e3")  # were floats, then refused


def test_plot_refuses_a_config_yaml_that_is_not_a_mapping(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("- a list\n- not a config\n")
    metrics_io.rewrite(run / "metrics.jsonl", [{"step": 0, "eval/episode_reward": 1.0}])
    _one_error(["plot", run, "--out", tmp_path / "x.png"], capsys, "config.yaml", "mapping")


def test_a_fifo_as_config_is_refused_without_blocking(tmp_path, capsys):
    fifo = tmp_path / "c.yaml"
    os.mkfifo(fifo)
    _one_error(["train", "ant_run", "--config", fifo], capsys, "not a regular file")


# --- 4. outputs checked before the work, also by default; file types ---------------------------


@pytest.mark.parametrize(
    "argv, words",
    [
        (["eval", "{run}", "--out", "{tmp}/x.txt"], [".json"]),
        (["render", "{run}", "--out", "{tmp}/x.gif"], [".mp4"]),
        (["record", "{run}", "--out", "{tmp}/x.rrd"], [".nc"]),
        (["plot", "{run}", "--out", "{tmp}/x.csv"], [".png"]),
        (["analyze", "{tmp}/rec.nc", "--out", "{tmp}/x"], [".png"]),
        (["view", "{tmp}/rec.nc", "--out", "{tmp}/x.nc"], [".rrd"]),
        (["compare", "{run}", "{run}", "--out", "{tmp}/x.json"], [".png"]),
        (["eval", "{run}", "--out", "{tmp}/fifo.json"], ["not a regular file"]),
        (["eval", "{run}", "--out", "{tmp}/link.json"], ["symbolic link (to"]),  # issue 53: links, `.`
        (["render", "{run}", "--out", "{tmp}/dangling.mp4"], ["symbolic link (to nothing"]),
        (["train", "ant_run", "--out", "{tmp}/dangling"], ["symbolic link to nothing"]),
        (["eval", "{run}", "--out", "."], ["is a directory"]),
    ],
)
def test_output_file_types_are_checked(tmp_path, capsys, argv, words):
    run = _run(tmp_path)
    (tmp_path / "rec.nc").write_bytes(b"x")
    os.mkfifo(tmp_path / "fifo.json")
    (tmp_path / "link.json").symlink_to(tmp_path / "rec.nc")
    (tmp_path / "dangling.mp4").symlink_to(tmp_path / "nowhere.mp4")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    argv = [a.format(run=run, tmp=tmp_path) for a in argv]
    _one_error(argv, capsys, *words)


def test_default_outputs_on_a_read_only_run_are_refused_before_any_work(tmp_path, capsys):
    """A run on a read-only mount (an archive, a colleague's share): each command that would
    write its default output into it fails at once, not after its rollout or recording."""
    run = _run(tmp_path / "ro")
    (run / "rec.nc").write_bytes(b"x")
    with read_only(tmp_path / "ro"):
        for argv in (
            ["eval", run],
            ["render", run],
            ["record", run],
            ["view", run],
            ["view", run / "rec.nc"],
            ["plot", run],
            ["analyze", run / "rec.nc"],
            ["compare", run, run],
            ["train", "--resume", run],
        ):
            _one_error(argv, capsys, "read-only")
        # an --out elsewhere is fine: the check of eval passes (it then fails on the toy checkpoint)
        assert _main(["eval", run, "--out", tmp_path / "e.json", "--episodes", "1"], capsys)[0] != 0


# --- 5. overwrites ------------------------------------------------------------------------------


def test_a_new_run_never_overwrites_a_users_config_yaml(tmp_path, capsys):
    out = tmp_path / "exp"
    out.mkdir()
    (out / "config.yaml").write_text("# my notes\nppo: {num_envs: 16}\n")
    before = (out / "config.yaml").read_bytes()
    _one_error(["train", "ant_run", "--out", out], capsys, "already holds a run", "config.yaml")
    with pytest.raises(VnlError, match="already holds a run"):
        rundir.prepare_run_dir(out, train_config.build("ant_run", "tiny"))
    assert (out / "config.yaml").read_bytes() == before


def test_outputs_that_would_destroy_an_input_or_a_run_file_are_refused(tmp_path, capsys):
    run = _run(tmp_path)
    rec = tmp_path / "rec.rrd"
    rec.write_bytes(b"x")
    for argv, words in [
        (["record", run, "--out", tmp_path / "x.rrd", "--viewer"], [".nc"]),  # its .rrd would be --out
        (["view", rec, "--out", rec], ["input"]),  # view rec.nc --out rec.nc, once named .rrd
        (["plot", run, "--out", run / "learning_curve.png"], ["run directory"]),
        (["eval", run, "--out", run / "checkpoints" / "x.json"], ["run directory"]),
    ]:
        _one_error(argv, capsys, *words)
    assert rec.read_bytes() == b"x"


# --- 6. exceptions that escaped main() ----------------------------------------------------------


@pytest.mark.parametrize("value", ["bogus", "glx", "EGL"])
def test_a_bad_mujoco_gl_is_one_line(value, monkeypatch, capsys, tmp_path):
    """(The real import failure needs a fresh process: tests/test_cli_fuzz.py.)"""
    monkeypatch.setenv("MUJOCO_GL", value)
    _one_error(["eval", _run(tmp_path)], capsys, "MUJOCO_GL", value)


def test_a_host_function_s_memory_error_is_one_line_and_a_bug_keeps_its_own_traceback(capsys):
    """XLA turns an exception of an FFI host function into its own runtime error; the CLI
    reports the original: MemoryError as one line (exit 1), anything else re-raised as itself."""
    import jax
    import jax.numpy as jp

    from vnl.physics import ffi

    def oom(inputs, outputs):
        raise MemoryError("cannot allocate 9 TB")

    def bug(inputs, outputs):
        raise ZeroDivisionError("a bug")

    results = [jax.ShapeDtypeStruct((3,), jp.float32)]
    for fn, key in ((oom, 0x7E57_0001), (bug, 0x7E57_0002)):
        ffi.register(key, fn)
        with pytest.raises(Exception) as caught:
            jax.block_until_ready(jax.jit(lambda x, k=key: ffi.call(k, results, x)[0])(jp.zeros(3)))
        assert "JaxRuntimeError" in type(caught.value).__name__ or "XlaRuntimeError" in type(caught.value).__name__
        if fn is oom:
            assert cli._failed(caught.value) == 1
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and err[0].startswith("vnl: error: out of memory (cannot allocate 9 TB)")
        else:
            with pytest.raises(ZeroDivisionError, match="a bug"):
                cli._failed(caught.value)


def test_mujoco_s_own_allocation_failure_names_the_batch():
    """MuJoCo's batch of a billion simulations fails with C++'s bad_alloc (pybind11 raises it as
    ValueError); it is a VnlError naming the count and the fix."""
    import mujoco

    from vnl.physics import CPhysics

    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint type="slide"/><geom size=".1"/></body></worldbody></mujoco>'
    )
    with pytest.raises(VnlError, match=r"out of memory making 1,000,000,000 MuJoCo simulations.*fewer"):
        CPhysics(model, threads=1)._batch(10**9)


def test_a_full_disk_closing_or_writing_metrics_keeps_whole_lines_and_close_never_raises():
    """A real tmpfs filled to the last block: the write fails with ENOSPC, the file is cut back to
    its last whole line, later writes refuse, and close() does not raise (Python's buffered file
    raised ENOSPC again from close(), outside any handler)."""
    with tmpfs("1m") as root:
        path = root / "metrics.jsonl"
        writer = metrics_io.JsonlWriter(path)
        writer.write({"step": 0, "x": 1.0})
        fill(root)
        with pytest.raises(OSError) as caught:
            for step in range(1, 100):
                writer.write({"step": step, "x": "y" * 5000})
        assert caught.value.errno == errno.ENOSPC
        with pytest.raises(OSError):
            writer.write({"step": 100})
        writer.close()
        writer.close()
        assert path.read_bytes().endswith(b"\n")
        assert [r["step"] for r in metrics_io.read(path)] == [0]


def test_orbax_s_full_disk_value_error_is_a_storage_error(capsys):
    """orbax (tensorstore) reports a full disk as `ValueError: ... [os_error_code='28']`: it is
    found as ENOSPC, the partial checkpoint is removed and the CLI's line names it."""
    from vnl import errors

    with tmpfs("2m") as root:
        big = ({"mean": np.zeros(2, np.float32)}, {"w": np.random.default_rng(0).normal(size=2**20)}, {"w": np.ones(1)})
        with pytest.raises(ValueError) as caught:
            checkpoint.save(root / "run", 1, big, 0, None, _meta(1))
        assert errors.storage_error(caught.value).errno == errno.ENOSPC
        assert cli._failed(caught.value) == 1
        assert "No space left on device" in capsys.readouterr().err
        assert [p.name for p in (root / "run" / "checkpoints").iterdir()] == []


# --- 7. meta.json that parses but is wrong ------------------------------------------------------


@pytest.mark.parametrize(
    "meta, required",
    [
        ({}, ()),
        ([], ()),
        ("a string", ()),
        ({"step": 999, "training_steps_per_epoch": 1}, ()),  # another step's meta
        ({"step": 4}, ("training_steps_per_epoch",)),  # what a resume needs is missing
        ({"step": 4, "training_steps_per_epoch": "10"}, ()),
        ({"step": 4, "training_steps_per_epoch": 1, "record": [1]}, ()),
        ({"step": 4, "training_steps_per_epoch": 1, "observation_layout": {"a": 1}}, ()),
        ({"step": 4, "training_steps_per_epoch": 1, "format": 99}, ()),  # a newer vnl's
    ],
)
def test_a_meta_json_that_parses_but_is_wrong_falls_back_to_an_older_checkpoint(tmp_path, meta, required):
    checkpoint.save(tmp_path, 2, PARAMS, 0, ARRAYS, _meta(2))
    checkpoint.save(tmp_path, 4, PARAMS, 0, ARRAYS, _meta(4))
    (checkpoint.step_dir(tmp_path, 4) / checkpoint.META).write_text(json.dumps(meta))
    with pytest.warns(UserWarning, match="unreadable"):
        step, _, got = checkpoint.load_train_state(tmp_path, required=required)
    assert step == 2 and got["step"] == 2


def test_non_finite_parameters_are_never_saved_and_never_loaded(tmp_path):
    checkpoint.save(tmp_path, 2, PARAMS, 0, ARRAYS, _meta(2))
    bad = {**ARRAYS, ".training.params.policy['w']": np.array([1.0, np.nan, 0.0], np.float32)}
    with pytest.raises(ValueError, match="non-finite"):
        checkpoint.save(tmp_path, 4, PARAMS, 0, bad, _meta(4))
    assert checkpoint.steps(tmp_path) == [2]
    checkpoint.save(tmp_path, 4, PARAMS, 0, ARRAYS, _meta(4))  # then NaN on disk (a run of an older vnl)
    np.savez(checkpoint.step_dir(tmp_path, 4) / checkpoint.TRAIN_STATE, **bad)
    with pytest.warns(UserWarning, match="non-finite"):
        assert checkpoint.load_train_state(tmp_path)[0] == 2


# --- 8. durability ------------------------------------------------------------------------------


class _Recorder:
    """Records os.open/os.fsync/os.rename/os.replace as (op, path), the fsync of a descriptor as
    the path it was opened with."""

    def __init__(self, monkeypatch):
        self.ops: list[tuple[str, str]] = []
        self._paths: dict[int, str] = {}
        real_open, real_fsync, real_rename, real_replace = os.open, os.fsync, os.rename, os.replace

        def open_(path, flags, *args, **kwargs):
            fd = real_open(path, flags, *args, **kwargs)
            self._paths[fd] = os.path.abspath(path)
            return fd

        def fsync(fd):
            self.ops.append(("fsync", self._paths.get(fd if isinstance(fd, int) else fd.fileno(), "?")))
            return real_fsync(fd)

        def rename(src, dst, *args, **kwargs):
            self.ops.append(("rename", os.path.abspath(dst)))
            return real_rename(src, dst, *args, **kwargs)

        def replace(src, dst, *args, **kwargs):
            self.ops.append(("rename", os.path.abspath(dst)))
            return real_replace(src, dst, *args, **kwargs)

        for name, fn in (("open", open_), ("fsync", fsync), ("rename", rename), ("replace", replace)):
            monkeypatch.setattr(os, name, fn)

    def check_every_rename_is_followed_by_its_dir_fsync(self) -> int:
        renames = [i for i, (op, _) in enumerate(self.ops) if op == "rename"]
        for i in renames:
            parent = os.path.dirname(self.ops[i][1])
            later = self.ops[i + 1 :]
            upto = next((j for j, (op, _) in enumerate(later) if op == "rename"), len(later))
            assert ("fsync", parent) in later[:upto], (self.ops[i], later[:upto])
        return len(renames)


def test_every_rename_is_followed_by_an_fsync_of_its_directory(tmp_path, monkeypatch):
    checkpoint.save(tmp_path, 2, PARAMS, 1, ARRAYS, _meta(2))
    rec = _Recorder(monkeypatch)
    checkpoint.save(tmp_path, 2, PARAMS, 1, ARRAYS, _meta(2))  # replaces step 2
    checkpoint.save(tmp_path, 4, PARAMS, 1, ARRAYS, _meta(4))  # rotates step 2 out
    config_lib.dump_yaml({"a": 1}, str(tmp_path / "config.yaml"))
    metrics_io.rewrite(tmp_path / "metrics.jsonl", [{"step": 0}])
    assert rec.check_every_rename_is_followed_by_its_dir_fsync() >= 7
    # the new checkpoint's files were fsynced before it was renamed into place
    final = str(checkpoint.step_dir(tmp_path, 4))
    at = rec.ops.index(("rename", final))
    synced = {path for op, path in rec.ops[:at] if op == "fsync"}
    for name in (checkpoint.TRAIN_STATE, checkpoint.META):
        assert any(p.endswith(f"/.tmp-000000000004-{os.getpid()}/{name}") for p in synced), name
    assert any("/params/" in p and p.endswith("_METADATA") for p in synced)  # orbax's own files
    assert ("fsync", str(tmp_path / ".config.tmp-")) not in rec.ops  # (names are unique, not fixed)


def test_backups_and_superseded_checkpoints_never_reuse_a_name(tmp_path):
    """Two resumes within one second: each keeps its own metrics backup and its own folder of
    superseded checkpoints (the second backup overwrote the first; the second folder's mkdir
    raised FileExistsError)."""
    records = [{"step": s, "wall_time": float(s)} for s in (0, 10, 20)]
    for rewind in (10, 0):
        metrics_io.rewrite(tmp_path / "metrics.jsonl", records)
        rundir.truncate_metrics(tmp_path, rewind, None, lambda s: None)
    assert len(list(tmp_path.glob("metrics.jsonl.*.bak"))) == 2
    for step in (2, 4, 6):
        checkpoint.save(tmp_path, step, PARAMS, 0, ARRAYS, _meta(step))
    rundir.set_aside_later_checkpoints(tmp_path, 4, lambda s: None)
    checkpoint.save(tmp_path, 6, PARAMS, 0, ARRAYS, _meta(6))
    rundir.set_aside_later_checkpoints(tmp_path, 2, lambda s: None)
    aside = sorted(p.name for p in checkpoint.checkpoint_dir(tmp_path).glob("superseded-*"))
    assert len(aside) == 2 and checkpoint.steps(tmp_path) == [2]


# --- 9. runs pinned to their inputs -------------------------------------------------------------


def test_a_user_walker_file_is_recorded_absolute_with_its_hash(tmp_path, monkeypatch):
    from vnl.walkers.from_file import file_sha256

    xml = tmp_path / "models" / "my_ant.xml"
    xml.parent.mkdir()
    xml.write_text('<mujoco><worldbody><body name="torso"><geom size=".1"/></body></worldbody></mujoco>')
    monkeypatch.chdir(tmp_path)
    config = train_config.build("run", "tiny", {"env_config": {"walker_xml": "models/my_ant.xml"}})
    saved = train_config.resolved(config)
    assert saved.env_config["walker_xml"] == str(xml) and saved.env_config["walker_xml_sha256"] == file_sha256(xml)
    run = tmp_path / "run"
    run.mkdir()
    config_lib.dump_yaml(saved, str(run / "config.yaml"))
    monkeypatch.chdir("/")
    assert train_config.read_config(run).env_config["walker_xml"] == str(xml)  # found from anywhere
    xml.write_text(xml.read_text().replace("</mujoco>", "<!-- edited --></mujoco>"))
    with pytest.raises(VnlError, match="not the file this run was trained with"):
        train_config.read_config(run)


def test_an_imitations_clips_file_is_recorded_absolute_with_its_hash(tmp_path, monkeypatch):
    import shutil

    from vnl.tasks import imitate
    from vnl.walkers.from_file import file_sha256

    clips = tmp_path / "data" / "my_clips.h5"
    clips.parent.mkdir()
    shutil.copy(imitate.DATA / "rodent_clips.h5", clips)
    monkeypatch.chdir(tmp_path)
    config = train_config.build("rodent_imitate", "tiny", {"env_config": {"clips": "data/my_clips.h5"}})
    saved = train_config.resolved(config)
    assert saved.env_config["clips"] == str(clips) and saved.env_config["clips_sha256"] == file_sha256(clips)
    run = tmp_path / "run"
    run.mkdir()
    config_lib.dump_yaml(saved, str(run / "config.yaml"))
    monkeypatch.chdir("/")
    assert train_config.read_config(run).env_config["clips"] == str(clips)  # found from anywhere
    # Evaluating on other clips is a variant, not the run's file changed.
    other = tmp_path / "other.h5"
    shutil.copy(clips, other)
    with open(other, "ab") as f:
        f.write(b"\0")
    variant = task_variant(train_config.read_config(run), [f"env_config.clips={other}"])
    assert variant.env_config["clips"] == str(other) and variant.env_config["clips_sha256"] == ""
    with open(clips, "ab") as f:
        f.write(b"\0")  # the same name, other bytes
    with pytest.raises(VnlError, match="not the file this run was trained on"):
        train_config.read_config(run)


def test_a_warm_start_from_a_config_whose_parent_changed_is_refused(tmp_path):
    from vnl.train import warm_start

    parent = _run(tmp_path, "parent")
    recorded = warm_start.config_hash(train_config.read_config(parent))
    init = {"run": str(parent), "config_hash": recorded}
    child = train_config.build("ant_run", "tiny", {"init": init})
    assert warm_start.load_parent(child).step == 0
    values = config_lib.load_yaml(str(parent / "config.yaml"))
    values["ppo"]["entropy_cost"] = 0.5  # the parent was edited (or is another run of that name)
    config_lib.dump_yaml(values, str(parent / "config.yaml"))
    with pytest.raises(VnlError, match="init.config_hash"):
        warm_start.load_parent(child)


# --- 10. exposure -------------------------------------------------------------------------------


def test_both_rerun_viewers_listen_on_localhost_only():
    from vnl.cli.cmd_view import viewer_command

    for web in (False, True):
        command = viewer_command(Path("x.rrd"), web)
        assert command[command.index("--bind") + 1] == "127.0.0.1", command


@pytest.mark.parametrize("how", ["world-writable", "group-writable", "not owned"])
def test_a_compilation_cache_others_can_write_is_refused(tmp_path, capsys, how):
    import argparse

    import jax

    from vnl.cli import process

    cache = tmp_path / "cache"
    cache.mkdir()
    if how == "not owned":
        if os.geteuid() != 0:
            pytest.skip("giving a directory to another user needs root")
        os.chown(cache, 65534, 65534)
    else:
        cache.chmod(0o777 if how == "world-writable" else 0o770)
    before = jax.config.jax_compilation_cache_dir
    process.compilation_cache(argparse.Namespace(no_compile_cache=False, compile_cache=str(cache)))
    out = capsys.readouterr().out
    assert "[vnl] compilation cache off" in out and ("writable by other" in out or "another user" in out), out
    assert jax.config.jax_compilation_cache_dir == before
    fresh = tmp_path / "fresh" / "jax"
    process.compilation_cache(argparse.Namespace(no_compile_cache=False, compile_cache=str(fresh)))
    try:
        assert stat.S_IMODE(fresh.stat().st_mode) == 0o700 and jax.config.jax_compilation_cache_dir == str(fresh)
    finally:
        from vnl import compile_cache

        compile_cache.disable()
        if before is not None:
            compile_cache.enable(before)


def test_a_disabled_or_moved_compilation_cache_is_no_longer_written(tmp_path, monkeypatch):
    """JAX opens its cache once per process: `disable()` and a second `enable()` must reach it, or
    every later compile in the process is written to the first directory."""
    import jax

    from vnl import compile_cache

    def compile_once(n):
        jax.jit(lambda x: x * n + 1.0).lower(jax.numpy.ones(n)).compile()

    def entries(path):
        return sorted(p.name for p in path.iterdir() if not p.name.startswith("."))

    before = jax.config.jax_compilation_cache_dir
    monkeypatch.setattr(compile_cache, "MIN_COMPILE_SECONDS", 0.0)
    first, second = tmp_path / "first", tmp_path / "second"
    try:
        compile_cache.enable(first)
        compile_once(3)
        written = entries(first)
        assert written, "the cache wrote nothing: the test cannot tell a disabled cache apart"
        compile_cache.disable()
        compile_once(5)
        assert entries(first) == written
        compile_cache.enable(second)
        compile_once(7)
        assert entries(first) == written and entries(second)
    finally:
        compile_cache.disable()
        if before is not None:
            compile_cache.enable(before)


# --- the foundation ---------------------------------------------------------------------------


def test_write_atomic_leaves_the_old_file_when_the_writer_fails(tmp_path):
    from vnl import durable

    path = tmp_path / "a.png"
    path.write_bytes(b"old")

    def broken(tmp):
        Path(tmp).write_bytes(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OSError):
        durable.write_atomic(path, writer=broken)
    assert path.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["a.png"]
