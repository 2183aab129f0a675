"""The docs: generated reference pages cover every CLI flag and every registered env, the result
cards come from the results file, the README stays short and names no section of itself in the
code. (`mkdocs build --strict` in .ci/run checks links and pages.)"""

import argparse
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts" / "docs"))

import reference  # noqa: E402  (scripts/docs/reference.py)
import results  # noqa: E402  (scripts/docs/results.py)

import vnl  # noqa: E402
from vnl.cli import build_parser  # noqa: E402


def every_flag(parser: argparse.ArgumentParser) -> dict[str, list[str]]:
    return {
        name: [s for a in p._actions for s in a.option_strings if s not in ("-h", "--help")]
        for name, p in reference._subparsers(parser).items()
    }


def test_the_cli_reference_lists_every_flag_of_every_command():
    page = reference.cli_markdown(build_parser())
    flags = every_flag(build_parser())
    assert set(flags) == {"list", "train", "eval", "render", "plot", "record", "view", "compare", "analyze"}
    for command, names in flags.items():
        section = page.split(f"## vnl {command}\n", 1)[1].split("\n## vnl ", 1)[0]
        missing = [f for f in names if f"`{f}`" not in section]
        assert not missing, f"vnl {command}: {missing} not in the CLI reference"


def test_a_new_flag_appears_in_the_cli_reference_without_editing_it():
    parser = build_parser()
    train = reference._subparsers(parser)["train"]
    train.add_argument("--brand-new-flag", type=int, help="a flag nobody documented by hand")
    assert "`--brand-new-flag`" in reference.cli_markdown(parser)
    assert "a flag nobody documented by hand" in reference.cli_markdown(parser)


def test_every_config_key_is_in_the_config_reference():
    import dataclasses

    from vnl.train.config import TrainConfig

    page = reference.config_markdown()
    for f in dataclasses.fields(TrainConfig):
        assert f"`{f.name}`" in page
    for section, cls in reference._nested(TrainConfig).items():
        for f in dataclasses.fields(cls):
            assert f"`{section}.{f.name}`" in page, f"{section}.{f.name}"


@pytest.mark.slow
def test_one_page_per_registered_env_with_one_observation_size():
    """Builds each env (C physics) for every preset: the page states one observation size, the
    size `vnl.make` gives, and the camera `--vision` adds."""
    from vnl.envs import registry

    for name in registry.names():
        page = reference.env_markdown(name)
        sizes = re.findall(r"\*\*Observation size (\d+)\*\*, the same under every preset", page)
        assert sizes == [str(vnl.make(name, impl="c").observation_size)], (name, sizes)
        assert "## env_config keys and defaults" in page and "reward terms" in page and "With `--vision`" in page


def test_result_cards_come_from_the_results_file(tmp_path):
    """A card's numbers are read from the results file: change the file, the card changes."""
    import json

    entry = {
        "env": "ant_run",
        "preset": "cpu",
        "measures": [["eval reward", "eval/episode_reward", ".1f"], ["vx (m/s)", "eval/mean_forward_velocity", "+.2f"]],
        "seeds": {
            str(s): {
                "untrained": {"eval/episode_reward": 500.0, "eval/mean_forward_velocity": 0.0},
                "trained": {"eval/episode_reward": 1289.4 + s, "eval/mean_forward_velocity": 1.96 + s / 10},
                "minutes": 3.1,
                "steps": 1105920,
                "steps_per_sec": 8000,
                "curve": {
                    "step": [0, 1105920],
                    "eval/episode_reward": [500.0, 1289.4],
                    "eval/mean_forward_velocity": [0, 2],
                },
            }
            for s in (0, 1)
        },
        "frame": "images/results/ant_run.png",
        "machine": "a test machine",
        "date": "2026-11-26",
        "vnl_commit": "abc1234",
        "command": "benchmarks/learning.py --envs ant_run --seeds 0 1",
        "alongside": "nothing",
    }
    docs = tmp_path / "docs"
    (docs / "results").mkdir(parents=True)
    (docs / "results" / "results.json").write_text(json.dumps({"ant_run": entry}))
    pages = results.pages(docs)
    card = pages["results/ant_run.md"]
    assert "**1289.9**" in card and "1289.4 to 1290.4" in card and "**+2.01**" in card and "a test machine" in card
    assert pages["results/ant_run_curves.png"][:4] == b"\x89PNG"
    assert "| [ant_run](ant_run.md) | vx (m/s): +2.01 (2 seeds)" in pages["results/index.md"]


def test_an_env_not_yet_measured_gets_a_card_saying_so_with_the_command(tmp_path):
    docs = tmp_path / "docs"
    (docs / "results").mkdir(parents=True)
    pages = results.pages(docs)  # no results file at all
    assert set(pages) == {"results/index.md", *(f"results/{env}.md" for env in results.ORDER)}
    assert "Not measured yet" in pages["results/humanoid_run.md"]
    assert "--envs humanoid_run --results docs/results/results.json" in pages["results/humanoid_run.md"]
    assert "| [humanoid_run](humanoid_run.md) | not measured yet |" in pages["results/index.md"]
    assert "| humanoid_run | not measured yet |" in results.expect_table({})


def test_a_card_links_the_experiment_pages_that_name_its_env(tmp_path):
    """A card whose numbers need explaining (the rat never leaves the bowl) leads to the research."""
    docs = tmp_path / "docs"
    (docs / "results").mkdir(parents=True)
    (docs / "experiments").mkdir()
    (docs / "experiments" / "bowl.md").write_text("# Can the rat climb out?\n\n`rodent_escape_bowl` stalls.\n")
    corridor = "# The corridor\n\nrodent_run_gaps, see ../results/rodent_run.md\n"
    (docs / "experiments" / "corridor.md").write_text(corridor)
    (docs / "experiments" / "index.md").write_text("# Experiments\n\nrodent_escape_bowl rodent_run\n")
    pages = results.pages(docs)
    assert "- [Can the rat climb out?](../experiments/bowl.md)" in pages["results/rodent_escape_bowl.md"]
    assert "- [The corridor](../experiments/corridor.md)" in pages["results/rodent_run_gaps.md"]
    assert "experiments/" not in pages["results/rodent_run.md"]  # a longer env's name or a link is no mention
    assert "experiments/" not in pages["results/ant_run.md"]


def test_the_shipped_results_have_their_frames_and_the_readme_table_is_theirs():
    data = results.load()
    for env, entry in data.items():
        assert (ROOT / "docs" / entry["frame"]).is_file(), f"{env}: frame {entry['frame']} missing"
    readme = (ROOT / "README.md").read_text()
    start, end = results.README_MARK
    assert readme.split(start, 1)[1].split(end, 1)[0].strip() == results.expect_table(data).strip(), (
        "README's table differs from the results file: run .venv/bin/python scripts/docs/results.py --readme"
    )


def test_the_readme_is_short_and_carries_no_test_counts_or_ci_minutes():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    assert "vnl train rodent_run" in readme
    assert not re.search(r"\d+ (tests|passed)\b", readme)
    assert not re.search(r"CI\b[^\n]{0,40}\d+(\.\d+)? ?min", readme)


def test_every_file_the_readme_links_to_exists():
    """README.md is read on its own (on GitHub, in a clone): it links only to files in the repo,
    not to pages the site generates."""
    readme = (ROOT / "README.md").read_text()
    targets = {t.split("#")[0] for t in re.findall(r"\]\(([^)\s]+)\)", readme) if "://" not in t}
    missing = sorted(t for t in targets if t and not (ROOT / t).exists())
    assert not missing, missing


def test_no_code_comment_names_a_readme_section():
    hits = [
        f"{p.relative_to(ROOT)}:{i}"
        for p in (ROOT / "vnl").rglob("*.py")
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if "README" in line
    ]
    assert not hits, hits


def test_every_docs_page_a_comment_or_preset_points_to_exists():
    """Comments, docstrings and presets cite their evidence as docs/... paths: each must exist."""
    cited = set()
    for p in [*(ROOT / "vnl").rglob("*.py"), *(ROOT / "vnl" / "train" / "presets").glob("*.yaml")]:
        cited |= set(re.findall(r"docs/[\w/.-]+\.(?:md|ipynb)", p.read_text()))
    generated = ("docs/reference/cli.md", "docs/reference/config.md", "docs/reference/envs/", "docs/results/")
    missing = sorted(c for c in cited if not (ROOT / c).is_file() and not c.startswith(generated))
    assert not missing, missing


def _resolves(dotted: str) -> bool:
    """Whether `vnl.a.b.c` names a module or an attribute of one (importing as needed)."""
    import importlib

    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        try:
            for name in parts[i:]:
                obj = getattr(obj, name)
        except AttributeError:
            return False
        return True
    return False


ANALYSIS_SIDE = ("vnl.analysis", "vnl.compare", "vnl.record", "vnl.recording", "vnl.rollout", "vnl.neuro", "vnl.viewer")


def test_every_analysis_name_the_tutorials_and_guides_use_exists():
    """The analysis side's public API is what the tutorials, how-tos and getting-started pages
    use: every `from vnl... import name`, every `module.attribute` of a module they import from
    vnl, and every dotted `vnl.x.y` they name still resolves (moved code keeps its public names)."""
    import ast
    import json

    names: set[str] = set()
    for path in sorted((ROOT / "docs" / "tutorials").glob("*.ipynb")):
        cells = json.loads(path.read_text())["cells"]
        code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
        code = "\n".join(line for line in code.splitlines() if not line.lstrip().startswith(("%", "!")))
        tree = ast.parse(code)
        modules = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "vnl":
                for a in node.names:
                    names.add(f"{node.module}.{a.name}")
                    modules[a.asname or a.name] = f"{node.module}.{a.name}"
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in modules:
                names.add(f"{modules[node.value.id]}.{node.attr}")
    pages = [*(ROOT / "docs" / "how-to").glob("*.md"), *(ROOT / "docs" / "getting-started").glob("*.md")]
    for page in pages:
        names |= {m.rstrip(".") for m in re.findall(r"`(vnl(?:\.\w+)+)", page.read_text())}
    names = {n for n in names if n.startswith(ANALYSIS_SIDE)}
    assert len(names) > 30, sorted(names)
    missing = sorted(n for n in names if not _resolves(n))
    assert not missing, missing
