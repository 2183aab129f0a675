"""benchmarks/gap_sequence.py, the seed's experiment: its test task, its networks, its tables, and
every network's activity replayed on the shared episodes."""

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import gap_sequence  # noqa: E402  (benchmarks/ on the path above)

from vnl import typed_config as config_lib  # noqa: E402
from vnl.train import config as train_config  # noqa: E402


def _run_dir(tmp_path: Path, preset: str = "cpu", assignments: tuple[str, ...] = ()) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    config = train_config.resolved(train_config.build("rodent_run_gaps", preset, assignments=list(assignments)))
    config_lib.dump_yaml(config, str(run / "config.yaml"))
    return run


def test_the_test_task_is_the_last_stage_for_every_key_a_stage_overrides(tmp_path):
    # The rat's cpu preset: a gapless stage with a bonus, short gaps, then the run's gaps (no overrides).
    run = _run_dir(tmp_path, assignments=("env_config.corridor.platform_length=[0.5,0.7]",))
    env_set = gap_sequence.test_task(run)
    assert env_set == ["env_config.corridor.gap_length=[0.05, 0.2]", "env_config.healthy_reward=0.0"]
    # The strings are `vnl record --set` values that make the last stage's env.
    from vnl.policy import read_config, task_variant

    config = read_config(run)
    variant = task_variant(config.stage(0), env_set).env_config
    assert variant == config.stage(2).env_config
    assert list(variant["corridor"]["platform_length"]) == [0.5, 0.7]  # the run's own setting stays


def test_a_run_without_stages_is_tested_on_its_own_task(tmp_path):
    assert gap_sequence.test_task(_run_dir(tmp_path, assignments=("curriculum=[]",))) == []


def test_networks_are_the_untrained_one_and_each_stages_last_checkpoint(tmp_path):
    run = _run_dir(tmp_path)
    records = [(0, 0), (500, 0), (1000, 0), (1500, 1), (2000, 2), (2500, 2)]
    lines = [json.dumps({"step": s, "curriculum/stage": k, "eval/episode_reward": 1.0}) for s, k in records]
    (run / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    for step in (0, 500, 1000, 1500, 2500):  # 2000 was not kept
        (run / "checkpoints" / f"{step:012d}").mkdir(parents=True)
    assert gap_sequence.networks(run) == {
        "untrained": 0,
        "after_no_gaps": 1000,
        "after_short_gaps": 1500,
        "after_gaps": 2500,
    }
    (run / "checkpoints" / f"{1500:012d}").rmdir()
    with pytest.raises(SystemExit, match="after_short_gaps"):
        gap_sequence.networks(run)


def test_the_decoding_table_shows_each_target_beside_its_controls():
    rows = [
        {"network": "a", "layer": "policy_hidden_0", "target": t, "control": c, "r2": r, "control_r2_mean": m}
        for t, c, r, m in [
            ("gap_distance", "shift", 0.81, 0.02),
            ("gap_distance", "shuffle", 0.81, -0.4),
            ("gap_time", "shift", 0.3, 0.01),
            ("gap_time", "shuffle", 0.3, -0.2),
        ]
    ]
    assert (
        gap_sequence.decoding_rows(rows)[-1]
        == "| a | policy_hidden_0 | 0.810 (0.020, -0.400) | 0.300 (0.010, -0.200) |"
    )
    for r in rows[2:]:
        r["r2"] = None
    assert gap_sequence.decoding_rows(rows)[-1].endswith("| – (not decodable: no usable steps) |")


@pytest.mark.slow
@pytest.mark.xdist_group("neuro_record")
def test_a_network_replayed_on_the_shared_episodes_gives_its_recorded_activity(rat_recording):
    run, ds, _, _ = rat_recording
    replayed = gap_sequence.on_shared(run, ds)
    from vnl.recording import model

    active = ds["active"].values > 0
    for layer in model.layers(ds):
        np.testing.assert_allclose(replayed[layer].values[active], ds[layer].values[active], atol=1e-5, err_msg=layer)
    # Another network's activity on the same episodes differs, and the behaviour stays the recording's.
    other = dataclasses.replace(run, params=(run.params[0], *[_scaled(p) for p in run.params[1:]]))
    moved = gap_sequence.on_shared(other, ds)
    assert not np.allclose(moved["policy_hidden_0"].values[active], ds["policy_hidden_0"].values[active])
    np.testing.assert_array_equal(moved["gap_distance"].values, ds["gap_distance"].values)


def _scaled(params):
    import jax

    return jax.tree.map(lambda x: x * 1.5, params)


def test_a_behaviour_row_counts_gaps_and_the_roots_distance():
    import xarray as xr

    active = np.array([[1, 1, 1, 0], [1, 1, 1, 1]], np.int8)
    pos = np.zeros((2, 4, 3, 3))  # bodies: world, the walker's root, a leg
    pos[:, :, 1, 0] = [[0.0, 0.5, 1.0, 9.0], [0.0, 1.0, 2.0, 3.0]]  # step 3 of episode 0 is after its end
    pos[:, :, 2, 0] = 100.0
    ds = xr.Dataset(
        {
            "active": (("episode", "time"), active),
            "event_gap_crossed": (("episode", "time"), np.array([[0, 1, 0, 0], [0, 1, 1, 0]])),
            "walker_body": (("body",), np.array([0, 1, 1], np.int8)),
            "body_pos": (("episode", "time", "body", "xyz"), pos),
        }
    )
    assert gap_sequence.behaviour_row("a", 1000, ds) == "| a | 1,000 | 1.50 ± 0.50 | 2.00 | 4 |"


def test_similarity_rows_read_each_measures_consecutive_pairs(tmp_path):
    layers = ["policy_hidden_0", "policy_output", "value_output"]
    pairs = [
        {"a": a, "b": b, "layers_a": layers, "layers_b": layers, "similarity": np.full((3, 3), v).tolist()}
        for a, b, v in [("n0", "n1", 0.5), ("n0", "n2", 0.1), ("n1", "n2", 0.9)]
    ]
    pairs[2]["similarity"][1][1] = None  # a constant layer: no similarity
    result = {"samples": 1200, "observations": "x.nc", "networks": [{"name": n} for n in ("n0", "n1", "n2")]}
    (tmp_path / "compare_cka.json").write_text(json.dumps({**result, "pairs": pairs}))
    lines = gap_sequence.similarity_rows(tmp_path, ["untrained", "after_a", "after_b"])
    assert "| untrained → after_a | 0.500 | 0.500 |" in lines
    assert "| after_a → after_b | 0.900 | – |" in lines
    assert any(line.startswith("**rdm**: not computed") for line in lines)
    assert any(line.startswith("**dsa**: not computed") for line in lines)


def test_stages_of_one_name_are_numbered_and_odd_characters_left_out_of_file_names(tmp_path):
    stages = "curriculum=[{name: a b, steps: 1000}, {name: a b, steps: 1000}, {name: c/d, steps: 1000}]"
    run = _run_dir(tmp_path, assignments=(stages,))
    lines = [json.dumps({"step": s, "curriculum/stage": k}) for s, k in [(0, 0), (1000, 0), (2000, 1), (3000, 2)]]
    (run / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    for step in (0, 1000, 2000, 3000):
        (run / "checkpoints" / f"{step:012d}").mkdir(parents=True)
    assert gap_sequence.networks(run) == {"untrained": 0, "after_0_a_b": 1000, "after_1_a_b": 2000, "after_c_d": 3000}
