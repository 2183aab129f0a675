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
from fsutil import snapshot

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
    "--condition-bins": (["compare"], 2),
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
        # evaluated once, its checkpoints gone: --resume cannot start it again from step 0
        "run_lost_ckpt/config.yaml": good_yaml.read_text(),
        "run_lost_ckpt/metrics.jsonl": record,
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
        ["train", "--resume", "run_lost_ckpt"],  # (run_no_ckpt, never evaluated, is started again)
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
    cases += [["compare", "run", "run", "--set", "ppo.learning_rate=1"], ["compare", "run", "run", "--set", "=1"]]
    cases += [["compare", "run", "run", "--recording", "rec.nc", "--set", "env_config.task=x"]]
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


# --- generated fuzz of values, shapes, files and outputs (issue 47) -------------------------------
#
# Each case runs `vnl` in a subprocess of its own sandbox (a copy of the fixtures, HOME and
# XDG_CACHE_HOME inside it but outside the compared tree), bounded in time and killed as a
# process group, two at a time. Each must end with exit code 2, exactly one `vnl: error:` line
# (warnings allowed), no traceback, nothing in the sandbox or the shared read-only fixtures
# created or changed (kind, size, mode, mtime, content) and, for the cases the CLI checks itself
# (`light`), neither JAX nor MuJoCo imported: an atexit hook of the launcher says which were.

import dataclasses  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import signal  # noqa: E402
import time  # noqa: E402

LAUNCHER = """
import atexit, json, os, sys
def _mark():
    with open(os.environ["VNL_FUZZ_MARK"], "w") as f:
        json.dump({"jax": "jax" in sys.modules, "mujoco": "mujoco" in sys.modules}, f)
atexit.register(_mark)
from vnl.cli import main
sys.exit(main(sys.argv[1:]))
"""
# A heavy case imports JAX and builds an env beside the other worker's compiles: on CI (2026-11-28)
# `train --resume run_links` took over 120 s; 240 s still tells a hang from a slow refusal.
LIGHT_SECONDS, HEAVY_SECONDS = 20, 240


@dataclasses.dataclass
class Case:
    group: str
    argv: list[str]
    expect: str  # in the error line: the reason the case is refused (lower case)
    light: bool = True  # refused by the CLI's checks, before JAX and MuJoCo are imported
    env: dict[str, str] = dataclasses.field(default_factory=dict)
    files: dict[str, str] = dataclasses.field(default_factory=dict)  # written into the sandbox first


NUMBER_KEYS = [
    "ppo.learning_rate",
    "ppo.entropy_cost",
    "ppo.discounting",
    "ppo.clipping_epsilon",
    "ppo.max_grad_norm",
    "ppo.num_envs",
    "ppo.num_timesteps",
    "seed",
    "log.video_seconds",
    "network.init_noise_std",
    "env_config.reset_noise_scale",
    "env_config.physics_timestep",
]
BAD_NUMBERS = [".nan", ".NaN", ".inf", "-.inf", "1e999", "-1e999", "99999999999999999999", "-" + "9" * 25, "[1, .nan]"]
BOMB_LISTS = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{b}: &{b} [{', '.join([f'*{a}'] * 9)}]\n" for a, b in zip("abcdefgh", "bcdefghi", strict=True)
)
BOMB_MAPS = "a: &a {x: 1, y: 2, z: 3, w: 4, v: 5, u: 6, t: 7, s: 8, r: 9}\n" + "".join(
    f"{b}: &{b} {{{', '.join(f'k{i}: *{a}' for i in range(9))}}}\n" for a, b in zip("abcdefgh", "bcdefghi", strict=True)
)
BOMB_WIDE = "a: &a {x: 1}\n" + "".join(
    f"{b}: &{b} [{', '.join([f'*{a}'] * 12)}]\n" for a, b in zip("abcdefg", "bcdefgh", strict=True)
)


def _deep(depth: int, kind: str) -> str:
    if kind == "list":
        return "[" * depth + "]" * depth
    return "{k: " * depth + "1" + "}" * depth


def generated_cases(ro: Path) -> list[Case]:
    """The fuzz cases; paths are relative to the sandbox's tree, `ro` holds the read-only ones."""
    cases: list[Case] = []
    train = ["train", "ant_run", "--preset", "tiny"]
    # non-finite and huge numbers through --set and --config
    for key in NUMBER_KEYS:
        for value in BAD_NUMBERS:
            cases.append(Case("numbers --set", [*train, "--set", f"{key}={value}"], key.split(".")[-1]))
    for i, key in enumerate(NUMBER_KEYS):
        *sections, leaf = key.split(".")
        for value in (".nan", "-.inf", "1e400", "123456789012345678901234567890"):
            text = (
                "".join(f"{'  ' * d}{s}:\n" for d, s in enumerate(sections))
                + f"{'  ' * len(sections)}{leaf}: {value}\n"
            )
            cases.append(Case("numbers --config", [*train, "--config", f"n{i}.yaml"], leaf, files={f"n{i}.yaml": text}))
    # seeds beyond 32 bits
    for command in (["train", "ant_run"], ["eval", "run"], ["render", "run"], ["record", "run"], ["view", "run"]):
        for seed in (str(2**32), str(2**63), str(2**64), "1" + "0" * 30):
            cases.append(Case("seeds", [*command, "--seed", seed], "--seed"))
    cases += [Case("seeds", ["compare", "run", "run", "--seed", str(2**64)], "--seed")]
    # section shapes and names (found by the library: JAX is imported)
    for text, expect in [
        ("ppo: 3", "ppo"), ("ppo: [1, 2]", "ppo"), ("ppo: text", "ppo"), ("network: 3", "network"),
        ("log: []", "log"), ("curriculum: 3", "curriculum"), ("curriculum: [3]", "curriculum"),
        ("curriculum: [{steps: x}]", "steps"), ("init: 5", "init"), ("env_config: [1]", "env_config"),
        ("vision: true", "vision"), ("randomize: 1.5", "randomize"), ("env: [ant_run]", "env"),
        ("preset: [cpu]", "preset"), ("preset: {a: 1}", "preset"), ("log: {keep_best: [x]}", "keep_best"),
        ("env_config: {walker: [ant]}", "walker"), ("vision: {camera: [x]}", "camera"), ("init: {run: [x]}", "run"),
        ("seed: [1]", "seed"), ("ppo: {num_envs: [16]}", "num_envs"),
    ]:  # fmt: skip
        cases.append(Case("shapes", [*train, "--config", "s.yaml"], expect, light=False, files={"s.yaml": text + "\n"}))
    for assignment in ["ppo=3", "network=[1]", "curriculum=3", "env_config=x", "preset=[cpu]", "log.keep_best=[x]"]:
        expect = assignment.split("=")[0].split(".")[-1]
        cases.append(Case("shapes --set", [*train, "--set", assignment], expect, light=False))
    # keys that are not strings
    for text in ["1: 2", "null: 1", "true: 1", "ppo: {1: 2}", "1.5: x", "ppo: {~: 1}", "env_config: {2: 3}"]:
        cases.append(Case("keys", [*train, "--config", "k.yaml"], "not a string", files={"k.yaml": text + "\n"}))
    cases.append(Case("keys", [*train, "--config", "k.yaml"], "not valid yaml", files={"k.yaml": "? [a, b]\n: 1\n"}))
    cases.append(Case("keys --set", [*train, "--set", "env_config={1: 2}"], "not a string"))
    # depth
    for depth in (65, 100, 1000, 20000):
        for kind in ("list", "map"):
            text = f"ppo: {_deep(depth, kind)}\n"
            cases.append(Case("depth", [*train, "--config", "d.yaml"], "nested more than", files={"d.yaml": text}))
    cases += [
        Case("depth --set", [*train, "--set", f"ppo.x={_deep(d, 'list')}"], "nested more than") for d in (70, 5000)
    ]
    cases.append(Case("depth --set", [*train, "--set", "a." * 80 + "b=1"], "nested more than"))
    # alias bombs
    for text in (BOMB_LISTS, BOMB_MAPS, BOMB_WIDE):
        cases.append(Case("aliases", [*train, "--config", "b.yaml"], "expands to more than", files={"b.yaml": text}))
        bomb = "ppo.x=" + text.replace("\n", ", ").join("{}")
        cases.append(Case("aliases --set", [*train, "--set", bomb], "expands to more than"))
    # file types of --config
    for path, expect in [
        ("a_dir", "is a directory"), ("fifo.yaml", "not a regular file"), ("/dev/null", "not a regular file"),
        ("binary.yaml", "not text"), ("big.yaml", "larger than"), ("loop.yaml", "symbolic link to nothing"),
        ("nul.yaml", "not valid yaml"), ("dangling.yaml", "symbolic link to nothing"),
    ]:  # fmt: skip
        cases.append(Case("file types", [*train, "--config", path], expect))
    # input types of recordings and run directories
    cases += [
        Case("inputs", ["analyze", "fifo.yaml"], "not a regular file"),
        Case("inputs", ["analyze", "/dev/zero"], "not a regular file"),
        Case("inputs", ["analyze", "a_dir"], "is a directory"),
        Case("inputs", ["view", "fifo.yaml"], "not a regular file"),
        Case("inputs", ["view", "/dev/zero"], "not a regular file"),
        Case("inputs", ["compare", "run", "run", "--recording", "fifo.yaml"], "not a regular file"),
        Case("inputs", ["compare", "run", "run", "--recording", "a_dir"], "is a directory"),
        Case("inputs", ["eval", "run_fifo_config"], "not a vnl run directory"),
        Case("inputs", ["eval", "run_big_config"], "larger than"),
        Case("inputs", ["eval", "run_nan_config"], "entropy_cost"),
        Case("inputs", ["plot", "run_fifo_metrics"], "no metrics.jsonl"),
        Case("inputs", ["train", "--resume", "run_big_config"], "larger than"),
        Case("inputs", ["plot", "run_list_config"], "mapping"),
        Case("inputs", ["train", "ant_run", "--init-from", "run_nan_config"], "entropy_cost"),
    ]
    # outputs on a read-only mount (also for root)
    r = str(ro)
    cases += [
        Case("read-only", argv, "read-only")
        for argv in (
            ["eval", f"{r}/run"],
            ["render", f"{r}/run"],
            ["record", f"{r}/run"],
            ["record", "run", "--viewer", "--out", f"{r}/ok.nc"],
            ["view", f"{r}/run"],
            ["view", f"{r}/rec.nc"],
            ["plot", f"{r}/run"],
            ["analyze", f"{r}/rec.nc"],
            ["analyze", f"{r}/rec.nc", "--layer", "policy_hidden_0"],
            ["compare", f"{r}/run", f"{r}/run"],
            ["train", "--resume", f"{r}/run"],
            ["train", "ant_run", "--out", f"{r}/new_run"],
            ["eval", "run", "--out", f"{r}/e.json"],
            ["plot", "run", "--out", f"{r}/p.png"],
            ["render", "run", "--out", f"{r}/v.mp4"],
        )
    ]
    # overwrites
    cases += [
        Case("overwrites", argv, expect)
        for argv, expect in (
            ([*train, "--out", "user_dir"], "already holds a run (config.yaml)"),  # the user's own config.yaml
            ([*train, "--out", "run"], "already holds a run"),
            (["record", "run", "--out", "x.rrd", "--viewer"], ".nc"),
            (["view", "rec.nc", "--out", "rec.nc"], ".rrd"),
            (["view", "rec.nc", "--out", "rec_copy.rrd"], "input of this command"),  # a symlink to rec.nc
            (["analyze", "rec.nc", "--out", "rec.nc"], ".png"),
            (["plot", "run", "--out", "run/metrics.jsonl"], ".png"),
            (["plot", "run", "--out", "run/learning_curve.png"], "keeps in its run directory"),
            (["eval", "run", "--out", "run/config.yaml"], ".json"),
            (["eval", "run", "--out", "run/checkpoints/x.json"], "keeps in its run directory"),
            (["compare", "run", "run", "--out", "run/learning_curve.png"], "keeps in its run directory"),
            (["eval", "run", "--out", "fifo.json"], "not a regular file"),
            (["render", "run", "--out", "a_dir"], "is a directory"),
        )
    ]
    # the recording commands' formats and methods (NWB, encoding/decoding/states, rdm/dsa)
    cases += [
        Case("neuro", argv, expect, light=light)
        for argv, expect, light in (
            (["record", "run", "--format", "nwb", "--out", "x.nc"], "use .nwb", True),
            (["record", "run", "--out", "x.nwb", "--format", "netcdf"], "use .nc", True),
            (["record", "run", "--out", "x.json"], "expected a .nc file name", True),
            (["record", "run", "--from", "rec.nc"], "not both", True),
            (["record", "--from", "rec.nc", "--format", "netcdf"], "--from converts", True),
            (["record", "--from", "rec.nc", "--out", "rec.nc"], "--from converts", True),
            (["record", "--from", "fifo.yaml"], "not a regular file", True),
            (["record", "--from", "a_dir"], "is a directory", True),
            (["record", "--from", "rec.nc", "--out", f"{r}/x.nwb"], "read-only", True),
            (["record", "--from", "rec.nc", "--out", "rec_copy.nwb"], "input of this command", True),
            (["record", "--format", "nwb"], "give the run directory", True),
            (["analyze", "rec.nc", "--method", "decoding", "--out", "x.txt"], "expected a", True),
            (["analyze", "rec.nc", "--method", "encoding", "--color", "reward"], "--color colours the pca", True),
            (["analyze", "rec.nc", "--method", "states", "--states", "1"], "--states", True),
            (["analyze", "rec.nc", "--method", "states", "--folds", "1"], "--folds", True),
            (["analyze", "rec.nc", "--method", "decoding", "--out", f"{r}/d.png"], "read-only", True),
            (["analyze", f"{r}/rec.nc", "--method", "encoding"], "read-only", True),
            (["analyze", "rec.nc", "--method", "decoding", "--out", "run/metrics.json"], "expected a", True),
            (["analyze", "rec.nc", "--method", "nope"], "--method", True),
            (["compare", "run", "run", "--measure", "dsa", "--rank", "0"], "--rank", True),
            (["compare", "run", "run", "--measure", "dsa", "--delays", "-3"], "--delays", True),
            (["compare", "run", "run", "--measure", "cka", "--rsa", "correlation"], "cannot be combined", True),
            (["compare", "run", "run", "--measure", "dsa", "--out", "x.gif"], "expected a", True),
            (["compare", f"{r}/run", f"{r}/run", "--measure", "rdm"], "read-only", False),
        )
    ]
    # long paths
    long = "x" * 300
    cases += [
        Case("long paths", ["eval", "run", "--out", "d/" * 3000 + "e.json"], "name too long"),
        Case("long paths", ["eval", "run", "--out", f"{long}.json"], "name too long"),
        Case("long paths", [*train, "--config", f"{long}.yaml"], "name too long"),
        Case("long paths", [*train, "--out", "r/" * 3000], "name too long"),
        Case("long paths", ["eval", "r" * 5000], "name too long"),
        Case("long paths", ["analyze", f"{long}.nc"], "name too long"),
    ]
    # MUJOCO_GL
    for gl in ("bogus", "glx", "EGL", "egl ", "cgl"):
        for argv in (["eval", "run"], ["render", "run"], ["record", "run"]):
            cases.append(Case("MUJOCO_GL", argv, "mujoco_gl", env={"MUJOCO_GL": gl}))
    return cases


def link_and_odd_input_cases() -> list[Case]:
    """Issue 53: links (a copy made of links, a linked lock and checkpoints folder, outputs that
    are links) and odd paths (`.`, `..`, an empty name, a file where a folder goes). Each is
    refused with its reason and changes nothing: neither the copy nor what its links point to."""
    train = ["train", "ant_run", "--preset", "tiny"]
    cases = [
        Case("links", argv, expect, light=light)
        for argv, expect, light in (
            (["eval", "run", "--out", "link.json"], "symbolic link (to", True),
            (["eval", "run", "--out", "dangling.json"], "symbolic link (to nothing", True),
            (["render", "run", "--out", "link.mp4"], "symbolic link (to", True),
            (["render", "run", "--out", "dangling.mp4"], "symbolic link (to nothing", True),
            ([*train, "--out", "dangling_dir"], "symbolic link to nothing", True),
            ([*train, "--out", "run_links"], "already holds a run", True),
            (["train", "--resume", "run_linked_ckpts"], "checkpoints is a symbolic link", True),
            (["train", "--resume", "run_links", "--from-step", "5"], "no checkpoint at step 5", False),
            (["train", "--resume", "run_links", "--set", "ppo.learning_rate=1.0"], "learning_rate", False),
            (["train", "--resume", "run_links"], "does not match this env and config", False),
            (["eval", "run_links", "--step", "5"], "no checkpoint at step 5", False),
            (["eval", "run_links", "--out", "link.json"], "symbolic link (to", True),
        )
    ]
    cases += [
        Case("odd inputs", argv, expect)
        for argv, expect in (
            (["eval", "."], "not a vnl run directory"),
            (["eval", ""], "not a vnl run directory"),
            (["render", "."], "not a vnl run directory"),
            (["train", "--resume", "."], "not a vnl run directory"),
            (["train", "--resume", "run/checkpoints"], "not a vnl run directory"),
            ([*train, "--init-from", "."], "not a vnl run directory"),
            ([*train, "--config", "."], "is a directory"),
            ([*train, "--config", ".."], "is a directory"),
            ([*train, "--config", "run/checkpoints"], "is a directory"),
            (["eval", "run", "--out", "."], "is a directory"),
            (["eval", "run", "--out", "run/."], "is a directory"),
            (["render", "run", "--out", ".."], "is a directory"),
            (["eval", "run", "--out", ".json"], "expected a .json"),
            (["eval", "run", "--out", "run/config.yaml/x.json"], "is not a directory"),
            (["eval", "run/config.yaml"], "is a file, not a run directory"),
            (["eval", "-"], "run directory not found"),
            ([*train, "--out", "afile.txt/run"], "is a file, not a directory"),
        )
    ]
    return cases


def _fuzz_fixtures(root: Path) -> None:
    """The sandbox template: the old fixtures plus a run with a checkpoint, a user's folder with
    its own config.yaml, and runs whose config.yaml or metrics.jsonl are odd."""
    from vnl.io import checkpoint

    _fixtures(root)
    good = (root / "good.yaml").read_text()
    params = ({"mean": np.zeros(2, np.float32)}, {"w": np.ones(3, np.float32)}, {"w": np.ones(1, np.float32)})
    checkpoint.save(root / "run", 0, params, 0, {".env.x": np.zeros(2)}, {"training_steps_per_epoch": 1})
    for name, text in {
        "user_dir/config.yaml": "# my notes\nppo: {num_envs: 16}\n",
        "run_big_config/config.yaml": "a: " + "x" * (2 << 20) + "\n",
        "run_nan_config/config.yaml": good.replace("entropy_cost: 0.01", "entropy_cost: .nan"),
        "run_list_config/config.yaml": "- 1\n",
        "run_list_config/metrics.jsonl": '{"step": 0}\n',
        "run_fifo_metrics/config.yaml": good,
        "run_fifo_config/metrics.jsonl": '{"step": 0}\n',
        "big.yaml": "a: " + "x" * (2 << 20) + "\n",
        "nul.yaml": "ppo:\0 1\n",
    }.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    assert "entropy_cost: .nan" in (root / "run_nan_config/config.yaml").read_text()
    (root / "loop.yaml").symlink_to("loop.yaml")
    (root / "dangling.yaml").symlink_to("nowhere.yaml")
    (root / "rec_copy.rrd").symlink_to("rec.nc")
    (root / "rec_copy.nwb").symlink_to("rec.nc")
    _link_fixtures(root)


def _link_fixtures(root: Path) -> None:
    """Links (relative, so that each sandbox's point into itself): `run_links`, what `cp -as run`
    makes (every file a link) with a lock file linked to `held.lock`; `run_linked_ckpts`, whose
    checkpoints folder is a link to run's; outputs that are links, to a file and to nothing."""
    for dirpath, _, filenames in os.walk(root / "run"):
        here = root / "run_links" / Path(dirpath).relative_to(root / "run")
        here.mkdir(parents=True, exist_ok=True)
        for name in filenames:
            (here / name).symlink_to(os.path.relpath(Path(dirpath, name), here))
    (root / "held.lock").write_text('{"pid": 1, "host": "the original run"}')
    (root / "run_links" / ".vnl-lock").symlink_to("../held.lock")
    (root / "run_linked_ckpts").mkdir()
    (root / "run_linked_ckpts" / "config.yaml").write_text((root / "run" / "config.yaml").read_text())
    (root / "run_linked_ckpts" / "checkpoints").symlink_to("../run/checkpoints")
    (root / "mine.json").write_text("{}")
    (root / "link.json").symlink_to("mine.json")
    (root / "link.mp4").symlink_to("mine.json")
    (root / "dangling.json").symlink_to("nowhere/x.json")
    (root / "dangling.mp4").symlink_to("nowhere.mp4")
    (root / "dangling_dir").symlink_to("nowhere_dir")


FIFOS = ("fifo.yaml", "fifo.json", "run_fifo_config/config.yaml", "run_fifo_metrics/metrics.jsonl")


def _sandbox(template: Path, where: Path, case: Case) -> Path:
    tree = where / "tree"
    shutil.copytree(template, tree, symlinks=True)
    for name in FIFOS:
        os.mkfifo(tree / name)
    for name, text in case.files.items():
        (tree / name).write_text(text)
    for d in ("home", "cache"):
        (where / d).mkdir()
    return tree


def _run_case(template: Path, where: Path, ro: Path, case: Case) -> str | None:
    """Runs one case; None when it passed, else what went wrong."""
    tree = _sandbox(template, where, case)
    before, ro_before = snapshot(tree), snapshot(ro)
    mark = where / "mark.json"
    env = {
        **{k: v for k, v in os.environ.items() if k not in ("VNL_COMPILE_CACHE", "MUJOCO_GL")},
        "HOME": str(where / "home"),
        "XDG_CACHE_HOME": str(where / "cache"),
        "PYTHONPATH": str(ROOT),
        "VNL_FUZZ_MARK": str(mark),
        **case.env,
    }
    argv = case.argv
    proc = subprocess.Popen(
        [sys.executable, "-c", LAUNCHER, *argv],
        cwd=tree,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    limit = LIGHT_SECONDS if case.light else HEAVY_SECONDS
    try:
        out, err = proc.communicate(timeout=limit)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return f"no answer in {limit} s (a hang)"
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("vnl: error:")]
    noise = [line for line in lines if not line.startswith(("vnl: error:", "vnl: warning:"))]
    problems = []
    if proc.returncode != 2:
        problems.append(f"exit {proc.returncode}")
    if len(errors) != 1 or noise or "Traceback" in out + err:
        problems.append(f"stderr {err[-700:]!r}")
    elif case.expect not in errors[0].lower():
        problems.append(f"refused for another reason than {case.expect!r}: {errors[0][:300]!r}")
    imported = json.loads(mark.read_text()) if mark.is_file() else {"jax": "?", "mujoco": "?"}
    if case.light and (imported["jax"] or imported["mujoco"]):
        problems.append(f"imported {imported} before refusing")
    if snapshot(tree) != before or snapshot(ro) != ro_before:
        after = snapshot(tree)
        changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
        problems.append(f"changed {changed[:5]}")
    return "; ".join(problems) or None


def _run_all(tmp_path: Path, make_cases, minimum: int) -> None:
    """Runs the cases `make_cases(ro)` in sandboxes of the fuzz fixtures, two at a time, with a
    read-only bind mount `ro` holding a run and a recording; fails naming every case that failed."""
    from fsutil import read_only

    template = tmp_path / "template"
    template.mkdir()
    _fuzz_fixtures(template)
    ro = tmp_path / "ro"
    ro.mkdir()
    shutil.copytree(template / "run", ro / "run")
    shutil.copy(template / "rec.nc", ro / "rec.nc")
    cases = make_cases(ro)
    assert len(cases) >= minimum, len(cases)
    start = time.monotonic()
    with read_only(ro):
        with ThreadPoolExecutor(max_workers=2) as pool:
            results = list(
                pool.map(lambda ic: _run_case(template, tmp_path / f"case{ic[0]}", ro, ic[1]), enumerate(cases))
            )
    failures = [  # the files a case writes (a config) are shown by their first characters
        f"[{c.group}] vnl {' '.join(c.argv)[:200]} {c.env or ''} {[t[:40] for t in c.files.values()]}: {r}"
        for c, r in zip(cases, results, strict=True)
        if r
    ]
    print(f"{len(cases)} cases in {time.monotonic() - start:.0f} s")
    assert not failures, f"{len(failures)} of {len(cases)}:\n" + "\n".join(failures[:40])


def test_generated_fuzz_of_values_shapes_files_and_outputs(tmp_path):
    """At least 200 generated cases (issue 47): non-finite and huge numbers, seeds, section
    shapes, names, non-string keys, depth, alias bombs, file and input types, read-only outputs,
    overwrites, long paths, MUJOCO_GL."""
    _run_all(tmp_path, generated_cases, 200)


# --- every input and output of the recording commands (issue 53) -----------------------------------
#
# Each file a command that reads a recording may be given (record --from, analyze, compare, view):
# NWB (also named .nc, or .NWB), other HDF5, NetCDF-3, a NetCDF-4 file that is not a recording,
# empty, text, damaged HDF5, links to them, to nothing, in a loop, to a directory, `.` and `..`;
# and each output as a link to nothing, a loop, a directory or a file of another type. Each is
# refused by the CLI's checks, before JAX, with its reason.

FOREIGN = [  # file in the sandbox, the reason in the error line
    ("session.nwb", "an nwb file"),  # no units: analyze reads it and says so; view and record --from refuse NWB
    ("SESSION.NWB", "an nwb file"),
    ("lab.nc", "an nwb file"),
    ("nwb_link.nc", "an nwb file"),
    ("foreign.h5", "neither netcdf-4 nor nwb"),
    ("classic.nc", "netcdf-3"),
    ("rec_no_layers.nc", "no network layers"),
    ("empty.nc", "an empty file"),
    ("rec_bad.nc", "neither hdf5 nor netcdf"),
    ("damaged.nc", "a damaged hdf5 file"),
    ("dangling.yaml", "symbolic link to nothing"),
    ("loop.yaml", "symbolic link to nothing"),
]


def _recording_fixtures(root: Path) -> None:
    """Files of other kinds than a recording, links, and outputs that are links, beside the fuzz
    fixtures (`_fuzz_fixtures`)."""
    from datetime import UTC, datetime

    import h5py
    import xarray as xr
    from pynwb import NWBHDF5IO, NWBFile, TimeSeries

    session = NWBFile(session_description="a session", identifier="x", session_start_time=datetime.now(UTC))
    session.add_acquisition(TimeSeries(name="lfp", data=np.zeros(10), unit="V", rate=1000.0))
    with NWBHDF5IO(str(root / "session.nwb"), "w") as io:
        io.write(session)
    for copy in ("SESSION.NWB", "lab.nc"):
        shutil.copy(root / "session.nwb", root / copy)
    with h5py.File(root / "foreign.h5", "w") as f:
        f["x"] = np.arange(5)
    xr.Dataset({"a": ("x", np.arange(3))}).to_netcdf(root / "classic.nc", engine="scipy")
    (root / "empty.nc").write_bytes(b"")
    (root / "damaged.nc").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 200)
    for link, target in {
        "nwb_link.nc": "session.nwb",
        "dir_link": "a_dir",
        "dangling_out.png": "missing_dir/x.png",
        "dangling_out.rrd": "nowhere.rrd",
        "dangling_out.nwb": "nowhere.nwb",
        "dangling_out.nc": "nowhere.nc",
        "ok.rrd": "nowhere_else.rrd",
        "loop_out.png": "loop_out.png",
        "to_text.png": "afile.txt",
        "dir_link.rrd": "a_dir",
    }.items():
        (root / link).symlink_to(target)
    _lab_nwb_fixtures(root)


LAB_FILES = {  # a lab's NWB file that vnl's analyses cannot use -> tests/recordings.nwb_session's arguments, reason
    "lab_no_units.nwb": ({"units": None}, "no units (no units table"),
    "lab_no_spikes.nwb": ({"units": "empty"}, "holds no spikes"),
    "lab_no_spike_times.nwb": ({"units": "no_column"}, "has no spike_times column"),
    "lab_no_behaviour.nwb": ({"behaviour": False}, "with no behaviour"),
    "lab_other_clock.nwb": ({"spike_offset": 1000.0}, "do not overlap; are they on one clock?"),
}


def _lab_nwb_fixtures(root: Path) -> None:
    """A lab's NWB files: a good one (lab.nwb: units, pose, speed, trials) and those of LAB_FILES."""
    from recordings import nwb_session  # tests/recordings.py

    nwb_session(root / "lab.nwb")
    for name, (kwargs, _) in LAB_FILES.items():
        nwb_session(root / name, **kwargs)


def lab_nwb_cases() -> list[Case]:
    """A lab's NWB file given to analyze and compare (issue 52): each refused with its reason, by
    the reader or the CLI's checks, before JAX."""
    cases = []
    for name, (_, expect) in LAB_FILES.items():
        cases += [
            Case("lab NWB", ["analyze", name], expect),
            Case("lab NWB", ["analyze", name, "--method", "decoding", "--target", "speed"], expect),
            Case("lab NWB", ["compare", name, "lab.nwb", "--conditions", "speed"], expect),
            Case("lab NWB", ["compare", "lab.nwb", name, "--measure", "dsa"], expect),
        ]
    for argv, expect in (
        (["analyze", "lab.nwb", "--method", "decoding"], "no target 'forward_speed' in the recording; its behaviour"),
        (["analyze", "lab.nwb", "--method", "decoding", "--target", "nose[z]"], "no target 'nose[z]'"),
        (["analyze", "lab.nwb", "--method", "encoding", "--features", "snout"], "has no snout: choose others"),
        (["analyze", "lab.nwb", "--intervals", "nope"], "no intervals table 'nope'"),
        (["analyze", "lab.nwb", "--bin", "0"], "argument --bin: must be above 0"),
        (["analyze", "lab.nwb", "--bin", "-0.02"], "argument --bin: must be above 0"),
        (["analyze", "lab.nwb", "--bin", "nan"], "argument --bin: must be above 0"),
        (["analyze", "lab.nwb", "--bin", "1e9"], "argument --bin: must be above 0"),
        (["analyze", "lab.nwb", "--bin", "abc"], "argument --bin: expected a number of seconds"),
        (["analyze", "lab.nwb", "--bin", "30", "--method", "decoding", "--target", "speed"], "a smaller --bin"),
        (["analyze", "rec.nc", "--bin", "0.02"], "--bin read an nwb file's times"),
        (["analyze", "rec.nc", "--intervals", "trials"], "--intervals read an nwb file's times"),
        (["compare", "lab.nwb", "rec.nc"], "--conditions variable"),
        (["compare", "lab.nwb", "run", "--conditions", "speed"], "is a run directory"),
        (["compare", "lab.nwb", "rec.nc", "--measure", "dsa", "--conditions", "speed"], "leave --conditions out"),
        (["compare", "lab.nwb", "rec.nc", "--conditions", "speed", "--recording", "rec.nc"], "leave --recording"),
        (["compare", "lab.nwb", "rec.nc", "--conditions", "nope"], "no target 'nope'"),
        (["compare", "lab.nwb", "lab.nwb", "--conditions", "nose"], "nose has 2 columns"),
        (["compare", "lab.nwb", "lab.nwb", "--conditions", "speed,speed,speed"], "names 3 variables"),
        (["compare", "lab.nwb", "rec.nc", "--conditions", "speed,reward"], "do not overlap"),
        (["compare", "lab.nwb", "rec.nc", "--measure", "dsa"], "read the nwb files with --bin 0.1"),
        (
            ["compare", "lab.nwb", "lab.nwb", "--conditions", "speed", "--condition-bins", "1"],
            "--condition-bins: must be",
        ),
        (["compare", "run", "run", "--recording", "lab.nwb"], "holds no observations"),
        (["compare", "run", "run", "--bin", "0.1"], "--bin and --intervals read nwb files"),
        (["compare", "rec.nc", "rec.nc", "--conditions", "reward", "--bin", "0.1"], "none of the recordings is an nwb"),
        (["view", "lab.nwb"], "`vnl analyze` and `vnl compare` read nwb files"),
        (["record", "--from", "lab.nwb"], "`vnl analyze` and `vnl compare` read nwb files"),
    ):
        cases.append(Case("lab NWB", argv, expect))
    return cases


def recording_cases(ro: Path) -> list[Case]:
    """The recording commands' inputs and outputs (see above)."""
    cases: list[Case] = []
    for name, expect in FOREIGN:
        for argv in (
            ["analyze", name],
            ["analyze", name, "--method", "states"],
            ["view", name],
            ["record", "--from", name],
            ["compare", name, "run"],
            ["compare", "run", "run", "--recording", name],
        ):
            cases.append(Case("recording inputs", argv, expect))
    for path in (".", "..", "a_dir", "dir_link"):
        cases += [
            Case("directories as inputs", ["analyze", path], "is a directory"),
            Case("directories as inputs", ["record", "--from", path], "is a directory"),
            Case("directories as inputs", ["compare", "run", "run", "--recording", path], "is a directory"),
            Case("directories as inputs", ["view", path], "not a vnl run directory"),
            Case("directories as inputs", ["compare", path, "run"], "not a vnl run directory"),
        ]
    cases.append(Case("directories as inputs", ["view", "rec.nc", "--step", "0"], "a recording was given"))
    for argv, expect in (
        (["analyze", "rec.nc", "--out", "dangling_out.png"], "is a symbolic link (to nothing"),
        (["analyze", "rec.nc", "--method", "encoding", "--out", "loop_out.png"], "is a symbolic link (to nothing"),
        (["analyze", "rec.nc", "--out", "to_text.png"], "is a symbolic link (to "),
        (["analyze", "rec.nc", "--out", "dir_link"], "expected a .png"),
        (["view", "rec.nc", "--out", "dangling_out.rrd"], "is a symbolic link (to nothing"),
        (["view", "rec.nc", "--out", "dir_link.rrd"], "is a symbolic link (to "),
        (["view", "run", "--out", "dangling_out.rrd"], "is a symbolic link (to nothing"),
        (["record", "--from", "rec.nc", "--out", "dangling_out.nwb"], "is a symbolic link (to nothing"),
        (["record", "run", "--out", "dangling_out.nc"], "is a symbolic link (to nothing"),
        (
            ["record", "run", "--viewer", "--out", "ok.nc"],
            "is a symbolic link (to nothing",
        ),  # ok.rrd: a link to nothing
        (["compare", "run", "run", "--out", "dangling_out.png"], "is a symbolic link (to nothing"),
        (["compare", "run", "run", "--out", "to_text.png"], "is a symbolic link (to "),
        (["compare", "rec.nc", "run"], "does not say which run"),  # its default output is beside that run
        (["compare", "run", "run", "--out", f"{ro}/x.png"], "read-only"),
        (["view", "rec.nc", "--out", f"{ro}/x.rrd"], "read-only"),
        (["record", "--from", "rec.nc", "--out", f"{ro}/x.nwb"], "read-only"),
        (["analyze", "rec.nc", "--method", "decoding", "--out", f"{ro}/d.png"], "read-only"),
    ):
        cases.append(Case("recording outputs", argv, expect))
    return cases


def test_generated_fuzz_of_recording_inputs_and_outputs(tmp_path):
    """Every input and output of record, analyze, compare and view (issue 53): foreign HDF5, NWB,
    links, directories; a lab's NWB files the analyses cannot use and the flags that read them
    (issue 52); each refused before JAX with its reason, nothing changed."""

    def make_cases(ro: Path) -> list[Case]:
        _recording_fixtures(tmp_path / "template")
        return recording_cases(ro) + lab_nwb_cases()

    _run_all(tmp_path, make_cases, 150)


def test_generated_fuzz_of_links_and_odd_inputs(tmp_path):
    """Issue 53: outputs that are links (to a file, to nothing), a copy made of links with a
    linked lock, a linked checkpoints folder, `.`, `..` and other odd paths."""
    _run_all(tmp_path, lambda ro: link_and_odd_input_cases(), 25)
