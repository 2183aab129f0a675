"""vnl.neuro.registry: every method behind it keeps its contract, and a new method is one module
and one line of the registry (docs/developers/index.md, "Add an analysis method")."""

import json
import sys
import textwrap

import numpy as np
import pytest
from recordings import synthetic  # tests/recordings.py

from vnl import compare
from vnl.cli import main
from vnl.errors import VnlError
from vnl.neuro import registry


@pytest.mark.parametrize("name", list(registry.ANALYSES))
def test_every_analysis_keeps_the_contract(name):
    module = registry.analysis(name)
    for function in ("analyze", "report", "figure", "output_name"):
        assert callable(getattr(module, function, None)), (name, function)
    assert module.output_name(registry.Options())  # a name before the recording is read


@pytest.mark.parametrize("name", list(registry.MEASURES))
def test_every_measure_keeps_the_contract(name):
    module = registry.measure(name)
    assert callable(module.matrix) and callable(module.label) and len(module.RANGE) == 2
    assert module.label(registry.Options())


def test_unknown_names_are_one_line():
    with pytest.raises(VnlError, match="unknown analysis method 'nope'; choose one of pca, encoding"):
        registry.analysis("nope")
    with pytest.raises(VnlError, match="unknown similarity measure 'nope'; choose one of cka, rsa"):
        registry.measure("nope")


TOY_ANALYSIS = '''
"""A toy analysis: each layer's mean activity."""
import dataclasses
from pathlib import Path

import numpy as np

from vnl.recording import model


@dataclasses.dataclass
class Means:
    means: dict

    def to_json(self):
        return {"analysis": "toy", "means": self.means}


def analyze(ds, options):
    return Means({layer: float(model.activity(ds, layer).mean()) for layer in model.layers(ds)})


def report(result):
    return f"{len(result.means)} layers averaged"


def figure(result, out, dt):
    Path(out).write_bytes(b"a figure")
    return Path(out)


def output_name(options, ds=None):
    return "toy"
'''

TOY_MEASURE = '''
"""A toy measure: the difference of two layers' mean activity."""
import numpy as np

RANGE = (-1.0, 1.0)


def label(options):
    return "difference of the means"


def matrix(a, b, options):
    return np.array([[x.mean() - y.mean() for y in b.values()] for x in a.values()])
'''


def test_a_new_method_is_one_module_and_one_registry_line(tmp_path, monkeypatch, capsys):
    (tmp_path / "toy_analysis.py").write_text(textwrap.dedent(TOY_ANALYSIS))
    (tmp_path / "toy_measure.py").write_text(textwrap.dedent(TOY_MEASURE))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(registry.ANALYSES, "toy", ("toy_analysis", "each layer's mean activity"))
    monkeypatch.setitem(registry.MEASURES, "toy", ("toy_measure", "difference of the means"))
    rec = tmp_path / "rec.nc"
    synthetic().to_netcdf(rec, engine="h5netcdf")
    assert main(["analyze", str(rec), "--method", "toy"]) == 0
    assert "2 layers averaged" in capsys.readouterr().out
    doc = json.loads((tmp_path / "toy.json").read_text())
    assert doc["analysis"] == "toy" and set(doc["means"]) == {"policy_hidden_0", "policy_hidden_1"}
    x = np.arange(12.0).reshape(6, 2)
    nets = [compare.Network(n, tmp_path, 0, n, {"h": x + i}) for i, n in enumerate("ab")]
    result = compare.compare(nets, "toy")
    assert result.pairs[(0, 1)][0, 0] == -1.0 and "difference of the means" in compare.table(result)
    for name in ("toy_analysis", "toy_measure"):
        sys.modules.pop(name, None)


def test_results_are_strict_json_with_null_for_what_could_not_be_estimated():
    def refuse(constant):
        raise ValueError(f"not JSON: {constant}")

    text = registry.json_text({"r2": float("nan"), "x": [1.0, float("inf"), {"y": np.float64("-inf")}], "n": 3})
    assert json.loads(text, parse_constant=refuse) == {"r2": None, "x": [1.0, None, {"y": None}], "n": 3}
