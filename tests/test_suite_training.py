"""One network trained on a suite's tasks (vnl.envs.suite, vnl.ppo.suite_loop): each task evaluated
on its own and averaged, a resume through a compact checkpoint bit-exact, the recurrent loop, the
final videos and `vnl eval` per task, and the settings a suite refuses."""

import json

import numpy as np
import pytest
from test_compact_checkpoints import KEPT, assert_same_run, physics_fields, quiet
from two_devices import ROOT, run_on_two_devices

from vnl.cli import main
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.io.video import read_mp4
from vnl.train import config as train_config
from vnl.train import rundir, trainer

pytestmark = [pytest.mark.usefixtures("point_envs")]

K = 1024  # tiny preset: 2 training steps of 512 env steps


def config(**values):
    base = {
        "ppo": {"num_timesteps": 2 * K, "num_evals": 3, "episode_length": None},
        # episodes of 12 and 9 steps end inside a training step, so every member auto-resets
        "env_config": {"test_point": {"episode_length": 12}, "test_plane": {"episode_length": 9}, "shares": [1, 3]},
        "log": {"video": False, "progress": False},
    }
    for key, value in values.items():
        base[key] = {**base.get(key, {}), **value}
    return train_config.build("test_suite", "tiny", file_values=base)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    run = tmp_path_factory.mktemp("suite") / "reference"
    trainer.train(config(), run, say=quiet)
    return run


@pytest.mark.slow
@pytest.mark.xdist_group("suite")
def test_each_task_is_evaluated_on_its_own_and_the_run_reports_their_mean(reference):
    records = metrics_io.read(reference / "metrics.jsonl")
    assert [r["step"] for r in records] == [0, K, 2 * K]
    for r in records:
        point, plane = r["eval/test_point/episode_reward"], r["eval/test_plane/episode_reward"]
        assert r["eval/episode_reward"] == pytest.approx((point + plane) / 2)
        # each evaluated on its own episode length: 12 and 9 steps
        assert r["eval/test_point/avg_episode_length"] == 12 and r["eval/test_plane/avg_episode_length"] == 9
        assert point != plane


@pytest.mark.slow
@pytest.mark.xdist_group("suite")
def test_a_suite_resumes_bit_exact_through_a_compact_checkpoint(reference, tmp_path):
    run = tmp_path / "run"
    trainer.train(config(ppo={"num_timesteps": K, "num_evals": 2}), run, say=quiet)
    _, arrays, _ = checkpoint.load_train_state(run)
    assert physics_fields(arrays) == set()  # no physics state at the top: it lives per member
    members = {
        name: {k.split(".data.")[-1].removeprefix("_impl.").split(".")[0] for k in arrays if f"['{name}'].data." in k}
        for name in ("test_point", "test_plane")
    }
    assert members == {"test_point": KEPT["c"], "test_plane": KEPT["c"]}
    rows = {name: arrays[f".env.info['tasks']['{name}'].data.qpos"].shape for name in members}
    assert rows == {"test_point": (4, 1), "test_plane": (12, 2)}  # 16 envs split 1:3, each its own nq
    held = sum(v.nbytes for k, v in arrays.items() if k.startswith(".env"))
    assert 16 * rundir.env_state_bytes(config().make_env()) == held  # the size estimate, to the byte
    trainer.resume(run, flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    assert_same_run(run, reference)


@pytest.mark.slow
@pytest.mark.xdist_group("suite")
def test_a_checkpoint_keeps_of_each_member_what_it_reads_and_resumes_after_the_reads_change(
    reference, tmp_path, monkeypatch
):
    """A member whose reads are unknown (None) keeps its whole physics state; the other stays
    compact. Resumed once both are known (a checkpoint holding more than the reads: the union of
    reads suites kept before 2026-11-28 evening), the run goes on bit for bit."""
    import tiny_env

    run = tmp_path / "run"
    with monkeypatch.context() as m:
        m.setattr(tiny_env.PlaneMass, "previous_state_reads", None)
        trainer.train(config(ppo={"num_timesteps": K, "num_evals": 2}), run, say=quiet)
        held = sum(v.nbytes for k, v in checkpoint.load_train_state(run)[1].items() if k.startswith(".env"))
        assert 16 * rundir.env_state_bytes(config().make_env()) == held  # the estimate, per member
    _, arrays, _ = checkpoint.load_train_state(run)
    point = {k.split(".data.")[-1].removeprefix("_impl.").split(".")[0] for k in arrays if "['test_point'].data." in k}
    plane = {k.split(".data.")[-1].removeprefix("_impl.").split(".")[0] for k in arrays if "['test_plane'].data." in k}
    assert point == KEPT["c"] and plane > KEPT["c"]
    trainer.resume(run, flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    assert_same_run(run, reference)


@pytest.mark.slow
@pytest.mark.xdist_group("suite")
def test_vnl_eval_evaluates_every_task_or_the_one_named(reference, capsys):
    out = reference / "eval_all.json"
    assert main(["eval", str(reference), "--episodes", "2", "--out", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert set(summary["tasks"]) == {"test_point", "test_plane"}
    assert summary["tasks"]["test_plane"]["max_steps"] == 9 and summary["tasks"]["test_point"]["max_steps"] == 12
    means = [summary["tasks"][t]["episode_reward"]["mean"] for t in ("test_point", "test_plane")]
    assert summary["episode_reward"] == pytest.approx(np.mean(means))
    one = reference / "eval_plane.json"
    args = ["eval", str(reference), "--episodes", "2", "--set", "env_config.task=test_plane", "--out", str(one)]
    assert main(args) == 0
    alone = json.loads(one.read_text())
    assert "tasks" not in alone and alone["episode_reward"] == summary["tasks"]["test_plane"]["episode_reward"]


@pytest.mark.slow
@pytest.mark.xdist_group("suite")
def test_vnl_record_records_every_task_into_one_recording_or_the_one_named(reference, capsys):
    import xarray as xr

    from vnl.recording import stack

    out, one = reference / "rec_all.nc", reference / "rec_plane.nc"
    assert main(["record", str(reference), "--episodes", "2", "--out", str(out)]) == 0
    assert (
        main(["record", str(reference), "--episodes", "2", "--out", str(one), "--set", "env_config.task=test_plane"])
        == 0
    )
    with xr.open_dataset(out) as ds, xr.open_dataset(one) as alone:
        assert stack.tasks(ds) == ["test_point", "test_plane"] and stack.episode_tasks(ds).tolist() == [0, 0, 1, 1]
        assert ds.sizes["time"] == 12 and alone.sizes["time"] == 9  # each task its own episode length
        assert "qpos" in json.loads(ds.attrs["dropped"])  # nq 1 and 2: not stacked
        assert stack.tasks(alone) == [] and "task" not in alone
        for name in ("policy_hidden_0", "observation", "action"):  # the same policy on the same episodes
            np.testing.assert_array_equal(ds[name].values[2:, :9], alone[name].values, err_msg=name)
        assert ds["observation"].shape[-1] == alone["observation"].shape[-1]  # the suite's one layout
    assert main(["record", str(reference), "--episodes", "2", "--out", str(reference / "rec.nwb")]) == 2
    assert "an NWB file holds one task" in capsys.readouterr().err
    assert not (reference / "rec.nwb").exists()
    # the viewer draws one world: a task's own recording or the run with the task named
    assert main(["view", str(out), "--out", str(reference / "all.rrd")]) == 2
    assert "view one task" in capsys.readouterr().err and not (reference / "all.rrd").exists()
    assert main(["view", str(reference), "--out", str(reference / "v.rrd"), "--steps", "5", "--no-camera"]) == 2
    assert "--set env_config.task=" in capsys.readouterr().err
    args = ["view", str(reference), "--set", "env_config.task=test_plane", "--steps", "5", "--no-camera"]
    assert main([*args, "--out", str(reference / "plane.rrd")]) == 0
    assert main(["view", str(one), "--out", str(reference / "plane_rec.rrd"), "--no-camera"]) == 0


@pytest.mark.slow
@pytest.mark.xdist_group("suite")
def test_vnl_compare_shows_the_networks_every_task_or_the_one_named(reference, capsys):
    both, plane = reference / "cmp_all.png", reference / "cmp_plane.png"
    args = ["compare", f"{reference}@0", str(reference), "--episodes", "2"]
    assert main([*args, "--out", str(both)]) == 0
    assert main([*args, "--set", "env_config.task=test_plane", "--out", str(plane)]) == 0
    both, plane = (json.loads(p.with_suffix(".json").read_text()) for p in (both, plane))
    assert both["observations"] == "2 episodes of each task of reference@0 (seed 0)"
    assert both["samples"] == 2 * 12 + 2 * 9  # every step of both tasks' episodes, each its own length
    assert plane["observations"] == "2 episodes of reference@0 (seed 0) (env_config.task=test_plane)"
    assert plane["samples"] == 2 * 9
    # --set makes a new recording's task: not with episodes already recorded
    assert main(["record", str(reference), "--episodes", "2", "--out", str(reference / "cmp_rec.nc")]) == 0
    capsys.readouterr()
    assert main([*args, "--recording", str(reference / "cmp_rec.nc"), "--set", "env_config.task=test_plane"]) == 2
    assert "--set chooses the task of a new recording" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.xdist_group("suite")
def test_a_recurrent_network_trains_on_a_suite_and_final_videos_are_per_task(tmp_path):
    run = tmp_path / "gru"
    sets = ["network.core=gru", "network.core_size=8", "ppo.num_evals=2", "log.video_seconds=0.2"]
    assert (
        main(
            ["train", "test_suite", "--preset", "tiny", "--steps", str(K), "--out", str(run)]
            + [a for s in sets for a in ("--set", s)]
        )
        == 0
    )
    last = metrics_io.read(run / "metrics.jsonl")[-1]
    assert last["step"] == K and np.isfinite(last["eval/test_point/episode_reward"])
    assert np.isfinite(last["eval/test_plane/episode_reward"])
    for task in ("test_point", "test_plane"):
        assert read_mp4(str(run / f"final_policy_{task}.mp4")).shape[0] >= 2
    assert not (run / "final_policy.mp4").exists()


@pytest.mark.parametrize(
    "values, words",
    [
        ({"vision": {"enabled": True}}, "cannot train with --vision"),
        ({"randomize": {"friction": [0.5, 1.5]}}, "cannot train with randomize"),
        ({"network": {"architecture": "intention"}}, "cannot train with network.architecture: intention"),
        ({"ppo": {"num_eval_envs": 3}}, "multiple of its 2 tasks"),
        ({"ppo": {"num_envs": 18, "batch_size": 18}}, "sum of their shares"),
    ],
)
def test_what_a_suite_cannot_train_with_is_refused_before_anything_is_built(values, words):
    with pytest.raises(VnlError, match=words):
        config(**values)


def test_one_task_of_a_suite_is_evaluated_not_trained(tmp_path):
    with pytest.raises(VnlError, match="picks one task of test_suite"):
        trainer.train(config(env_config={"task": "test_point"}), tmp_path / "run", say=quiet)
    assert not (tmp_path / "run").exists()


SUITE_ON_TWO_DEVICES = """
import json, sys
sys.path.insert(0, {tests!r})
import tiny_env; tiny_env.register()
import jax
import test_suite_training as t
from vnl.train import trainer
trainer.train(t.config(ppo={{"num_timesteps": t.K, "num_evals": 2}}), {run!r}, say=lambda _: None)
print("RESULT" + json.dumps({{"devices": jax.device_count()}}))
"""


@pytest.mark.slow
@pytest.mark.xdist_group("suite")
def test_a_suite_trained_on_two_devices_resumes_on_one_with_each_row_its_members(tmp_path):
    """A suite's first epoch on two (emulated) devices, each holding its share of both tasks, then
    the run resumed on this process's one device: the checkpoint's observation rows are member-major
    (every test_point row before every test_plane row, 1:3), each task evaluated on its own in both."""
    script = SUITE_ON_TWO_DEVICES.format(tests=str(ROOT / "tests"), run=str(tmp_path / "run"))
    assert run_on_two_devices(script)[0] == {"devices": 2}
    _, arrays, _ = checkpoint.load_train_state(tmp_path / "run")
    obs = arrays[".env.obs"]
    task = obs[:, -2:]  # the suite's one-hot task block: (1, 0) test_point, (0, 1) test_plane
    n = len(obs)
    assert n % 8 == 0 and task[: n // 4].tolist() == [[1.0, 0.0]] * (n // 4), task
    assert task[n // 4 :].tolist() == [[0.0, 1.0]] * (3 * n // 4), task
    trainer.resume(tmp_path / "run", flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    records = metrics_io.read(tmp_path / "run" / "metrics.jsonl")
    assert [r["step"] for r in records] == [0, K, 2 * K]
    for r in records:
        assert r["eval/test_point/avg_episode_length"] == 12 and r["eval/test_plane/avg_episode_length"] == 9
