"""Writes the generated pages of the docs site at build time (mkdocs-gen-files runs this file):
the CLI reference, the config keys, one page per registered env, and the result cards. None of
them is stored in docs/: they are made from the code and the results data on every build.
"""

from __future__ import annotations

import sys
from pathlib import Path

import mkdocs_gen_files

sys.path.insert(0, str(Path(__file__).resolve().parent))
import reference  # noqa: E402  (scripts/docs/reference.py)
import results  # noqa: E402  (scripts/docs/results.py)

from vnl.cli import build_parser  # noqa: E402
from vnl.cli.process import configure_process  # noqa: E402

configure_process()  # as the CLI: headless OpenGL, quiet third-party deprecations (jaxopt through brax)

with mkdocs_gen_files.open("reference/cli.md", "w") as f:
    f.write(reference.cli_markdown(build_parser()))
mkdocs_gen_files.set_edit_path("reference/cli.md", "../vnl/cli/__init__.py")

with mkdocs_gen_files.open("reference/config.md", "w") as f:
    f.write(reference.config_markdown())
mkdocs_gen_files.set_edit_path("reference/config.md", "../vnl/train/config.py")

names = reference.env_names()
with mkdocs_gen_files.open("reference/envs/index.md", "w") as f:
    f.write(reference.envs_index(names))
for name in names:
    with mkdocs_gen_files.open(f"reference/envs/{name}.md", "w") as f:
        f.write(reference.env_markdown(name))

for page, content in results.pages(Path(__file__).resolve().parents[2] / "docs").items():
    with mkdocs_gen_files.open(page, "wb" if isinstance(content, bytes) else "w") as f:
        f.write(content)

# The tutorials with their outputs: the notebook tests (tests/test_notebook.py) execute each
# tutorial and write it to build/notebooks/; the site shows that copy when its cells are the
# tutorial's own (else the tutorial as written, without outputs).
ROOT = Path(__file__).resolve().parents[2]
for source in sorted((ROOT / "docs" / "tutorials").glob("*.ipynb")):
    executed = ROOT / "build" / "notebooks" / source.name
    if executed.is_file():
        import json

        cells = [(c["cell_type"], "".join(c["source"])) for c in json.loads(source.read_text())["cells"]]
        ran = json.loads(executed.read_text())
        if [(c["cell_type"], "".join(c["source"])) for c in ran["cells"]] == cells:
            with mkdocs_gen_files.open(f"tutorials/{source.name}", "w") as f:
                f.write(executed.read_text())
