"""Shared assertion of the interruption tests: a run that was killed and resumed ended exactly as
the uninterrupted reference run."""

from pathlib import Path

import numpy as np

from vnl.io import checkpoint
from vnl.io import metrics as metrics_io


def assert_same_as_reference(run: Path, reference: Path, total: int, epoch: int) -> None:
    """metrics.jsonl's steps are 0, epoch, ..., total (unique, in order, complete); every
    evaluation and training metric but timings equals the reference's; the final training state
    is bit-identical."""
    records = metrics_io.read(run / "metrics.jsonl")
    expected = metrics_io.read(reference / "metrics.jsonl")
    assert [r["step"] for r in records] == list(range(0, total + 1, epoch))
    for got, want in zip(records, expected, strict=True):
        for key in want:
            if key.startswith(("eval/episode", "training/")) and "sps" not in key and "walltime" not in key:
                assert got[key] == want[key], (got["step"], key, got[key], want[key])
    _, final, _ = checkpoint.load_train_state(run)
    _, want, _ = checkpoint.load_train_state(reference)
    assert final.keys() == want.keys()
    for key in want:
        np.testing.assert_array_equal(final[key], want[key], err_msg=key)


def assert_same_final_state(run: Path, reference: Path) -> dict[str, np.ndarray]:
    """The newest checkpoints of `run` and `reference` hold the same arrays, bit for bit; returns them."""
    _, want, _ = checkpoint.load_train_state(reference)
    _, got, _ = checkpoint.load_train_state(run)
    assert got.keys() == want.keys()
    for key in want:
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    return want
