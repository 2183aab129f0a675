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
    from vnl.cli import COMMANDS

    assert set(flags) == set(reference._subparsers(build_parser())) and len(flags) == len(COMMANDS)
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
    assert "sampled actions" not in card
    for s in (0, 1):  # `benchmarks/learning.py --sampled 16`: a second table
        mean = {"eval/episode_reward": 900.0 + s, "eval/mean_forward_velocity": 1.5 + s / 10}
        zeros = dict.fromkeys(mean, 0.0)
        std = {"eval/episode_reward": 20.0, "eval/mean_forward_velocity": 0.25}
        sampled = {"episodes": 16, "untrained": zeros, "untrained_std": zeros, "trained": mean, "trained_std": std}
        entry["seeds"][str(s)]["sampled"] = sampled
    (docs / "results" / "results.json").write_text(json.dumps({"ant_run": entry}))
    card = results.pages(docs)["results/ant_run.md"]
    assert "`vnl eval RUN --stochastic --episodes 16`" in card
    assert "| vx (m/s) | +0.00 | **+1.55** | +1.50 to +1.60 | +1.50 ± 0.25, +1.60 ± 0.25 |" in card, card


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


# --- the user pages: numbers, API names, examples, tutorials, the built site (issue 52) ---------
import check_site  # noqa: E402  (scripts/docs/check_site.py)
import hooks  # noqa: E402  (scripts/docs/hooks.py)
import notebooks  # noqa: E402  (scripts/docs/notebooks.py)
import pages  # noqa: E402  (scripts/docs/pages.py)


def experiment_pages() -> dict[str, str]:
    return {p.name: p.read_text() for p in (ROOT / "docs" / "experiments").glob("*.md")}


def test_every_measured_number_on_a_user_page_has_a_source_and_agrees_with_it():
    """Minutes, speeds, steps/s, speed-ups and R² on the getting-started, how-to, tutorial and
    reference pages (and in the preset comments the env pages show): each agrees with its env's
    result card, or is written on the experiment page the paragraph cites, or carries its date and
    command. The experiment pages themselves are the dated log and are not checked."""
    data, linked = results.load(), experiment_pages()
    faults = [f for page, text in pages.user_pages().items() for f in pages.number_faults(page, text, data, linked)]
    for preset in sorted((ROOT / "vnl" / "train" / "presets").glob("*.yaml")):
        faults += pages.number_faults(preset.name, pages.preset_comments(preset.read_text()), data, linked)
    assert not faults, "\n".join(faults)


def test_the_number_check_finds_a_number_that_disagrees_with_the_data():
    data = results.load()
    seeds = data["ant_run"]["seeds"].values()
    minutes = sum(s["minutes"] for s in seeds) / len(seeds)
    wrong = f"The ant (`ant_run`) learns to run in about {minutes + 3.1:.1f} minutes on a CPU.\n"
    right = f"The ant (`ant_run`) learns to run in about {minutes:.0f} minutes on a CPU.\n"
    assert pages.number_faults("p.md", wrong, data, {}) and not pages.number_faults("p.md", right, data, {})
    cited = "The rat ran at 1.66-1.79 m/s ([gait](../experiments/gait.md)).\n"
    assert pages.number_faults("p.md", cited, data, {"gait.md": "seeds at 1.60-1.70 m/s"})
    assert not pages.number_faults("p.md", cited, data, {"gait.md": "three seeds: 1.66-1.79 m/s"})
    unsourced = "On a laptop the rat trains at 2,900 steps/s.\n"
    dated = "On 2026-11-24 (`benchmarks/ppo_throughput.py --envs rodent_run`) the rat trained at 2,900 steps/s.\n"
    assert pages.number_faults("p.md", unsourced, data, {}) and not pages.number_faults("p.md", dated, data, {})
    assert not pages.number_faults("p.md", "5 × 10 ms physics steps; the target is 1 m/s.\n", data, {})


def test_a_table_on_a_user_page_states_each_env_as_the_code_builds_it():
    """A table row naming an env in its first cell, with an observation, actions, control step or
    episode column, must agree with the env `vnl.make` builds (issue 52: 42 and 159 on one page,
    67 and 178 on the env pages)."""
    from vnl.envs import registry

    built: dict[str, dict[str, float] | None] = {}

    def facts(name: str) -> dict[str, float] | None:
        if name not in built:
            env = vnl.make(name, impl="c") if name in registry.names() else None
            built[name] = env and {
                "observation": env.observation_size,
                "actions": env.action_size,
                "dt": round(env.dt, 6),
                "episode": env.config.episode_length,
            }
        return built[name]

    faults = [f for page, text in pages.user_pages().items() for f in pages.table_faults(page, text, facts)]
    assert not faults, "\n".join(faults)
    stale = "| name | obs | act |\n|---|---|---|\n| `ant_run` | 42 | 8 |\n"
    size = facts("ant_run")["observation"]
    assert pages.table_faults("p.md", stale, facts) == [f"p.md: ant_run's observation is '42' here, {size} in the code"]


def test_the_api_reference_documents_every_vnl_name_the_user_pages_use():
    """Whatever names the tutorials, how-tos and getting-started pages use (`from vnl.compare import
    ...`, `vnl.neuro.nwb.report`, inline `vnl.x.y`), each resolves and docs/reference/api.md
    documents it (its `::: name` entry, or its module's or class's)."""
    import types

    documented = pages.documented((ROOT / "docs" / "reference" / "api.md").read_text())
    unresolved, missing = [], []
    for page, text in pages.user_pages().items():
        for name in sorted(pages.names_used(text)):
            if not pages.public(name):
                continue
            try:
                obj = pages.resolve(name)
            except LookupError as e:
                unresolved.append(f"{page}: {e}")
                continue
            if not isinstance(obj, types.ModuleType) and not pages.covered(obj, documented):
                missing.append(f"{page}: {name}")
    assert not unresolved, "names that do not exist:\n" + "\n".join(unresolved)
    assert not missing, "used on a page, not in docs/reference/api.md:\n" + "\n".join(missing)


def test_the_api_check_sees_a_name_the_reference_leaves_out():
    page = "```python\nfrom vnl import compare\n\nnet = compare.network(src, obs, mask, 'a')\n```\n"
    assert "vnl.compare.network" in pages.names_used(page)
    api = "::: vnl.compare.linear_cka\n"
    assert not pages.covered(pages.resolve("vnl.compare.network"), pages.documented(api))
    assert pages.covered(pages.resolve("vnl.compare.linear_cka"), pages.documented(api))
    assert "vnl.neuro.nwb.report" in pages.names_used("Then `vnl.neuro.nwb.report(messages)` prints them.\n")


def test_every_example_on_a_user_page_reads_only_what_an_earlier_example_made():
    """Run in order from an empty directory, no example reads a run directory or file that no
    earlier example of its page made (issue 52: 25 examples used runs nothing had created)."""
    faults = [f"{page}: {f}" for page, text in pages.user_pages().items() for f in pages.missing_inputs(text)]
    assert not faults, "\n".join(faults)
    page = "```bash\nvnl train ant_run --out runs/ant\nvnl eval runs/ant\nvnl record runs/rat\n```\n"
    assert pages.missing_inputs(page) == ["`vnl record runs/rat` reads runs/rat, which no earlier example made"]
    assert pages.missing_inputs("```python\nvnl.load_policy('runs/x')\n```\n")


def test_the_tutorials_are_stored_with_clean_outputs_of_their_current_cells():
    """docs/tutorials/*.ipynb carry their outputs (every build of the site shows them): executed
    top to bottom by scripts/docs/notebooks.py, with no error, warning, local path or placeholder,
    and made by the cells as they are now (a changed cell without new outputs fails)."""
    import nbformat

    for path in sorted((ROOT / "docs" / "tutorials").glob("*.ipynb")):
        nb = nbformat.read(path, as_version=4)
        assert notebooks.faults(nb) == [], (path.name, notebooks.faults(nb))
        assert any(c.get("outputs") for c in nb.cells if c.cell_type == "code"), path.name
        note = nb.cells[-1]
        assert notebooks.EXECUTED_TAG in note.metadata.get("tags", []) and nb.metadata["vnl"]["executed"] in note.source
        nb.cells[1].source += "\n# edited"
        assert any("changed since" in f for f in notebooks.faults(nb)), path.name


def test_the_outputs_check_finds_warnings_paths_and_errors():
    import nbformat

    nb = nbformat.v4.new_notebook()
    cell = nbformat.v4.new_code_cell("x", execution_count=1)
    cell.outputs = [
        nbformat.v4.new_output("stream", name="stderr", text="/home/me/.venv/jaxopt/x.py: DeprecationWarning: x"),
        nbformat.v4.new_output("stream", name="stdout", text="<rerun_notebook.Viewer object at 0x7f01b1ce43b0>\n"),
    ]
    nb.cells = [cell]
    nb.metadata["vnl"] = {"sources_sha256": notebooks.sources_sha256(nb)}
    found = " ".join(notebooks.faults(nb))
    assert "stderr" in found and "a warning" in found and "a local path" in found and "a memory address" in found


def test_hand_written_pages_get_their_tables_from_the_data_when_the_site_is_built():
    page = "What to expect:\n\n<!-- vnl:results -->\n\nMore.\n"
    out = hooks.expand(page, "getting-started/first-run.md", ROOT / "docs")
    assert "| [ant_run](../results/ant_run.md) |" in out and "<!-- vnl:" not in out
    with pytest.raises(ValueError, match="unknown marker"):
        hooks.expand("<!-- vnl:nonsense -->\n", "index.md", ROOT / "docs")
    assert "<!-- vnl:results -->" in (ROOT / "docs" / "getting-started" / "first-run.md").read_text()
    assert "<!-- vnl:envs -->" in (ROOT / "docs" / "getting-started" / "first-run.md").read_text()


def test_a_table_cell_keeps_angle_brackets_and_pipes_visible():
    """The CLI reference showed `default runs/-` (`<env>` taken for an HTML tag) and `\\|` inside
    code (issue 52)."""
    assert reference._cell("run directory (default runs/<env>-<timestamp>)") == (
        "run directory (default runs/&lt;env&gt;-&lt;timestamp&gt;)"
    )
    assert reference._cell("one of `a|b` or c|d") == "one of `a|b` or c\\|d"
    assert reference._code("float | None") == "`float | None`"
    rows = reference.flag_rows(reference._subparsers(build_parser())["train"])
    assert any("&lt;env&gt;" in help_text for *_, help_text in rows)


def write_site(root: Path, pages_html: dict[str, str]) -> Path:
    for name, body in pages_html.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(f"<html><body>{body}</body></html>")
    return root


def test_the_site_check_finds_dead_links_anchors_hidden_text_and_missing_downloads(tmp_path):
    good = write_site(
        tmp_path / "good",
        {
            "index.html": '<a href="a/">a</a> <a href="a/#x">x</a> <a href="https://example.org">ext</a>',
            "a/index.html": '<h2 id="x">x</h2><a href="../index.html">home</a>',
            "tutorials/t/index.html": '<a href="t.ipynb" download>Download</a>',
            "tutorials/t/t.ipynb": "{}",
        },
    )
    assert check_site.check(good) == ([], ["https://example.org"])
    bad = write_site(
        tmp_path / "bad",
        {
            "index.html": '<a href="../how-to/neurophysiology.md">x</a> <a href="a/#nope">y</a>',
            "a/index.html": "<p>default runs/<env>-x</p><td>float \\| None</td>",
            "tutorials/t/index.html": "<p>no link</p>",
        },
    )
    faults = "\n".join(check_site.check(bad)[0])
    assert "no such file" in faults and "no id 'nope'" in faults and "<env>" in faults
    assert "literal" in faults and "no download link to t.ipynb" in faults


@pytest.mark.slow
def test_an_env_page_shows_the_env_rendered_at_reset():
    """The picture on each env page is MuJoCo's render of the env right after reset, from its
    default video camera (OpenGL: EGL or OSMesa, as videos need)."""
    import io

    import numpy as np
    from PIL import Image

    image = np.asarray(Image.open(io.BytesIO(reference.env_picture("ant_run", 96, 72))).convert("RGB"))
    assert image.shape == (72, 96, 3) and image.std() > 10  # a scene, not a blank frame
    page = reference.env_markdown("ant_run")
    assert "![ant_run right after reset, from its default video camera](ant_run.png)" in page


def test_no_user_page_says_a_sentence_or_shows_an_image_twice():
    faults = [f"{page}: {f}" for page, text in pages.user_pages().items() for f in pages.repeats(text)]
    assert not faults, "\n".join(faults)
    assert pages.repeats("![a](x.png)\n\nText.\n\n![a](x.png)\n") == ["image twice: x.png"]
