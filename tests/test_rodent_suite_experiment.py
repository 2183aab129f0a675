"""benchmarks/rodent_suite.py, the one-brain-four-tasks experiment: which networks it analyses, what it
reads of the run's evaluations, and its tables (trained beside untrained, refusals shown as n/a)."""

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import rodent_suite  # noqa: E402  (benchmarks/ on the path above)

TASKS = ["rodent_run_gaps", "rodent_two_touch"]


def _run(tmp_path: Path, evaluated: tuple[int, ...], kept: tuple[int, ...]) -> Path:
    run = tmp_path / "run"
    for step in kept:
        (run / "checkpoints" / f"{step:012d}").mkdir(parents=True)
    lines = []
    for step in evaluated:
        rec = {"step": step, "eval/episode_reward": 1.0}
        for i, t in enumerate(TASKS):
            rec[f"eval/{t}/episode_reward"] = step / 1000 + i
            rec[f"eval/{t}/episode_measure/touches"] = 0.5 * i
            rec[f"eval/{t}/episode_measure/touches_std"] = 9.0
            rec[f"eval/{t}/sps"] = 100.0
        lines.append(json.dumps(rec))
    (run / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    return run


def test_the_trained_network_is_the_newest_checkpoint_unless_a_step_is_named(tmp_path):
    run = _run(tmp_path, evaluated=(0, 500, 1000), kept=(0, 500, 1000))
    assert rodent_suite.newest(run, None) == 1000
    assert rodent_suite.newest(run, 500) == 500
    with pytest.raises(SystemExit, match="no checkpoint at step 700"):
        rodent_suite.newest(run, 700)


def test_a_run_without_its_untrained_checkpoint_or_an_evaluation_is_refused(tmp_path):
    with pytest.raises(SystemExit, match="no checkpoint at step 0"):
        rodent_suite.newest(_run(tmp_path / "a", evaluated=(0, 500), kept=(500,)), None)
    with pytest.raises(SystemExit, match="no evaluation at step 500"):
        rodent_suite.newest(_run(tmp_path / "b", evaluated=(0,), kept=(0, 500)), None)


def test_each_task_s_evaluation_is_its_reward_and_measures_not_their_spreads(tmp_path):
    run = _run(tmp_path, evaluated=(0, 2000), kept=(0, 2000))
    assert rodent_suite.evaluation(run, 2000, TASKS) == {
        "rodent_run_gaps": {"reward": 2.0, "touches": 0.0},
        "rodent_two_touch": {"reward": 3.0, "touches": 0.5},
    }


def _tasks_json(fraction: float, cross: float | None) -> dict:
    layer = {"task_modulated_fraction": fraction, "cross_task_rsa": cross, "within_task_rsa": 0.5,
             "control_cross_task_rsa_95": 0.2}  # fmt: skip
    return {"layers": {"policy_hidden_0": layer}}


def _dynamics_json(cross: float, within: float) -> dict:
    layer = {"cross_task": {"a|b": cross, "a|c": cross + 0.2}, "within_task": {"a": within, "b": within}}
    return {"layers": {"policy_hidden_0": layer}}


def test_the_layer_table_puts_the_untrained_control_beside_the_trained_network():
    results = {
        "trained": {"tasks": _tasks_json(0.4, 0.3), "dynamics": {"policy_hidden_0": _dynamics_json(0.5, 0.25)}},
        "untrained": {"tasks": _tasks_json(0.6, None), "dynamics": {"policy_hidden_0": None}},
    }
    rows = rodent_suite.layer_rows(results)
    assert rows[2:] == [
        "| policy_hidden_0 | trained | 0.40 | 0.30 | 0.50 | 0.20 | 0.600 | 0.250 |",
        "| policy_hidden_0 | untrained | 0.60 | n/a | 0.50 | 0.20 | n/a | n/a |",  # RSA and DSA refused
    ]


def test_the_embedding_table_gives_each_behaviour_s_share_of_each_task():
    emb = {"silhouette": 0.22, "control_silhouette": 0.07, "behaviours": [
        {"behaviour": 0, "share_of_task": {"a": 0.25, "b": 1.0}},
        {"behaviour": 1, "share_of_task": {"a": 0.75, "b": 0.0}},
    ]}  # fmt: skip
    rows = rodent_suite.embedding_rows(emb)
    assert rows[0].startswith("silhouette 0.22 (control 0.07)")
    assert rows[-2:] == ["| 0 | 0.25 | 1.00 |", "| 1 | 0.75 | 0.00 |"]
    assert "refused" in rodent_suite.embedding_rows(None)[0]
