"""Writes the generated pages of the docs site at build time (mkdocs-gen-files runs this file):
the CLI reference, the config keys, one page per registered env with a picture of it, and the
result cards. None of them is stored in docs/: they are made from the code and the results data on
every build. (The tutorials are stored with their outputs: scripts/docs/notebooks.py.)
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
    with mkdocs_gen_files.open(f"reference/envs/{name}.png", "wb") as f:
        f.write(reference.env_picture(name))  # rendered from the env at reset (OpenGL: EGL or OSMesa)

for page, content in results.pages(Path(__file__).resolve().parents[2] / "docs").items():
    with mkdocs_gen_files.open(page, "wb" if isinstance(content, bytes) else "w") as f:
        f.write(content)
