"""The tutorials (docs/tutorials/*.ipynb) are stored with their outputs, so every build of the site
(`mkdocs build`, `mkdocs serve`) shows them without running them. This script executes a tutorial
in a fresh kernel, in a temporary directory, checks its outputs, and writes it back in place with
its outputs and a last cell saying when, where and with which vnl it ran:

    .venv/bin/python scripts/docs/notebooks.py quickstart rat-to-neurons

It refuses to write a tutorial whose outputs hold an error, a warning, a local path or a
placeholder (`faults`); fix the cell (the tutorial's code, or vnl) rather than the output. The
outputs are stored as the kernel made them, but for live widgets (a progress bar, Rerun's viewer):
they need the running kernel, and a page cannot show them.
tests/test_docs.py checks the stored outputs (clean, and made by the cells as they are now:
`metadata.vnl.sources_sha256`); tests/test_notebook.py executes each tutorial again.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
TUTORIALS = ROOT / "docs" / "tutorials"
EXECUTED_TAG = "vnl-executed"  # the tag of the last cell, written by this script
WIDGET = "application/vnd.jupyter.widget-view+json"

# What no stored output may hold: the machine's paths, the traces of a warning, an object's memory
# address, a placeholder.
LOCAL_PATH = re.compile(r"(?<![\w.:/])/(?:work|home|root|tmp|Users|usr|opt|var|private|mnt|srv)/[\w.-]+")
WARNING = re.compile(r"\b\w*Warning\b|warnings\.warn|\bwarning:", re.I)
ADDRESS = re.compile(r"\bat 0x[0-9a-f]{6,}\b")
PLACEHOLDER = re.compile(r"YOUR-ORG|<your copy", re.I)


def code_sources(nb: Any) -> list[str]:
    return ["".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"]


def sources_sha256(nb: Any) -> str:
    """A digest of the tutorial's cells as written (code and markdown, the executed-note cell
    left out): the outputs stored with it were made by these cells if the digests agree."""
    cells = [c for c in nb["cells"] if EXECUTED_TAG not in c.get("metadata", {}).get("tags", [])]
    text = "\x00".join(f"{c['cell_type']}\x01{''.join(c['source'])}" for c in cells)
    return hashlib.sha256(text.encode()).hexdigest()


def output_text(output: Any) -> str:
    """The text of an output a reader sees: a stream, an error, or a rich output's text parts
    (plain text, HTML, LaTeX, JSON; images left out)."""
    if output.get("output_type") == "stream":
        return "".join(output.get("text", ""))
    if output.get("output_type") == "error":
        return f"{output.get('ename')}: {output.get('evalue')}"
    data = output.get("data", {})
    parts = [data[k] for k in ("text/plain", "text/html", "text/markdown", "text/latex") if k in data]
    return "\n".join("".join(p) if isinstance(p, list) else str(p) for p in parts)


def faults(nb: Any) -> list[str]:
    """What is wrong with a tutorial's stored outputs (an empty list: nothing)."""
    out = []
    code = [(i, c) for i, c in enumerate(nb["cells"]) if c["cell_type"] == "code"]
    counts = [c.get("execution_count") for _, c in code]
    if counts != list(range(1, len(code) + 1)):
        out.append(f"not executed top to bottom in one kernel (execution counts {counts})")
    for i, cell in code:
        for o in cell.get("outputs", []):
            text = output_text(o)
            if o.get("output_type") == "error":
                out.append(f"cell {i}: an error: {text[:200]}")
            if o.get("output_type") == "stream" and o.get("name") == "stderr":
                out.append(f"cell {i}: writes to stderr: {text[:200]!r}")
            for name, pattern in (("a warning", WARNING), ("a local path", LOCAL_PATH), ("a memory address", ADDRESS),
                                  ("a placeholder", PLACEHOLDER)):  # fmt: skip
                m = pattern.search(text)
                if m:
                    out.append(f"cell {i}: {name} in its output: {text[max(0, m.start() - 60) : m.end() + 60]!r}")
    meta = nb.get("metadata", {}).get("vnl", {})
    if meta.get("sources_sha256") != sources_sha256(nb):
        out.append("its cells changed since its outputs were made: run scripts/docs/notebooks.py on it")
    if any(WIDGET in o.get("data", {}) for _, c in code for o in c.get("outputs", [])):
        out.append("it stores a widget's output (a live kernel's: nothing a page can show)")
    if "widgets" in nb.get("metadata", {}):
        out.append("it stores widget state (a live kernel's; the site would load it from a CDN)")
    return out


def machine() -> str:
    cpu = "unknown CPU"
    try:
        cpu = re.search(r"model name\s*:\s*(.*)", Path("/proc/cpuinfo").read_text()).group(1).strip()  # type: ignore[union-attr]
    except (OSError, AttributeError):
        pass
    gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return f"{cpu}, {len(os.sched_getaffinity(0))} cores, {gib:.0f} GiB"


def commit() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "vnl"], cwd=ROOT, capture_output=True, text=True)
    except OSError:
        return "unknown"
    return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "") if head.returncode == 0 else "unknown"


def execute(name: str, workdir: Path, timeout: int = 900) -> Any:
    """Runs docs/tutorials/<name>.ipynb in a fresh kernel whose working directory is `workdir`,
    with this checkout's vnl and a compilation cache of its own; returns the executed notebook as
    the kernel left it (`for_storage` makes the copy stored in docs/), with when, where and how
    long in `metadata.vnl`."""
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(TUTORIALS / f"{name}.ipynb", as_version=4)
    nb.cells = [c for c in nb.cells if EXECUTED_TAG not in c.get("metadata", {}).get("tags", [])]
    client = NotebookClient(
        nb, timeout=timeout, kernel_name="python3", store_widget_state=False,
        resources={"metadata": {"path": str(workdir)}},
    )  # fmt: skip
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),  # this checkout's vnl
        "VNL_COMPILE_CACHE": str(workdir / "jax-cache"),
    }
    load = os.getloadavg()[0]  # other work on the machine slows the run: the note says how busy it was
    start = time.time()
    client.execute(env=env)
    nb.metadata["vnl"] = {
        "name": name,
        "executed": time.strftime("%Y-%m-%d"),
        "machine": machine(),
        "vnl_commit": commit(),
        "seconds": round(time.time() - start, 1),
        "load_average": round(load, 1),
    }
    return nb


def for_storage(executed: Any) -> Any:
    """The copy of an executed tutorial stored in docs/tutorials: its outputs as the kernel made
    them but for live widgets (a progress bar, Rerun's viewer: they need the running kernel, and a
    page cannot show them), no execution timings, and a last cell saying when, where, with which
    vnl and in how long it ran; `metadata.vnl.sources_sha256` ties the outputs to the cells."""
    import copy

    import nbformat

    nb = copy.deepcopy(executed)
    nb.metadata.pop("widgets", None)
    for cell in nb.cells:
        cell.metadata.pop("execution", None)
        if "outputs" in cell:
            cell.outputs = [o for o in cell.outputs if WIDGET not in o.get("data", {})]
    v = nb.metadata["vnl"]
    note = nbformat.v4.new_markdown_cell(
        f"*The outputs above are from running this notebook on {v['executed']}, on {v['machine']}, with vnl "
        f"{v['vnl_commit']}: {v['seconds'] / 60:.1f} minutes from the first cell to the last, the machine's load "
        f"average {v['load_average']:.1f} when it started* (`python scripts/docs/notebooks.py {v['name']}`, which "
        "stores them).",
        metadata={"tags": [EXECUTED_TAG]},
    )
    nb.cells.append(note)
    v["sources_sha256"] = sources_sha256(nb)
    return nb


def main(argv: list[str] | None = None) -> int:
    import nbformat

    parser = argparse.ArgumentParser(description="Execute tutorials and store them with their outputs.")
    parser.add_argument("names", nargs="+", help="tutorial names (docs/tutorials/<name>.ipynb)")
    parser.add_argument("--check", action="store_true", help="only check the stored outputs (no execution)")
    args = parser.parse_args(argv)
    status = 0
    for name in args.names:
        path = TUTORIALS / f"{name}.ipynb"
        if args.check:
            found = faults(nbformat.read(path, as_version=4))
        else:
            with tempfile.TemporaryDirectory(prefix=f"vnl-{name}-") as tmp:
                nb = for_storage(execute(name, Path(tmp)))
            found = faults(nb)
            if not found:
                nbformat.write(nb, path)
        for f in found:
            print(f"{name}: {f}")
        status |= bool(found)
        print(f"{name}: {'faults: not written' if found and not args.check else 'ok' if not found else 'faults'}")
    return status


if __name__ == "__main__":
    sys.exit(main())
