"""Warm starts (`--init-from`), lineage plots and curricula, on the point-mass test env."""

import json
import shutil

import numpy as np
import pytest
import yaml

from vnl.cli import main
from vnl.errors import VnlError
from vnl.io import checkpoint, plot
from vnl.io import metrics as metrics_io
from vnl.train import config as train_config
from vnl.train import config_changes, trainer, warm_start

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("curriculum"), pytest.mark.usefixtures("point_envs")]

# Tiny preset: 16 envs × 4 minibatches × 8 steps = 512 env steps per training step.
K = 1024
QUIET = {"video": False, "progress": False}
# MuJoCo C physics: the point mass's PPO programs compile in about half the time of MJX's.
PPO = {"num_timesteps": K, "num_evals": 2, "learning_rate": 3e-3}
SETTINGS = {"ppo": PPO, "log": QUIET, "env_config": {"impl": "c"}}
# Two stages of K steps, evaluated every 512 steps; the episode length shows which stage's env
# is evaluated (ppo.episode_length null: the env's own).
CURRICULUM = {
    "ppo": {"num_evals": 5, "learning_rate": 3e-3, "episode_length": None},
    "log": QUIET,
    "curriculum": [
        {"name": "near", "steps": K, "env_config": {"target": 0.5, "episode_length": 20, "impl": "c"}},
        {"name": "far", "steps": K, "env_config": {"target": 1.0, "episode_length": 40, "impl": "c"}},
    ],
}


def quiet(_):
    pass


def tree_arrays(run_dir, step=None):
    _, params = checkpoint.load(run_dir, step)
    import jax

    return [np.asarray(x) for x in jax.tree.leaves(params)]


def untimed(records):
    timing = ("wall_time", "env_steps_per_sec", "training/sps", "training/walltime", "eval/walltime", "eval/sps")
    return [{k: v for k, v in r.items() if k not in timing and not k.endswith("_time")} for r in records]


@pytest.fixture(scope="module", autouse=True)
def compile_cache(tmp_path_factory):
    """The persistent compilation cache (on by default in the CLI): a resumed run or a run of the
    same env config loads the programs compiled for the first instead of compiling them again."""
    from vnl import compile_cache

    compile_cache.enable(tmp_path_factory.mktemp("jax-cache"))
    yield
    compile_cache.disable()


@pytest.fixture(scope="module")
def parent(tmp_path_factory):
    out = tmp_path_factory.mktemp("parent") / "run"
    trainer.train(train_config.build("test_point", "tiny", file_values=SETTINGS), out, say=quiet)
    return out


def child_config(parent_dir, keep_optimizer=False, **env_config):
    values = {**SETTINGS, "init": {"run": str(parent_dir), "keep_optimizer": keep_optimizer}}
    values["env_config"] = {**SETTINGS["env_config"], **env_config}
    return train_config.build("test_point", "tiny", file_values=values)


@pytest.fixture(scope="module")
def child(parent, tmp_path_factory):
    """A run warm-started from `parent` on another env config (the target at 0.5 m, not 1 m)."""
    out = tmp_path_factory.mktemp("child") / "run"
    trainer.train(child_config(parent, target=0.5), out, say=quiet)
    return out


COUNT = ".training.optimizer_state[0].count"
MU = ".training.optimizer_state[0].mu.policy['params']['hidden_0']['kernel']"


def test_warm_start_begins_with_the_parents_networks(parent, child):
    # The child's untrained checkpoint (step 0) holds the parent's final networks and normalizer.
    for a, b in zip(tree_arrays(parent), tree_arrays(child, 0), strict=True):
        np.testing.assert_array_equal(a, b)
    _, theirs, _ = checkpoint.load_train_state(parent)
    _, ours, _ = checkpoint.load_train_state(child, 0)
    assert int(ours[COUNT]) == 0 and int(theirs[COUNT]) > 0  # a fresh optimizer
    assert not ours[MU].any() and theirs[MU].any()
    assert int(ours[".training.env_steps.lo"]) == 0  # the child counts its own steps
    saved = yaml.safe_load((child / "config.yaml").read_text())
    parent_config = train_config.build("test_point", "tiny", file_values=SETTINGS)
    assert saved["init"]["run"] == str(parent.absolute()) and saved["init"]["step"] == K
    assert saved["init"]["config_hash"] == warm_start.config_hash(train_config.resolved(parent_config))
    assert saved["env_config"]["target"] == 0.5
    # The child trained on from there: its final networks differ from the parent's.
    assert any(not np.array_equal(a, b) for a, b in zip(tree_arrays(parent), tree_arrays(child), strict=True))


def test_keep_optimizer_takes_the_parents_adam_state(parent):
    from vnl.envs import registry
    from vnl.ppo.loop import PPOLoop

    config = child_config(parent, keep_optimizer=True)
    loop = PPOLoop(registry.make("test_point", **config.env_config), config)
    fresh = loop.init(config.seed)
    state = warm_start.apply(loop, fresh, warm_start.load_parent(config), keep_optimizer=True)
    ours = loop.to_arrays(state)
    _, theirs, _ = checkpoint.load_train_state(parent)
    for k, v in theirs.items():
        if k.startswith((".training.params", ".training.normalizer_params", ".training.optimizer_state")):
            np.testing.assert_array_equal(ours[k], v, err_msg=k)
    assert int(ours[COUNT]) > 0 and int(ours[".training.env_steps.lo"]) == 0
    np.testing.assert_array_equal(ours[".env.obs"], loop.to_arrays(fresh)[".env.obs"])  # its own envs


def test_warm_start_with_an_added_sensor_begins_as_the_parent(parent, tmp_path, capsys):
    """A child whose observation adds an entry (`target`) to the parent's: the first layers take
    the parent's weights for the old inputs and zeros for the new one, the normalizer mean 0 and
    std 1 there, so the child's step-0 policy acts exactly as the parent's; then it trains."""
    import jax
    import jax.numpy as jp

    from vnl.envs import registry
    from vnl.ppo.loop import PPOLoop

    config = child_config(parent, observe_target=True)
    env = registry.make("test_point", **config.env_config)
    grown = warm_start.check_layout(warm_start.load_parent(config), env, "test_point")
    assert grown.input_rows.tolist() == [0, 1, -1] and grown.new_inputs == ("target (1)",)
    loop = PPOLoop(env, config)
    ours = loop.to_arrays(warm_start.apply(loop, loop.init(config.seed), grown, keep_optimizer=False))
    _, theirs, _ = checkpoint.load_train_state(parent)
    for net in ("policy", "value"):
        kernel = f".training.params.{net}['params']['hidden_0']['kernel']"
        np.testing.assert_array_equal(ours[kernel][:2], theirs[kernel])
        assert ours[kernel].shape[0] == 3 and not ours[kernel][2].any()
    mean, std = ours[".training.normalizer_params.mean"], ours[".training.normalizer_params.std"]
    np.testing.assert_array_equal(mean[:2], theirs[".training.normalizer_params.mean"])
    assert (mean[2], std[2]) == (0.0, 1.0)
    # The same actions as the parent's policy, whatever the new input says.
    from vnl import policy as policy_lib

    act = policy_lib.load_policy(parent, deterministic=True)
    obs = np.asarray([[0.3, -0.1], [-0.5, 0.2]], np.float32)
    child_obs = np.concatenate([obs, [[7.0], [-3.0]]], axis=1)
    key = jax.random.PRNGKey(0)
    with pytest.raises(VnlError, match="drop --keep-optimizer"):
        warm_start.apply(loop, loop.init(config.seed), grown, keep_optimizer=True)
    out = tmp_path / "child"
    trainer.train(config, out, say=print)
    assert "new observation entries target (1)" in capsys.readouterr().out
    child_act = policy_lib.load_policy(out, step=0, deterministic=True)
    np.testing.assert_allclose(child_act(jp.asarray(child_obs), key), act(jp.asarray(obs), key), atol=1e-6)
    # Entries added anywhere are matched by name and width, in order; a dropped or resized entry is not.
    a, b, c = ("a", 2), ("b", 1), ("c", 3)
    assert warm_start.grown_inputs([a, b], [c, a, ("n", 1), b])[0].tolist() == [-1, -1, -1, 0, 1, -1, 2]
    assert warm_start.grown_inputs([a, b], [a, c])[0] is None
    assert warm_start.grown_inputs([a, b], [a, ("b", 2)])[0] is None


def test_warm_start_errors_are_one_line_before_anything_is_written(parent, tmp_path, capsys):
    out = tmp_path / "x"
    flags = ["--preset", "tiny", "--out", str(out), "--no-video", "--no-compile-cache"]
    # Another env with another observation and action layout: the sizes are named.
    assert main(["train", "ant_run", *flags, "--init-from", str(parent)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("vnl: error:")
    assert "width 2 and give 1 actions" in err and "ant_run has observations of width 27 and 8 actions" in err
    # Other network sizes than the parent's.
    warm = ["train", "test_point", *flags, "--init-from", str(parent)]
    assert main([*warm, "--set", "network.policy_hidden_layer_sizes=[8]"]) == 2
    assert "network.policy_hidden_layer_sizes [16, 16] vs [8]" in capsys.readouterr().err
    assert main([*warm, "--step", "7"]) == 2
    assert "no checkpoint at step 7" in capsys.readouterr().err
    assert main(["train", "test_point", *flags, "--step", "0"]) == 2
    assert "--step needs --init-from" in capsys.readouterr().err
    assert main(["train", "--resume", str(parent), "--init-from", str(parent)]) == 2
    assert "use one of them" in capsys.readouterr().err
    assert not out.exists()
    # Given right, it trains, and the summary calls step 0 the warm start, not untrained.
    assert main(warm) == 0
    said = capsys.readouterr().out
    assert "(warm start) -> " in said and "(untrained)" not in said


def test_lineage_plot_draws_the_parent_then_the_child(parent, child, tmp_path):
    grandchild = tmp_path / "grandchild"
    trainer.train(child_config(child, target=0.5), grandchild, say=quiet)  # the child's programs: cached
    assert plot.lineage(grandchild) == [(parent.absolute(), K), (child.absolute(), K), (grandchild, None)]
    # A moved parent is found next to its child by name.
    moved = tmp_path / "moved"
    moved.mkdir()
    shutil.copytree(child, moved / "child")
    shutil.copytree(grandchild, moved / "grandchild")
    yaml_path = moved / "grandchild" / "config.yaml"
    saved = yaml.safe_load(yaml_path.read_text())
    saved["init"]["run"] = str(tmp_path / "gone" / "child")
    yaml_path.write_text(yaml.safe_dump(saved))
    assert plot.lineage(moved / "grandchild")[1][0] == moved / "child"
    out = tmp_path / "lineage.png"
    assert main(["plot", str(moved / "grandchild"), str(parent), "--lineage", "--out", str(out)]) == 0
    assert out.stat().st_size > 5000
    shutil.rmtree(moved / "child")
    with pytest.raises(VnlError, match="parent of .* has no metrics.jsonl"):
        plot.lineage(moved / "grandchild")


def test_lineage_plot_labels_a_parent_named_like_its_child(parent, child, tmp_path, monkeypatch):
    # Parent and child are both called `run`: the legend tells them apart by their folders.
    from matplotlib.figure import Figure

    figures = []
    monkeypatch.setattr(Figure, "savefig", lambda self, *args, **kwargs: figures.append(self))
    plot.compare_runs([child], "reward", tmp_path / "x.png", lineage=True)
    legend = [t.get_text() for t in figures[0].axes[0].get_legend().get_texts()]
    assert legend == [f"{parent.parent.name}/run (parent)", f"{child.parent.name}/run"]


@pytest.fixture(scope="module")
def staged(tmp_path_factory):
    """An uninterrupted two-stage run: evaluations at 0, 512, 1024 (stage 1), 1536, 2048 (stage 2)."""
    out = tmp_path_factory.mktemp("curriculum") / "run"
    config = train_config.build("test_point", "tiny", file_values=CURRICULUM)
    messages = []
    trainer.train(config, out, say=messages.append)
    return out, messages


def test_curriculum_trains_each_stage_in_its_env(staged):
    out, messages = staged
    records = metrics_io.read(out / "metrics.jsonl")
    assert [r["step"] for r in records] == [0, 512, 2 * 512, 3 * 512, 4 * 512]
    assert [r["curriculum/stage"] for r in records] == [0, 0, 0, 1, 1]
    # Evaluated in each stage's env: its episode length.
    assert [r["eval/avg_episode_length"] for r in records] == [20, 20, 20, 40, 40]
    assert any("curriculum stage 2/2 (far) from step 1,024" in m for m in messages)
    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert saved["ppo"]["num_timesteps"] == 2 * K and [s["name"] for s in saved["curriculum"]] == ["near", "far"]
    _, arrays, _ = checkpoint.load_train_state(out)
    assert int(arrays[".curriculum_stage"]) == 1


@pytest.mark.parametrize("step", [2 * 512, 3 * 512])  # at the end of stage 1, inside stage 2
def test_curriculum_resumes_exactly_at_any_stage(staged, tmp_path, step):
    out, _ = staged
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    trainer.resume(copy, from_step=step, say=quiet)
    for a, b in zip(tree_arrays(out), tree_arrays(copy), strict=True):
        np.testing.assert_array_equal(a, b)
    _, sa, _ = checkpoint.load_train_state(out)
    _, sb, _ = checkpoint.load_train_state(copy)
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)
    assert untimed(metrics_io.read(copy / "metrics.jsonl")) == untimed(metrics_io.read(out / "metrics.jsonl"))


def test_a_resumed_curriculum_run_given_more_steps_extends_its_last_stage(staged, tmp_path):
    """`vnl train --resume RUN --steps N` on a curriculum run: the last stage trains on to N (its
    env: 40-step episodes), and the saved config's stages add up to N; fewer steps than the last
    stage's start is one line."""
    out, _ = staged
    copy = tmp_path / "longer"
    shutil.copytree(out, copy)
    trainer.resume(copy, flags={"ppo": {"num_timesteps": 3 * K}}, say=quiet)
    records = metrics_io.read(copy / "metrics.jsonl")
    assert untimed(records[:5]) == untimed(metrics_io.read(out / "metrics.jsonl"))
    assert [r["step"] for r in records[5:]] == [5 * 512, 6 * 512]
    assert [(r["curriculum/stage"], r["eval/avg_episode_length"]) for r in records[5:]] == [(1, 40), (1, 40)]
    saved = yaml.safe_load((copy / "config.yaml").read_text())
    assert [s["steps"] for s in saved["curriculum"]] == [K, 2 * K] and saved["ppo"]["num_timesteps"] == 3 * K
    with pytest.raises(VnlError, match="ends before the curriculum's last stage starts"):
        trainer.resume(copy, flags={"ppo": {"num_timesteps": 512}}, say=quiet)
    with pytest.raises(VnlError, match="num_timesteps"):  # one line, not a TypeError
        config_changes.resume_config(train_config.read_config(copy), ["ppo.num_timesteps=abc"], None)


def test_curriculum_config_errors_name_the_problem(staged):
    with pytest.raises(VnlError, match=r"sum of its stages' steps \(2,048\).*ppo.num_timesteps is 5,000"):
        train_config.build("test_point", "tiny", file_values=CURRICULUM, flags={"ppo": {"num_timesteps": 5000}})
    bad = json.loads(json.dumps(CURRICULUM))
    bad["curriculum"][1]["env_config"]["nope"] = 1
    with pytest.raises(VnlError, match=r"curriculum\[1\].env_config: test_point: unknown config key nope"):
        train_config.build("test_point", "tiny", file_values=bad)
    bad["curriculum"][1] = {"env_config": {}}
    with pytest.raises(VnlError, match="steps"):
        train_config.build("test_point", "tiny", file_values=bad)
    out, _ = staged
    with pytest.raises(VnlError, match="curriculum"):
        trainer.resume(out, assignments=["curriculum=[]"], say=quiet)


def test_an_env_preset_may_be_a_curriculum_whose_last_stage_is_the_users_task():
    """ant_run_gaps' cpu preset: no gaps, short gaps, then the env config the user asked for."""
    config = train_config.build("ant_run_gaps", "cpu")
    config.validate()
    stages = [config.stage(i).resolved_env_config().corridor.gap_length for i in range(len(config.curriculum))]
    assert stages == [(0.0, 0.0), (0.125, 0.25), (0.125, 0.5)]
    assert config.ppo.num_timesteps == sum(stage.steps for stage in config.curriculum)  # a frozen preset's stages
    longer = train_config.build("ant_run_gaps", "cpu", assignments=["env_config.corridor.gap_length=[0.5,1.0]"])
    assert longer.stage(len(longer.curriculum) - 1).resolved_env_config().corridor.gap_length == (0.5, 1.0)
    with pytest.raises(VnlError, match="sum of its stages' steps"):
        train_config.build("ant_run_gaps", "cpu", flags={"ppo": {"num_timesteps": 1000}}).validate()
    assert train_config.build("ant_run_gaps", "cpu", assignments=["curriculum=[]"]).curriculum == ()


def test_rodent_gaps_presets_run_gapless_with_a_bonus_then_gaps_without_it():
    """rodent_run_gaps' presets: the stages' gaps and bonus, the corridor seen, the user's last stage."""
    for preset, steps in (("cpu", 8_000_000), ("gpu", 32_000_000)):
        config = train_config.build("rodent_run_gaps", preset)
        config.validate()
        assert config.ppo.num_timesteps == steps and config.ppo.learning_rate_final == 0.0
        assert [stage.name for stage in config.curriculum] == ["no_gaps", "short_gaps", "gaps"]
        assert not config.curriculum[-1].env_config  # the last stage is the task as configured
        envs = [config.stage(i).resolved_env_config() for i in range(len(config.curriculum))]
        assert [e.corridor.gap_length for e in envs] == [(0.0, 0.0), (0.03, 0.1), (0.05, 0.2)]
        assert [e.healthy_reward for e in envs] == [0.2, 0.0, 0.0]
        for e in envs:
            assert e.observe_heading and e.observe_corridor and e.healthy_min_upright == 0.7071
            assert len(e.ground_scan) == 12 and e.impl == ("c" if preset == "cpu" else "jax")
    wider = train_config.build("rodent_run_gaps", "cpu", assignments=["env_config.corridor.gap_length=[0.1,0.3]"])
    assert wider.stage(2).resolved_env_config().corridor.gap_length == (0.1, 0.3)


def test_ant_gaps_cpu_preset_sees_a_small_depth_image_of_the_floor_only_with_vision():
    """With --vision, ant_run_gaps' cpu preset renders 16x16 depth from the ant's ground camera
    (affordable on a CPU: docs/experiments/vision-gaps.md); blind, the same preset has no pixels."""
    seeing = train_config.build("ant_run_gaps", "cpu", flags={"vision": {"enabled": True}})
    seeing.validate()
    sizes = seeing.make_env().observation_size
    assert {k: v for k, v in sizes.items() if k.startswith("pixels/")} == {"pixels/ground": (16, 16, 1)}
    assert not isinstance(train_config.build("ant_run_gaps", "cpu").make_env().observation_size, dict)


@pytest.fixture(scope="module")
def parent_seed1(tmp_path_factory):
    """`parent`'s config with another seed (its programs come from the compilation cache)."""
    out = tmp_path_factory.mktemp("parent1") / "run"
    trainer.train(train_config.build("test_point", "tiny", file_values=SETTINGS, flags={"seed": 1}), out, say=quiet)
    return out


def test_compare_networks_on_the_same_episodes(parent, parent_seed1, child, tmp_path, capsys):
    import jax

    from vnl import compare, record
    from vnl.analysis import open_recording
    from vnl.policy import load_run

    rec = record.write(record.record(load_run(parent), episodes=2, steps=20, seed=3), tmp_path / "record.nc")
    out = tmp_path / "cka.png"
    args = ["compare", str(parent), str(parent_seed1), str(child), "--recording", str(rec), "--out", str(out)]
    assert main([*args, "--no-compile-cache"]) == 0
    text = capsys.readouterr().out
    assert (
        "linear CKA on 40 steps" in text
        and f"{parent.parent.name}/run (rows) vs {parent_seed1.parent.name}/run" in text
    )
    assert "(columns)  (same model, other seed)" in text
    assert out.stat().st_size > 10_000
    result = json.loads(out.with_suffix(".json").read_text())
    assert [p["across_seeds"] for p in result["pairs"]] == [True, False, False]
    # The numbers: each network's layers recomputed on the recording, then CKA by its definition.
    ds = open_recording(rec)
    obs, mask = ds["observation"].values, ds["active"].values > 0
    acts = []
    for run_dir in (parent, child):
        activity, _ = record.network_activity(load_run(run_dir), obs, jax.random.PRNGKey(0))
        acts.append({k: np.asarray(v).reshape(2, 20, -1)[mask] for k, v in activity.items() if k != "action"})
    pair = result["pairs"][1]  # parent vs child
    assert pair["layers_a"][0] == "policy_hidden_0"
    for i, la in enumerate(pair["layers_a"]):
        for j, lb in enumerate(pair["layers_b"]):
            assert pair["similarity"][i][j] == pytest.approx(compare.linear_cka(acts[0][la], acts[1][lb]), rel=1e-6)
    # Own recording of the first network, RSA, a step of a run; bad input is one line.
    out = tmp_path / "rsa.png"
    args = ["compare", f"{parent}@0", str(parent), "--episodes", "2", "--steps", "10", "--rsa", "euclidean"]
    assert main([*args, "--out", str(out), "--no-compile-cache"]) == 0
    text = capsys.readouterr().out
    assert "RSA (Spearman of euclidean RDMs) on 20 steps" in text and "run@0 (rows) vs run (columns)\n" in text
    assert main(["compare", str(parent), "--no-compile-cache"]) == 2
    assert "at least two networks" in capsys.readouterr().err
    assert main(["compare", str(parent), f"{parent}@x", "--no-compile-cache"]) == 2
    assert "RUN_DIR@STEP" in capsys.readouterr().err


def test_a_warm_started_curriculum_builds_each_stages_world_once(parent, tmp_path, capsys):
    """`vnl train ENV --init-from RUN` with two stages and the final video: the camera check, the
    warm start's layout check, the disk estimate, the stages' loops and the video all use the
    run's two worlds, each built once (`vnl.train.worlds`)."""
    from vnl.tasks.contract import world_builds

    config = tmp_path / "stages.yaml"
    config.write_text(yaml.safe_dump({**CURRICULUM, "log": {"progress": False}}))
    before = world_builds()
    argv = ["train", "test_point", "--preset", "tiny", "--config", str(config), "--init-from", str(parent)]
    assert main([*argv, "--out", str(tmp_path / "run"), "--no-compile-cache"]) == 0
    assert world_builds() - before == 2
    said = capsys.readouterr().out
    assert said.count("[vnl] built the world of test_point (stage") == 2, said


def test_commands_after_training_use_the_env_of_the_checkpoints_stage(staged, tmp_path):
    """`vnl eval` of a curriculum run: a stage-1 checkpoint is evaluated in stage 1's env (20-step
    episodes), the last in stage 2's (40), each with one world built."""
    from vnl.tasks.contract import world_builds

    out, _ = staged
    for step, length in ((512, 20), (4 * 512, 40)):
        before = world_builds()
        assert main(["eval", str(out), "--step", str(step), "--episodes", "2", "--out", str(tmp_path / "e.json")]) == 0
        assert world_builds() - before == 1
        summary = json.loads((tmp_path / "e.json").read_text())
        assert summary["max_steps"] == length and summary["checkpoint_step"] == step
