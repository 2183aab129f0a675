"""A recording of several tasks (`vnl.recording.stack`) and the cross-task analysis
(`vnl analyze --method tasks`) on synthetic recordings with planted structure: one layer codes the
behaviour the same way in every task, one codes it differently per task, one carries the task."""

import functools
import json

import numpy as np
import pytest
import xarray as xr

from vnl.cli import main
from vnl.errors import VnlError
from vnl.neuro import tasks as tasks_method
from vnl.neuro.registry import Options
from vnl.recording import stack

E, DT, J, K, U = 4, 0.02, 6, 5, 12
FREQS = (1.0, 2.0, 4.0, 7.0, 12.0)  # one movement per behaviour
TASKS = ("run", "forage", "touch")


@pytest.fixture(autouse=True)
def fewer_repeats(monkeypatch):
    monkeypatch.setattr(tasks_method, "CONTROL_REPEATS", 8)


def behaviour_blocks(rng, steps, occupancy):
    """(steps,) behaviour labels in blocks of 0.8-1.6 s, drawn with `occupancy` (K,)."""
    out, t = np.zeros(steps, int), 0
    while t < steps:
        n = int(rng.integers(40, 80))
        out[t : t + n], t = rng.choice(K, p=occupancy), t + n
    return out


def task_recording(i, steps, rng, codes, extra=None, occupancy=None):
    """One task's recording: joints oscillating at the behaviour's frequency; layers
    `policy_hidden_0` (the same code of the behaviour in every task), `policy_hidden_1` (a code
    of its own per task), `value_hidden_0` (noise plus a constant per task)."""
    occupancy = np.roll(np.array([0.3, 0.25, 0.2, 0.15, 0.1]), i) if occupancy is None else occupancy
    label = np.stack([behaviour_blocks(rng, steps, occupancy) for _ in range(E)])
    phase = 2 * np.pi * np.cumsum(np.asarray(FREQS)[label] * DT, axis=1)
    angle = np.sin(phase[..., None] + np.linspace(0, np.pi, J)) + 0.05 * rng.normal(size=(E, steps, J))
    onehot = np.eye(K)[label]
    noise = lambda: 0.3 * rng.normal(size=(E, steps, U))  # noqa: E731
    et = ("episode", "time")
    data = {
        "active": (et, np.ones((E, steps))),
        "joint_angle": (et + ("joint",), angle),
        "com_velocity": (et + ("axis",), 0.01 * rng.normal(size=(E, steps, 3))),
        "policy_hidden_0": (et + ("policy_hidden_0_unit",), onehot @ codes["shared"] + noise()),
        "policy_hidden_1": (et + ("policy_hidden_1_unit",), onehot @ codes["own"][i] + noise()),
        "value_hidden_0": (et + ("value_hidden_0_unit",), codes["offset"][i] + noise()),
        "body_pos": (et + ("body", "xyz"), np.zeros((E, steps, 2 + i, 3))),  # arenas differ
        "joint_limit": (("joint",), np.arange(J, dtype=float)),  # one per joint, not per step
        **(extra or {}),
    }
    coords = {"episode": np.arange(E), "time": np.arange(steps) * DT, "joint": [f"j{j}" for j in range(J)],
              "axis": ["x", "y", "z"], "body": [f"b{j}" for j in range(2 + i)], "xyz": ["x", "y", "z"]}  # fmt: skip
    attrs = {
        "env": "synthetic_suite",
        "checkpoint_step": 7,
        "control_dt": DT,
        "env_set": json.dumps([f"env_config.task={TASKS[i]}"]),
    }
    return xr.Dataset(data, coords=coords, attrs=attrs)


def stacked(seed=0, steps=(400, 300, 350)):
    rng = np.random.default_rng(seed)
    codes = {
        "shared": 2 * rng.normal(size=(K, U)),
        "own": [2 * rng.normal(size=(K, U)) for _ in TASKS],
        "offset": [3 * rng.normal(size=U) for _ in TASKS],
    }
    extra = {"gap_distance": (("episode", "time"), np.ones((E, steps[0])), {"units": "m"})}
    parts = {name: task_recording(i, n, rng, codes, extra if i == 0 else None)
             for i, (name, n) in enumerate(zip(TASKS, steps, strict=True))}  # fmt: skip
    return stack.stack_tasks(parts), parts


def test_stacking_keeps_what_the_tasks_share_and_pads_the_shorter_episodes():
    ds, parts = stacked()
    assert stack.tasks(ds) == list(TASKS) and ds.sizes["episode"] == 3 * E and ds.sizes["time"] == 400
    assert stack.episode_tasks(ds).tolist() == [0] * E + [1] * E + [2] * E
    assert "body_pos" not in ds and json.loads(ds.attrs["dropped"]) == ["body_pos"]
    assert np.asarray(ds["active"].values[E : 2 * E, 300:]).sum() == 0  # the second task's 300 steps, padded
    assert np.asarray(ds["active"].values[E : 2 * E, :300]).all()
    np.testing.assert_array_equal(
        ds["policy_hidden_0"].values[E : 2 * E, :300], parts["forage"]["policy_hidden_0"].values
    )
    gap = ds["gap_distance"].values
    assert (gap[:E] == 1).all() and np.isnan(gap[E:]).all()  # one task's variable, NaN in the others'
    assert "env_set" not in ds.attrs and ds.attrs["control_dt"] == DT and ds.attrs["checkpoint_step"] == 7
    assert ds["gap_distance"].attrs == {"units": "m"}  # a variable's attributes, from the task that has it
    assert ds["joint_limit"].dims == ("joint",)  # not repeated per episode
    np.testing.assert_allclose(ds["time"].values, np.arange(400) * DT)
    assert json.loads(ds.attrs["env_sets"])["touch"] == ["env_config.task=touch"]


def test_stacking_refuses_recordings_of_different_networks_and_a_single_task():
    _, parts = stacked()
    other = dict(parts, touch=parts["touch"].drop_vars("value_hidden_0"))
    with pytest.raises(VnlError, match="different layers"):
        stack.stack_tasks(other)
    with pytest.raises(VnlError, match="two recordings"):
        stack.stack_tasks({"run": parts["run"]})
    slower = parts["touch"].assign_attrs(control_dt=2 * DT)
    with pytest.raises(VnlError, match="other control steps"):
        stack.stack_tasks(dict(parts, touch=slower))


def test_the_planted_invariant_task_specific_and_task_carrying_layers_are_told_apart():
    ds, _ = stacked()
    r = tasks_method.analyze(ds, Options(states=K))
    shared, own, tonic = (r.summary(n) for n in ("policy_hidden_0", "policy_hidden_1", "value_hidden_0"))
    # the same code of behaviour in every task: as similar across tasks as within one, above the control
    assert shared["cross_task_rsa"] > 0.8 and shared["within_task_rsa"] > 0.8
    assert shared["cross_task_rsa"] > shared["control_cross_task_rsa_95"]
    # a code of its own per task: reliable within a task, not across tasks
    assert own["within_task_rsa"] > 0.8 and own["cross_task_rsa"] < 0.5
    # a constant per task: most units task-modulated; the behaviour code's units few
    assert tonic["task_modulated_fraction"] >= 0.75 and tonic["median_eta2"] > 0.5
    assert shared["task_modulated_fraction"] <= 0.25
    assert r.shares.shape == (K, 3) and np.allclose(r.shares.sum(0), 1)
    # a pair of tasks has a cross-task RSA where halves of each share 4 behaviours or more (10 steps each)
    iu = np.triu_indices(3, 1)
    assert r.shared.max() <= K
    np.testing.assert_array_equal(np.isnan(r.cross_rsa["policy_hidden_0"][iu]), r.shared[iu] < 4)


def test_a_unit_coding_behaviour_alone_is_not_task_modulated_when_the_tasks_show_other_behaviours():
    """Two tasks that show the behaviours in very different proportions, one layer coding the
    behaviour alone: its units' variance differs between the tasks through the behaviour (raw eta²
    of the task high), and the method, which removes each behaviour's mean first, finds them not
    task-modulated."""
    rng = np.random.default_rng(1)
    codes = {"shared": 2 * rng.normal(size=(K, U)), "own": [2 * rng.normal(size=(K, U))] * 2,
             "offset": [np.zeros(U)] * 2}  # fmt: skip
    mostly = [np.array([0.45, 0.45, 0.04, 0.03, 0.03]), np.array([0.03, 0.03, 0.04, 0.45, 0.45])]
    parts = {n: task_recording(i, 600, rng, codes, occupancy=mostly[i]) for i, n in enumerate(TASKS[:2])}
    ds = stack.stack_tasks(parts)
    r = tasks_method.analyze(ds, Options(states=K, layer="policy_hidden_0"))
    # tasks that share no behaviour: no cross-task RSA, and the report says why
    apart = [np.array([0.5, 0.5, 0, 0, 0]), np.array([0, 0, 0, 0.5, 0.5])]
    parts = {n: task_recording(i, 300, rng, codes, occupancy=apart[i]) for i, n in enumerate(TASKS[:2])}
    few = tasks_method.analyze(stack.stack_tasks(parts), Options(states=K, layer="policy_hidden_0"))
    assert few.shared[0, 1] < 4 and few.summary("policy_hidden_0")["cross_task_rsa"] is None
    assert f"run and forage share at most {few.shared[0, 1]}" in tasks_method.report(few)
    # the confound is there: on the raw activity most units would pass the same permutation control
    x, labels = ds["policy_hidden_0"].values.reshape(-1, U), stack.episode_tasks(ds)
    raw = tasks_method.eta_squared(x, np.repeat(labels, 600))
    rng = np.random.default_rng(0)
    null = [tasks_method.eta_squared(x, np.repeat(rng.permutation(labels), 600)) for _ in range(20)]
    assert np.mean(raw > np.percentile(null, 95)) >= 1 / 3
    assert r.summary("policy_hidden_0")["task_modulated_fraction"] <= 0.1


def test_a_recording_of_one_task_is_refused_and_the_cli_writes_figure_and_json(tmp_path, capsys):
    ds, parts = stacked()
    with pytest.raises(VnlError, match="holds one task"):
        tasks_method.analyze(parts["run"], Options(states=K))
    with pytest.raises(VnlError, match="2 episodes of every task"):
        tasks_method.analyze(ds.isel(episode=[0, 4, 5, 8, 9]), Options(states=K))
    with pytest.raises(VnlError, match="6 ways to assign the tasks"):  # 2 tasks x 2 episodes: too few for the control
        tasks_method.analyze(
            stack.stack_tasks({t: parts[t].isel(episode=[0, 1]) for t in TASKS[:2]}), Options(states=K)
        )
    path = tmp_path / "rec.nc"
    ds.to_netcdf(path)
    assert main(["analyze", str(path), "--method", "tasks", "--states", str(K)]) == 0
    out = capsys.readouterr().out
    assert "tasks: run, forage, touch" in out and "policy_hidden_1: task-modulated units" in out
    doc = json.loads((tmp_path / "tasks.json").read_text())
    assert doc["tasks"] == list(TASKS) and set(doc["layers"]) == {
        "policy_hidden_0",
        "policy_hidden_1",
        "value_hidden_0",
    }
    assert doc["layers"]["policy_hidden_0"]["cross_task_rsa_by_pair"].keys() == {
        "run|forage",
        "run|touch",
        "forage|touch",
    }
    assert (tmp_path / "tasks.png").stat().st_size > 10_000


def test_the_embedding_of_several_tasks_is_coloured_by_task_and_says_which_task_owns_each_behaviour(monkeypatch):
    from vnl.neuro import embedding

    monkeypatch.setattr(embedding, "MAX_POINTS", 300)
    ds, _ = stacked()
    result = embedding.analyze(ds, Options(states=K))
    assert result.color_by == "task" and result.task_names == list(TASKS)
    for k, b in enumerate(result.behaviours()):  # each task's share of the behaviour's steps
        mine = result.labels == k
        assert b["task_share"] == pytest.approx({t: np.mean(result.color[mine] == i) for i, t in enumerate(TASKS)})
        of_task = {t: np.mean(mine[result.color == i]) for i, t in enumerate(TASKS)}
        assert b["share_of_task"] == pytest.approx(of_task) and "mean_task" not in b
    # the steps are those of every task's active steps, coloured by their episode's task
    np.testing.assert_array_equal(result.color, stack.episode_tasks(ds)[result.episode])
    assert np.bincount(result.color.astype(int)).tolist() == [E * 400, E * 300, E * 350]
    other = embedding.analyze(ds, Options(states=K, color="gap_distance"))
    assert other.task_names == [] and "task_share" not in other.behaviours()[0]


def test_what_needs_one_world_or_one_gait_refuses_a_recording_of_several_tasks(tmp_path, capsys):
    from vnl.neuro import rhythm
    from vnl.recording import nwb

    ds, _ = stacked()
    path = tmp_path / "rec.nc"
    ds.to_netcdf(path)
    assert main(["record", "--from", str(path), "--format", "nwb"]) == 2
    assert "an NWB file holds one task" in capsys.readouterr().err and not (tmp_path / "rec.nwb").exists()
    with pytest.raises(VnlError, match="holds one task"):
        nwb.write(ds, tmp_path / "direct.nwb")
    with pytest.raises(VnlError, match="run, forage, touch.*--task NAME"):
        rhythm.analyze(ds, Options())


def test_one_task_of_a_stacked_recording_is_that_tasks_recording_and_every_method_takes_it(tmp_path, capsys):
    ds, parts = stacked()
    one = stack.select(ds, "forage")  # the second task: 300 of the stack's 400 steps
    assert one.sizes == {**dict(one.sizes), "episode": E, "time": 300} and "task" not in one
    for k in ("policy_hidden_0", "policy_hidden_1", "value_hidden_0", "joint_angle", "com_velocity"):
        np.testing.assert_array_equal(one[k].values, parts["forage"][k].values)
    assert one["active"].values.all() and "gap_distance" not in one  # the first task's variable is left out
    assert "gap_distance" in stack.select(ds, "run") and stack.select(ds, "run").sizes["time"] == 400
    assert stack.tasks(one) == [] and json.loads(one.attrs["env_set"]) == ["env_config.task=forage"]
    assert "tasks" not in one.attrs and one.attrs["control_dt"] == DT
    with pytest.raises(VnlError, match="no task 'jump': it holds run, forage, touch"):
        stack.select(ds, "jump")
    with pytest.raises(VnlError, match="holds one task"):
        stack.select(one, "forage")
    # each task's gait is referred to another foot: the stack leaves gait_phase out, a task's own is made again
    from vnl.recording import behaviour

    rng, feet = np.random.default_rng(1), ["hand_L", "foot_R"]
    for i, (name, part) in enumerate(parts.items()):
        contact = rng.random((E, part.sizes["time"], 2)) < 0.5
        contact[..., i % 2] |= rng.random(contact.shape[:2]) < 0.5  # the reference foot touches down most
        foot, parts[name]["gait_phase"] = behaviour.reference_gait(contact, np.ones(contact.shape[:2], bool), feet)
        parts[name]["foot_contact"] = (("episode", "time", "end_effector"), contact.astype(float))
        parts[name] = parts[name].assign_coords(end_effector=feet).assign_attrs(gait_reference_foot=foot)
    gaits = stack.stack_tasks(parts)
    assert "gait_phase" not in gaits and "gait_phase" in json.loads(gaits.attrs["dropped"])
    for name in ("run", "forage"):
        again = stack.select(gaits, name)
        np.testing.assert_array_equal(again["gait_phase"].values, parts[name]["gait_phase"].values)
        assert again.attrs["gait_reference_foot"] == parts[name].attrs["gait_reference_foot"]
    path = tmp_path / "rec.nc"
    ds.to_netcdf(path)
    argv = ["analyze", str(path), "--method", "encoding", "--features", "joint_angle", "--folds", "2"]
    assert main([*argv, "--layer", "policy_hidden_1", "--task", "touch"]) == 0
    doc = json.loads((tmp_path / "encoding_touch.json").read_text())
    assert (tmp_path / "encoding_touch.png").is_file() and "policy_hidden_1" in json.dumps(doc)
    capsys.readouterr()
    for argv, said in (
        (["--task", "jump"], "no task 'jump': it holds run, forage, touch"),
        (["--method", "tasks", "--task", "run"], "--method tasks compares the tasks"),
    ):
        assert main(["analyze", str(path), *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("vnl: error:") and said in err and "Traceback" not in err


def rotating(rng, freq, steps, episodes=4, units=6):
    """(episodes, steps, units): a damped-free rotation at `freq` Hz in a random plane of the
    units, from a random phase per episode, plus noise."""
    basis = np.linalg.qr(rng.normal(size=(units, units)))[0][:, :2]
    phase = rng.uniform(0, 2 * np.pi, (episodes, 1)) + 2 * np.pi * freq * DT * np.arange(steps)
    plane = np.stack([np.cos(phase), np.sin(phase)], -1)
    return plane @ basis.T + 0.02 * rng.normal(size=(episodes, steps, units))


def test_dsa_across_tasks_tells_the_same_dynamics_from_other_dynamics(tmp_path, capsys, monkeypatch):
    from vnl.neuro import task_dynamics

    rng = np.random.default_rng(3)
    parts = {}
    for name, freq in (("run", 1.0), ("forage", 1.0), ("touch", 3.5)):
        x = rotating(rng, freq, 120)
        parts[name] = xr.Dataset(
            {"active": (("episode", "time"), np.ones(x.shape[:2])),
             "policy_hidden_0": (("episode", "time", "policy_hidden_0_unit"), x)},
            coords={"episode": np.arange(4), "time": np.arange(120) * DT}, attrs={"control_dt": DT},
        )  # fmt: skip
    ds = stack.stack_tasks(parts)
    result = task_dynamics.dynamics(ds, "policy_hidden_0", n_delays=3, rank=2, iters=400)
    same, other = result.cross[0, 1], result.cross[0, 2]
    assert result.within.max() < 0.05 and same < 0.05, (result.within, same)  # the same rotation, other samples
    assert other > 0.2, (other, same, result.within)  # another frequency
    assert result.to_json()["cross_task"].keys() == {"run|forage", "run|touch", "forage|touch"}
    assert "run | touch" in task_dynamics.report(result)
    with pytest.raises(VnlError, match="delays \\+ 2"):
        task_dynamics.dynamics(ds.isel(time=slice(0, 4)), "policy_hidden_0", n_delays=3, rank=2)
    with pytest.raises(VnlError, match="holds one task"):
        task_dynamics.dynamics(parts["run"], "policy_hidden_0")
    with pytest.raises(VnlError, match="touch has 1 episode"):
        task_dynamics.dynamics(ds.isel(episode=[0, 1, 4, 5, 8]), "policy_hidden_0", n_delays=3, rank=2)

    # the same from the command line: every layer (here one), a heatmap and its JSON
    monkeypatch.setattr(task_dynamics, "dynamics", functools.partial(task_dynamics.dynamics, iters=400))
    path = tmp_path / "rec.nc"
    ds.to_netcdf(path)
    assert main(["analyze", str(path), "--method", "dynamics", "--delays", "3", "--rank", "2"]) == 0
    assert "run | touch: 0.31" in capsys.readouterr().out
    doc = json.loads((tmp_path / "dynamics.json").read_text())["layers"]["policy_hidden_0"]
    assert doc["cross_task"]["run|forage"] < 0.05 < 0.2 < doc["cross_task"]["forage|touch"] and doc["rank"] == 2
    assert (tmp_path / "dynamics.png").stat().st_size > 10_000
    assert main(["analyze", str(path), "--method", "dynamics", "--rank", "200"]) == 2
    assert "no layer has units x --delays >= --rank (200)" in capsys.readouterr().err
