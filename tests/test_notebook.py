"""The tutorials (docs/tutorials/*.ipynb) run end to end, executed with nbclient in a fresh kernel
by scripts/docs/notebooks.py, and what they print is clean enough to be stored as the site shows it
(no warning, local path or error: `notebooks.faults`). The stored outputs are checked without
running anything in tests/test_docs.py."""

import sys
from pathlib import Path

import pytest

# Each tutorial is a group of its own (no compile is shared: each has its own cache), so the two
# workers can run two at a time and the longest stops being one worker's tail.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts" / "docs"))
import notebooks  # noqa: E402  (scripts/docs/notebooks.py)


def execute(name: str, tmp_path: Path):
    """Runs docs/tutorials/<name>.ipynb in a fresh kernel (in `tmp_path`); fails if the copy it
    would store has an error, a warning, a local path or a placeholder in its outputs."""
    nb = notebooks.execute(name, tmp_path)
    assert notebooks.faults(notebooks.for_storage(nb)) == []
    return nb


@pytest.mark.xdist_group("notebook_quickstart")
def test_quickstart_notebook_runs(tmp_path):
    nb = execute("quickstart", tmp_path)
    outputs = {i: cell.get("outputs", []) for i, cell in enumerate(nb.cells) if cell.cell_type == "code"}
    assert not [o for out in outputs.values() for o in out if o.get("output_type") == "error"]
    text = "".join(o.get("text", "") for out in outputs.values() for o in out if o.get("output_type") == "stream")
    assert "reward terms" in text and "linear CKA" in text and "(same model, other seed)" in text
    rich = [o for out in outputs.values() for o in out if o.get("output_type") in ("display_data", "execute_result")]
    kinds = {k for o in rich for k in o.get("data", {})}
    assert "text/html" in kinds and "image/png" in kinds  # the inline videos (HTML), the PCA and CKA figures
    assert any("application/vnd.jupyter.widget-view+json" in o.get("data", {}) for o in rich)  # the viewer
    runs = next((tmp_path / "runs").iterdir())
    assert (runs / "seed0" / "metrics.jsonl").is_file() and (runs / "view.rrd").stat().st_size > 100_000


@pytest.mark.xdist_group("notebook_rat_to_neurons")
def test_rat_to_neurons_notebook_runs(tmp_path):
    nb = execute("rat-to-neurons", tmp_path)
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.get("output_type") == "stream")
    assert "critical issues or best-practice violations: 0" in text
    assert "pose series equal to the recording: True" in text
    assert "trained: R²" in text and "untrained (step 0): R²" in text and "DSA (rad)" in text
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 5  # the tuning curves, encoding, two decodings, states
    assert any("application/vnd.jupyter.widget-view+json" in o.get("data", {}) for o in outputs)  # the viewer
    rat = next((tmp_path / "runs").iterdir()) / "rat"
    assert (rat / "record.nwb").stat().st_size > 100_000


@pytest.mark.xdist_group("notebook_mocap_to_nwb")
def test_mocap_to_nwb_notebook_runs(tmp_path):
    nb = execute("mocap-to-nwb", tmp_path)
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.get("output_type") == "stream")
    assert "23 keypoints, 1000 frames at 30 frames/s" in text
    assert "residual (mm) per keypoint, median / 90th percentile" in text and "\n  all " in text
    assert "step 4096: reward" in text and "encoder_intention_mean      (8, 200, 60)" in text
    assert "the decoder read the latent's mean: True" in text
    assert "critical issues or best-practice violations: 0" in text
    assert "encoder_intention_mean in NWB: 60 units" in text
    assert "observation[ref_root_pos[0]] from encoder_intention_mean: held-out R²" in text and "control (shift)" in text
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 2  # the fitted rat beside its keypoints, the decoding
    runs = next((tmp_path / "runs").iterdir())
    assert (runs / "rat_clips.h5").is_file() and (runs / "rat_fit.png").stat().st_size > 10_000
    assert (runs / "rat" / "record.nwb").stat().st_size > 100_000


@pytest.mark.xdist_group("notebook_one_rat_four_tasks")
def test_one_rat_four_tasks_notebook_runs(tmp_path):
    nb = execute("one-rat-four-tasks", tmp_path)
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    text = "".join(o.get("text", "") for o in outputs if o.get("output_type") == "stream")
    tasks = ["rodent_run_gaps", "rodent_maze_forage", "rodent_escape_bowl", "rodent_two_touch"]
    assert f"{tasks} {{'episode': 16, 'time': 300" in text
    assert "silhouette" in text and text.count("task-modulated units") >= 8  # trained and untrained layers
    assert all(f"{t}: gait frequency" in text for t in tasks)  # the rhythm of each task
    assert text.count("(within ") == 6  # DSA: every pair of the four tasks against its within-task distances
    assert len([o for o in outputs if "image/png" in o.get("data", {})]) >= 3  # the embedding, tasks, dynamics
    run = next((tmp_path / "runs").iterdir())
    assert (run / "record.nc").stat().st_size > 100_000 and (run / "tasks.png").is_file()
    assert (run / "dynamics.png").stat().st_size > 10_000
