"""docs/tutorials/quickstart.ipynb runs end to end (executed with nbclient in a fresh kernel)."""

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("notebook")]

ROOT = Path(__file__).resolve().parents[1]


def execute(name: str, tmp_path: Path) -> nbformat.NotebookNode:
    """Runs docs/tutorials/<name>.ipynb in a fresh kernel (in `tmp_path`) and writes the executed
    notebook to build/notebooks/<name>.ipynb, for the docs to show its outputs."""
    nb = nbformat.read(ROOT / "docs" / "tutorials" / f"{name}.ipynb", as_version=4)
    client = NotebookClient(nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}})
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),  # this checkout's vnl
        "VNL_COMPILE_CACHE": str(tmp_path / "jax-cache"),
    }
    client.execute(env=env)
    built = ROOT / "build" / "notebooks"
    built.mkdir(parents=True, exist_ok=True)
    nbformat.write(nb, built / f"{name}.ipynb")
    return nb


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
    assert (ROOT / "build" / "notebooks" / "rat-to-neurons.ipynb").is_file()
