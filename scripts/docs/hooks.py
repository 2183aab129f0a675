"""MkDocs hooks (mkdocs.yml: `hooks:`): tables a hand-written page shows, generated when the site is
built, so that no page keeps a copy of a number the code or the results data hold. A page writes a
marker on a line of its own:

- `<!-- vnl:envs -->`: every registered env as `vnl list` shows it (observation, actions, control
  step, episode, description), each linked to its reference page;
- `<!-- vnl:results -->`: what each env's `cpu` preset learns and how long it takes, from
  docs/results/results.json, each linked to its result card;
- `<!-- vnl:presets -->`: the generic presets (`cpu`, `gpu`, `tiny`) side by side, where they differ;
- `<!-- vnl:learners -->`: PPO against SAC on the same env and budget, from
  docs/results/learners.json (benchmarks/learners.py writes it).

An unknown `vnl:` marker fails the build.
"""

from __future__ import annotations

import json
import posixpath
import re
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import reference  # noqa: E402  (scripts/docs/reference.py)
import results  # noqa: E402  (scripts/docs/results.py)

MARKER = re.compile(r"^<!-- vnl:([\w-]+) -->[ \t]*$", re.M)


def _relative(page_path: str, target: str) -> str:
    """`target` (a path in the docs) as a link from the page at `page_path`."""
    return posixpath.relpath(target, posixpath.dirname(page_path) or ".")


def table(name: str, page_path: str, docs: Path) -> str:
    """The Markdown a marker stands for, with links relative to the page at `page_path`."""
    if name == "envs":
        link = _relative(page_path, "reference/envs/{name}.md")
        return "\n".join(reference.envs_table(reference.env_names(), link))
    if name == "presets":
        return "\n".join(reference.presets_table())
    if name == "results":
        link = _relative(page_path, "results/{env}.md")
        return results.expect_table(results.load(docs / "results" / "results.json"), link=link)
    if name == "learners":
        return learners_table(json.loads((docs / "results" / "learners.json").read_text()))
    raise ValueError(f"{page_path}: unknown marker <!-- vnl:{name} --> (known: envs, presets, results, learners)")


def learners_table(entries: dict[str, Any]) -> str:
    """One table per env of docs/results/learners.json: each learner's last evaluation within the
    budget (untrained -> last), its best, and where the numbers come from."""
    out: list[str] = []
    for env, e in entries.items():
        measures = e["measures"]
        names = " | ".join(f"{name} (untrained → last)" for name, _, _ in measures)
        out += [f"**{env}**, {e['minutes_budget']:g} minutes each, seed {e['seed']}:", ""]
        out += [f"| learner | env steps | minutes | {names} | best {measures[0][0]} (step, minutes) |"]
        out += ["|" + "---|" * (len(measures) + 4)]
        for r in e["rows"]:
            cells = " | ".join(f"{r['untrained'][k]:{spec}} → {r['last'][k]:{spec}}" for _, k, spec in measures)
            b = r["best"]
            best = f"{b[measures[0][1]]:{measures[0][2]}} ({b['step']:,}, {b['minutes']})"
            out.append(f"| {r['learner']} | {r['steps']:,} | {r['minutes']} | {cells} | {best} |")
        out += [
            "",
            f"*`{e['command']}`, commit {e['commit']}, {e['machine']}, {e['date']}; alongside: "
            f"{e['alongside']}; SAC settings: {', '.join(e['sac_settings'])}.*",
            "",
        ]
    return "\n".join(out)


def expand(markdown: str, page_path: str, docs: Path) -> str:
    return MARKER.sub(lambda m: table(m[1], page_path, docs), markdown)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if "<!-- vnl:" not in markdown:
        return markdown
    return expand(markdown, page.file.src_uri, Path(config["docs_dir"]))
