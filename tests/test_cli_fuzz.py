"""CLI fuzz: hundreds of generated bad invocations, each run as a subprocess, each ending in one
`vnl: error:` line with exit code 2 and no traceback, and none modifying anything that existed.

Flags, numbers and paths are checked before JAX is imported (~0.15 s per invocation); the cases
that need the library (unknown env or key, corrupt checkpoints, metrics, recordings) take a few
seconds each. Two invocations run at a time.
"""

import hashlib
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from vnl import typed_config as config_lib
from vnl.train import config as train_config

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("cli_fuzz")]

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ["list", "train", "eval", "render", "plot", "record", "analyze", "compare", "view"]
# flag -> (commands, smallest valid value)
NUMBERS = {
    "--steps": (["train", "eval", "render", "record", "compare", "view"], 1),
    "--episodes": (["eval", "record", "compare"], 1),
    "--step": (["eval", "render", "record", "view"], 0),
    "--seed": (["train", "eval", "render", "record", "compare", "view"], 0),
    "--episode": (["view"], 0),
    "--units": (["view"], 0),
    "--max-samples": (["compare"], 1),
    "--num-envs": (["train"], 1),
    "--from-step": (["train"], 0),
    "--num-processes": (["train"], 1),
    "--process-id": (["train"], 0),
    "--width": (["render"], 16),
    "--height": (["render"], 16),
}


def _tree(root: Path) -> dict[str, tuple]:
    """Every file and directory under `root`: (kind, size, mtime, content hash)."""
    out = {}
    for p in sorted(root.rglob("*")):
        st = p.lstat()
        digest = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else ""
        out[str(p.relative_to(root))] = (p.is_dir(), st.st_size, st.st_mtime_ns, digest)
    return out


def _fixtures(root: Path) -> None:
    """Run directories, config files and recordings, good and broken, under `root`."""
    import xarray as xr

    config = train_config.resolved(train_config.build("ant_run", "tiny"))
    good_yaml = root / "good.yaml"
    config_lib.dump_yaml(config, str(good_yaml))
    record = '{"step": 0, "eval/episode_reward": 1.0}\n'
    layout = {
        # a run whose checkpoint files are garbage
        "run/config.yaml": good_yaml.read_text(),
        "run/metrics.jsonl": record + record.replace('"step": 0', '"step": 10'),
        "run/checkpoints/000000000000/params/x": "garbage",
        "run/checkpoints/000000000000/train_state.npz": "garbage",
        "run/checkpoints/000000000000/meta.json": "{garbage",
        "run_no_ckpt/config.yaml": good_yaml.read_text(),
        "run_bad_yaml/config.yaml": "env: ant_run\nppo: [unclosed\n",
        "run_bad_config/config.yaml": "env: ant_run\nppo: {nope: 1}\n",
        "run_bad_metrics/config.yaml": good_yaml.read_text(),
        "run_bad_metrics/metrics.jsonl": record + "not json\n" + record.replace('"step": 0', '"step": 10'),
        "bad.yaml": "ppo: [unclosed\n",
        "list.yaml": "- 1\n- 2\n",
        "unknown_key.yaml": "ppo: {nope: 1}\n",
        "wrong_env.yaml": "env: humanoid_run\n",
        "afile.txt": "just a file\n",
        "rec_bad.nc": "not netcdf",
    }
    for rel, text in layout.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    (root / "binary.yaml").write_bytes(bytes(range(128, 256)))
    for d in ("norun", "a_dir", "work"):
        (root / d).mkdir()
    rng = np.random.default_rng(0)
    base = {"active": (("episode", "time"), np.ones((1, 20))), "reward": (("episode", "time"), np.zeros((1, 20)))}
    layers = {
        "policy_hidden_0": (("episode", "time", "u0"), rng.normal(size=(1, 20, 4))),
        "value_output": (("episode", "time", "u1"), rng.normal(size=(1, 20, 1))),
    }
    coords = {"time": np.arange(20) * 0.1}
    xr.Dataset(base, coords=coords).to_netcdf(root / "rec_no_layers.nc", engine="h5netcdf")
    xr.Dataset({**base, **layers}, coords=coords).to_netcdf(root / "rec.nc", engine="h5netcdf")


def _positional(command: str) -> list[str]:
    """Valid positional arguments for `command` (so that the flag under test is the only fault)."""
    given = {"train": ["ant_run"], "eval": ["run"], "render": ["run"], "plot": ["run"], "record": ["run"]}
    given |= {"analyze": ["rec.nc"], "compare": ["run", "run"], "view": ["run"]}
    return given.get(command, [])


def bad_invocations() -> list[list[str]]:
    """Generated invocations, each with one fault, paths relative to the fixture root."""
    cases: list[list[str]] = [[c] for c in ["trian", "evaluate", "lst", "", "TRAIN", "rendr", "plott", "--version"]]
    cases += [[]]  # no command
    for c in COMMANDS:  # unknown flags
        cases += [[c, *_positional(c), flag] for flag in ["--bogus", "-x", "--stepz", "--out-dir=x", "--verbose=2"]]
    for flag, (commands, smallest) in NUMBERS.items():  # bad numbers
        values = ["abc", "1.5", "", "1e3", "0x10", "--", str(smallest - 1), str(smallest - 5)]
        values += ["5000", "100000"] if flag in ("--width", "--height") else []
        cases += [[c, *_positional(c), flag, v] for c in commands for v in values]
    for c in ["eval", "record", "analyze", "plot"]:  # missing required positionals
        cases.append([c])
    cases += [["render"], ["train"], ["train", "--from-step", "3", "ant_run"], ["train", "--resume", "run", "ant_run"]]
    cases += [["train", "ant_run", "--set", s] for s in ["ppo.num_envs", "=3", "ppo..x=1", ".x=1"]]
    for c in ["eval", "render", "record", "plot"]:  # wrong run directories
        cases += [[c, d] for d in ["missing", "afile.txt", "norun", "run_bad_yaml", "a_dir"]]
    cases += [["train", "--resume", d] for d in ["missing", "afile.txt", "norun", "run_bad_yaml"]]
    cases += [["plot", "run", d] for d in ["missing", "run_no_ckpt"]]
    cases += [["analyze", p] for p in ["missing.nc", "a_dir"]]
    for c in ["eval", "render", "record", "plot", "analyze", "compare", "view"]:  # unwritable --out
        cases += [[c, *_positional(c), "--out", out] for out in ["missing_dir/x.out", "afile.txt/x.out", "a_dir"]]
    cases += [["train", "ant_run", "--out", "afile.txt"]]
    cases += [["train", "ant_run", "--config", f] for f in ["missing.yaml", "a_dir", "bad.yaml", "list.yaml"]]
    cases += [["train", "ant_run", "--config", "binary.yaml"]]
    # Found by the library (JAX imported): a few seconds each.
    cases += [["train", "ant_walk"], ["train", "ant_run", "--set", "ppo.nope=1"]]
    cases += [["train", "ant_run", "--set", "env_config.nope=1"], ["train", "ant_run", "--set", "ppo.num_envs=100"]]
    cases += [["train", "ant_run", "--config", "unknown_key.yaml"], ["train", "ant_run", "--config", "wrong_env.yaml"]]
    cases += [["train", "ant_run", "--preset", "huge"]]
    cases += [
        ["train", "--resume", "run_bad_config"],
        ["train", "--resume", "run_no_ckpt"],
        ["train", "--resume", "run"],
    ]
    cases += [
        ["train", "--resume", "run", "--set", "ppo.learning_rate=1.0"],
        ["train", "--resume", "run", "--from-step", "5"],
    ]
    cases += [["eval", "run"], ["eval", "run_no_ckpt"], ["record", "run"], ["eval", "run_bad_config"]]
    cases += [["eval", "run", "--step", "5"]]
    cases += [["plot", "run_bad_metrics"], ["plot", "run", "--metric", "nope"]]
    cases += [
        ["analyze", "rec_bad.nc"],
        ["analyze", "rec_no_layers.nc"],
        ["analyze", "rec.nc", "--layer", "value_output"],
    ]
    cases += [["analyze", "rec.nc", "--layer", "nope"], ["analyze", "rec.nc", "--color", "nope"]]
    cases += [["compare", "run"], ["compare", "missing", "run"], ["compare", "run", "run", "--recording", "missing.nc"]]
    cases += [["compare", "run@x", "run"], ["view", "missing"], ["view", "run", "--episode", "2"]]
    return cases


def _run(root: Path, argv: list[str], env: dict[str, str]) -> tuple[list[str], subprocess.CompletedProcess]:
    argv = [str(root / a) if (root / a.split("/")[0]).exists() and a else a for a in argv]
    p = subprocess.run(
        [sys.executable, "-m", "vnl", *argv], capture_output=True, text=True, timeout=300, cwd=root / "work", env=env
    )
    return argv, p


def test_bad_invocations_end_in_one_error_line_and_change_nothing(tmp_path):
    root = tmp_path / "tree"
    root.mkdir()
    _fixtures(root)
    cases = bad_invocations()
    assert len(cases) >= 200, len(cases)
    before = _tree(root)
    env = {**os.environ, "VNL_COMPILE_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT)}
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(lambda argv: _run(root, argv, env), cases))
    failures = []
    for argv, p in results:
        lines = [line for line in p.stderr.splitlines() if line.strip()]
        errors = [line for line in lines if line.startswith("vnl: error:")]
        noise = [line for line in lines if not line.startswith(("vnl: error:", "vnl: warning:"))]
        if p.returncode != 2 or len(errors) != 1 or noise or "Traceback" in p.stdout + p.stderr:
            failures.append(f"vnl {' '.join(argv)} -> exit {p.returncode}\n{p.stderr[-600:]}")
    assert not failures, f"{len(failures)} of {len(cases)}:\n" + "\n".join(failures[:8])
    assert _tree(root) == before
