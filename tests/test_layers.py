"""vnl's modules import each other in the order docs/developers/layers.md writes down, and in no
circle; no module is over 500 lines. The layers are read from that page itself, so the text and
the code cannot drift apart."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "vnl"


def written_layers() -> list[set[str]]:
    """The layer table of docs/developers/layers.md, top (index 0) to bottom: each layer's units
    (`vnl.train`, `vnl.tasks`, ...)."""
    text = (ROOT / "docs" / "developers" / "layers.md").read_text()
    block = re.search(r"<!-- layers -->\n```\n(.*?)```", text, re.S)
    assert block, "docs/developers/layers.md has no layers block (<!-- layers --> followed by a code block)"
    layers = []
    for line in block.group(1).strip().splitlines():
        paths = re.findall(r"vnl/[\w/]*?(?:\.py|/)", line)
        units = {"vnl." + p.removeprefix("vnl/").removesuffix(".py").removesuffix("/").replace("/", ".") for p in paths}
        assert units, line
        layers.append(units)
    return layers


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> set[str]:
    """The vnl modules `path` imports anywhere (module level or inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("vnl")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("vnl"):
            for a in node.names:  # `from vnl.io import checkpoint` imports the module vnl.io.checkpoint
                sub = f"{node.module}.{a.name}"
                is_module = (ROOT / (sub.replace(".", "/") + ".py")).is_file() or (
                    ROOT / sub.replace(".", "/")
                ).is_dir()
                found.add(sub if is_module else node.module)
    return found


def graph() -> dict[str, set[str]]:
    return {module_name(p): imports(p) - {module_name(p)} for p in sorted(PACKAGE.rglob("*.py"))}


def unit_of(module: str, units: set[str]) -> str:
    """The layer unit holding `module`: the longest unit that is it or a package above it."""
    owners = [u for u in units if module == u or module.startswith(u + ".")]
    assert owners, f"{module} is in no layer of docs/developers/layers.md"
    return max(owners, key=len)


def test_every_import_points_down_or_within_its_layer():
    layers = written_layers()
    units = set().union(*layers)
    level = {u: i for i, layer in enumerate(layers) for u in layer}  # 0 = top
    wrong = []
    for module, targets in graph().items():
        if module == "vnl":  # the package facade: its lazy table loads the public API on first use
            continue
        mine = level[unit_of(module, units)]
        for target in targets:
            theirs = level[unit_of(target, units)] if target != "vnl" else len(layers)
            if theirs < mine:
                wrong.append(f"{module} (layer {mine}) imports {target} (layer {theirs}, above it)")
    assert not wrong, "\n".join(sorted(wrong))


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    cycles, state = [], {}

    def visit(node: str, stack: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == "open":
                cycles.append(stack[stack.index(nxt) :] + [nxt])
            elif nxt not in state:
                visit(nxt, [*stack, nxt])
        state[node] = "done"

    for node in sorted(edges):
        if node not in state:
            visit(node, [node])
    return cycles


def test_no_import_cycles_between_modules_or_packages():
    g = {m: {t for t in ts if t != "vnl"} for m, ts in graph().items() if m != "vnl"}
    assert not _cycles(g), _cycles(g)
    units = set().union(*written_layers())
    packages: dict[str, set[str]] = {}
    for module, targets in g.items():
        mine = unit_of(module, units)
        packages.setdefault(mine, set()).update(unit_of(t, units) for t in targets if unit_of(t, units) != mine)
    assert not _cycles(packages), _cycles(packages)


def test_the_checks_catch_an_upward_import_and_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == [["a", "b", "c", "a"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
    layers = written_layers()
    assert unit_of("vnl.ppo.loop", set().union(*layers)) == "vnl.ppo"
    top = {u: i for i, layer in enumerate(layers) for u in layer}
    assert top["vnl.cli"] < top["vnl.train"] < top["vnl.ppo"] < top["vnl.envs"] < top["vnl.tasks"] < top["vnl.walkers"]


def test_no_function_is_over_80_lines():
    long = [
        f"{p.relative_to(ROOT)}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
        for p in PACKAGE.rglob("*.py")
        for node in ast.walk(ast.parse(p.read_text()))
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.end_lineno - node.lineno + 1 > 80
    ]
    assert not long, long


def test_no_module_is_over_500_lines():
    long = {str(p.relative_to(ROOT)): n for p in PACKAGE.rglob("*.py") if (n := len(p.read_text().splitlines())) > 500}
    assert not long, long


HEAVY = ("pynwb", "hdmf", "ndx_pose", "nwbinspector", "pynapple", "sklearn", "rsatoolbox", "hmmlearn")


@pytest.mark.slow
def test_vnl_train_imports_none_of_the_neuroscience_tools():
    # What `vnl train` imports: the CLI with every subcommand's parser, the train command and all
    # that training loads, an env built and stepped.
    code = (
        "import sys\n"
        "from vnl.cli import build_parser\n"
        "import vnl.cli.cmd_train, vnl.train.trainer, vnl.train.session, vnl.train.distributed\n"
        "import vnl.policy, vnl.rollout, vnl.envs.registry\n"
        "from vnl.train import config\n"
        "env = config.build('rodent_run', 'tiny', assignments=['env_config.impl=c']).make_env()\n"
        "build_parser().parse_args(['train', 'rodent_run'])\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]"


def documented_modules() -> set[str]:
    """The modules (paths under vnl/) that the developer guide's Layout block names: an entry
    `pkg/  a.py, b.py (...)` names pkg/__init__.py, pkg/a.py, pkg/b.py; `cmd_<name>.py` any cmd_*.py."""
    text = (ROOT / "docs" / "developers" / "index.md").read_text()
    block = re.search(r"## Layout\n\n```\nvnl/\n(.*?)```", text, re.S)
    assert block, "docs/developers/index.md has no Layout block starting with vnl/"
    entries: list[str] = []
    for line in block.group(1).splitlines():
        if re.match(r"  \S", line):
            entries.append(line.strip())
        elif line.startswith("    ") and entries:
            entries[-1] += " " + line.strip()
        else:
            break  # the first line outside vnl/ (benchmarks/, scripts/, ...)
    found = set()
    for entry in entries:
        head = entry.split()[0]
        package = head if head.endswith("/") else ""
        if package:
            found.add(package + "__init__.py")
        for token in re.findall(r"[\w<>/]+(?:\.py|/)", entry):
            path = token if "/" in token.rstrip("/") or not package else package + token
            found.add(path + "__init__.py" if path.endswith("/") else path)
    return found


def test_every_module_is_in_the_developer_guides_layout():
    documented = documented_modules()
    patterns = [
        re.compile(re.sub(r"<\w+>", r"\\w+", re.escape(d).replace(r"\<", "<").replace(r"\>", ">"))) for d in documented
    ]
    missing = [
        str(p.relative_to(PACKAGE))
        for p in sorted(PACKAGE.rglob("*.py"))
        if not any(pat.fullmatch(str(p.relative_to(PACKAGE))) for pat in patterns)
    ]
    assert not missing, f"modules missing from docs/developers/index.md's Layout: {missing}"
