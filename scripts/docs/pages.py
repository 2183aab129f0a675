"""What the user pages of the docs say, read the way tests/test_docs.py checks it: the user pages
(getting started, how-to guides, tutorials, hand-written reference; not the dated experiment log),
their Python and shell examples, the vnl names their code uses, and the numbers they state.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import json
import re
import shlex
import types
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
USER_PAGES = ("index.md", "getting-started/*.md", "how-to/*.md", "tutorials/*.ipynb", "reference/*.md")


# --- the pages ----------------------------------------------------------------------------------
@dataclass
class Block:
    """A fenced code block of a page (or a notebook's code cell): its language and text."""

    lang: str
    text: str


def user_pages(docs: Path = DOCS) -> dict[str, str]:
    """Page (relative to docs/) -> its Markdown; a notebook as its cells (markdown cells as they are,
    code cells as ```python blocks). The hand-written reference (formats, API) is included; the
    generated one is checked where it is made (scripts/docs/reference.py)."""
    out = {}
    for pattern in USER_PAGES:
        for path in sorted(docs.glob(pattern)):
            rel = path.relative_to(docs).as_posix()
            out[rel] = notebook_markdown(path) if path.suffix == ".ipynb" else path.read_text()
    return out


def notebook_markdown(path: Path) -> str:
    cells = json.loads(path.read_text())["cells"]
    parts = []
    for c in cells:
        source = "".join(c["source"])
        parts.append(source if c["cell_type"] == "markdown" else f"```python\n{source}\n```")
    return "\n\n".join(parts) + "\n"


FENCE = re.compile(
    r"^(?P<indent>[ \t]*)(?P<fence>```+|~~~+)[ \t]*(?P<lang>[\w+-]*)[^\n]*\n(?P<body>.*?)^(?P=indent)(?P=fence)[ \t]*$",
    re.M | re.S,
)


def blocks(markdown: str) -> list[Block]:
    """The fenced code blocks of a page, in order."""
    return [Block(m["lang"].lower(), inspect.cleandoc("\n" + m["body"])) for m in FENCE.finditer(markdown)]


def prose(markdown: str) -> str:
    """The page without its fenced code blocks and HTML comments."""
    return re.sub(r"<!--.*?-->", "", FENCE.sub("", markdown), flags=re.S)


# --- the vnl names the pages use ----------------------------------------------------------------
def _code_for_ast(text: str) -> str:
    """A notebook cell or snippet as Python: IPython magics and shell lines dropped."""
    return "\n".join("" if line.lstrip().startswith(("%", "!")) else line for line in text.splitlines())


def names_in_code(text: str, aliases: dict[str, str] | None = None) -> set[str]:
    """Dotted vnl names (`vnl.compare.network`) that Python code uses: through `import vnl...`,
    `from vnl... import ...` and attribute access on what those imports bound. `aliases` (name ->
    dotted vnl name) carries the imports of earlier cells or blocks of the same page, and is updated."""
    aliases = {} if aliases is None else aliases
    try:
        tree = ast.parse(_code_for_ast(text))
    except SyntaxError:
        return set(re.findall(r"\bvnl(?:\.[A-Za-z_]\w*)+", text))  # a fragment: its dotted names
    used: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name == "vnl" or a.name.startswith("vnl."):
                    aliases[a.asname or a.name.split(".")[0]] = a.name if a.asname else "vnl"
        elif isinstance(node, ast.ImportFrom) and node.module and (node.module + ".").startswith("vnl."):
            for a in node.names:
                aliases[a.asname or a.name] = f"{node.module}.{a.name}"
                used.add(f"{node.module}.{a.name}")
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            chain, inner = [node.attr], node.value
            while isinstance(inner, ast.Attribute):
                chain.insert(0, inner.attr)
                inner = inner.value
            if isinstance(inner, ast.Name) and inner.id in aliases:
                used.add(".".join([aliases[inner.id], *chain]))
    return used


def names_in_prose(markdown: str) -> set[str]:
    """Dotted vnl names in a page's inline code (`vnl.neuro.nwb.write(ds, path)`)."""
    spans = re.findall(r"`([^`\n]+)`", prose(markdown))
    return {n for s in spans for n in re.findall(r"(?<![\w/.])vnl(?:\.[A-Za-z_]\w*)+", s)}


def names_used(markdown: str) -> set[str]:
    """Every dotted vnl name a page's Python code or inline code uses."""
    found, aliases = names_in_prose(markdown), {}
    for b in blocks(markdown):  # in order: a notebook's cells, or a page's blocks, share their imports
        if b.lang in ("python", "py", "pycon"):
            found |= names_in_code(b.text, aliases)
    return found


def resolve(dotted: str) -> Any:
    """The object a dotted name (`vnl.compare.network`) names; raises LookupError if none.

    A name reached through an object that is neither a module nor a class (an attribute of a
    function's result) is the longest prefix that is one of those."""
    parts = dotted.split(".")
    obj: Any = None
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        rest = parts[i:]
        break
    else:
        raise LookupError(f"{dotted}: no such module")
    for j, attr in enumerate(rest):
        if not isinstance(obj, (types.ModuleType, type)):
            break
        try:
            obj = getattr(obj, attr)
        except AttributeError:
            raise LookupError(f"{dotted}: {'.'.join(parts[: i + j])} has no attribute {attr!r}") from None
    return obj


def public(dotted: str) -> bool:
    return not any(p.startswith("_") for p in dotted.split("."))


def documented(api_md: str) -> list[Any]:
    """The objects docs/reference/api.md documents (its `::: dotted.name` lines)."""
    return [resolve(m) for m in re.findall(r"^::: *([\w.]+)", api_md, re.M)]


def covered(obj: Any, docs: list[Any]) -> bool:
    """Whether `obj` is documented: one of `docs`, or a member with a docstring of a documented
    module or class (mkdocstrings renders those)."""
    if any(obj is d for d in docs):
        return True
    owner_name = getattr(obj, "__module__", None)
    qual = getattr(obj, "__qualname__", "")
    for d in docs:
        if isinstance(d, types.ModuleType) and owner_name == d.__name__ and "." not in qual and obj.__doc__:
            return True
        if isinstance(d, type) and qual.startswith(d.__qualname__ + ".") and getattr(obj, "__doc__", None):
            return True
    return False


# --- shell examples: each run directory made before it is used ----------------------------------
INPUT_FLAGS = {"--resume", "--init-from", "--recording", "--from"}
SYNTHETIC = "vnl.recording.synthetic"
"""`python -m vnl.recording.synthetic FILE.nwb` writes a lab session to FILE.nwb (docs/how-to/your-nwb.md)."""
PLACEHOLDER = re.compile(r"^[A-Z][A-Z0-9_]*(\.\w+)?$|[<>|\[\]$*]|\.\.\.")  # RUN_DIR, RECORD.nc, <run>, A|B, $x, ...


def shell_commands(block: str) -> Iterator[list[str]]:
    """The vnl commands of a shell block, each as its words (comments and continuations handled;
    `a && b` is two commands; `.venv/bin/vnl` and `srun vnl` count as vnl)."""
    text = re.sub(r"\\\n", " ", block)
    for line in text.splitlines():
        line = line.split(" #", 1)[0] if not line.lstrip().startswith("#") else ""
        for part in re.split(r"&&|;|\|\|", line):
            try:
                words = shlex.split(part)
            except ValueError:
                continue
            while words and words[0] in ("srun", "sudo", "time", "nohup", "do", "then", "!"):
                words = words[1:]
            if words and words[0].endswith("vnl") and words[0].split("/")[-1] == "vnl":
                yield words
            elif words[:3] and words[0].split("/")[-1].startswith("python") and words[1:3] == ["-m", SYNTHETIC]:
                yield ["vnl", SYNTHETIC, *words[3:]]  # it makes the file it names


def _values(words: list[str]) -> tuple[list[str], dict[str, str]]:
    """Positional words and `--flag value` pairs of a command's arguments (flags without a value
    are recorded as '')."""
    positional, flags, i = [], {}, 0
    while i < len(words):
        w = words[i]
        if w.startswith("--") and "=" in w:
            k, v = w.split("=", 1)
            flags[k] = v
        elif w.startswith("-"):
            nxt = words[i + 1] if i + 1 < len(words) else None
            takes = nxt is not None and not nxt.startswith("-") and w not in NO_VALUE
            flags[w] = nxt if takes else ""
            i += takes
        else:
            positional.append(w)
        i += 1
    return positional, flags


NO_VALUE = {
    "--no-video", "--vision", "--distributed", "--print-config", "--stochastic", "--viewer", "--keep-optimizer",
    "--verbose", "-v", "--list-cameras", "--lineage", "--no-camera", "--no-compile-cache", "--help", "-h",
}  # fmt: skip


def _path(word: str) -> str | None:
    """A run directory or file a word names (`runs/rat@best` -> runs/rat), or None for a placeholder."""
    if PLACEHOLDER.search(word) or "/" not in word and not word.endswith((".nc", ".nwb", ".rrd")):
        return None
    return word.split("@")[0].rstrip("/")


def missing_inputs(markdown: str) -> list[str]:
    """The commands of a page's shell blocks, run in order from a fresh directory, that read a run
    directory or file no earlier command of the page made. A command makes `--out DIR`
    (`vnl train`), a recording (`vnl record RUN` -> RUN/record.nc or .nwb, or `--out`), and what
    `vnl analyze`/`compare`/`render`/`eval`/`view` write is not read by later examples here."""
    made: set[str] = set()
    faults = []
    for b in blocks(markdown):
        if b.lang in ("python", "py"):  # a run a Python example loads: vnl.load_policy("runs/ant")
            for r in re.findall(r"""["'](runs/[^"'\s]+)["']""", b.text):
                if not any(r == m or r.startswith(m + "/") for m in made):
                    faults.append(f"the Python example reads {r}, which no earlier example made")
            continue
        if b.lang not in ("bash", "sh", "shell", "console", ""):
            continue
        for words in shell_commands(b.text):
            if len(words) < 2:
                continue
            command, (positional, flags) = words[1], _values(words[2:])
            reads: list[str] = []
            if command in ("eval", "render", "record", "view", "analyze", "compare", "plot"):
                reads += [p for p in map(_path, positional) if p]
            reads += [p for f in INPUT_FLAGS & set(flags) if (p := _path(flags[f]))]
            if command == "render" and "--list-cameras" in flags:
                reads = [p for p in reads if p]
            for r in reads:
                if not any(r == m or r.startswith(m + "/") for m in made):
                    faults.append(f"`{' '.join(words)}` reads {r}, which no earlier example made")
            if command == SYNTHETIC and positional:
                made.add(positional[0])
            if command == "train" and flags.get("--out"):
                made.add(flags["--out"].rstrip("/"))
            if command == "train" and flags.get("--resume"):
                made.add(flags["--resume"].rstrip("/"))
            if command == "record":
                out = flags.get("--out")
                if out:
                    made.add(out)
                elif positional and (p := _path(positional[0])):
                    made.add(f"{p}/record.{'nwb' if flags.get('--format') == 'nwb' else 'nc'}")
            if command in ("view", "analyze", "compare", "eval", "render", "plot") and flags.get("--out"):
                made.add(flags["--out"])
    return faults


# --- numbers: each from the data, or dated with its command -------------------------------------
MEASURED = re.compile(
    r"(?<![\w.])(?P<a>[+-]?\d[\d,]*(?:\.\d+)?)(?:\s*(?:-|–|to)\s*(?P<b>[+-]?\d[\d,]*(?:\.\d+)?))?\s*"
    r"(?P<unit>m/s|(?:env )?steps/s|images/s|minutes?\b|min\b"
    r"|[×x](?!\s*\d)(?=\s*(?:faster|slower|more|less|fewer|as)\b|\s*[,;:)]|\s*$))"
)  # a speed (m/s, steps/s, images/s), a duration in minutes, a speed-up (1.7× faster); not a product (5 × 10 ms)
R2 = re.compile(r"R²\s*(?:of\s*)?(?P<a>[+-]?\d\.\d+)(?:\s*(?:-|–|to)\s*(?P<b>[+-]?\d\.\d+))?")
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
COMMAND = re.compile(r"`(?:vnl |\.venv/bin/|python |benchmarks/|nice )[^`]*`")


def paragraphs(markdown: str) -> list[str]:
    """A page's prose in paragraphs (code blocks and comments left out); a table is one paragraph,
    joined with the paragraph just before it (its caption: where a table says what was measured)."""
    paras = [p.strip() for p in re.split(r"\n\s*\n", prose(markdown)) if p.strip()]
    out: list[str] = []
    for p in paras:
        if p.lstrip().startswith("|") and out and not out[-1].lstrip().startswith("|"):
            out[-1] = out[-1] + "\n" + p
        else:
            out.append(p)
    return out


def _strip_code(text: str) -> str:
    return re.sub(r"`[^`\n]*`", " ", text)


def _decimals(number: str) -> int:
    return len(number.split(".")[1]) if "." in number else 0


def _num(text: str) -> float:
    return float(text.replace(",", ""))


def env_names_in(text: str, names: list[str]) -> list[str]:
    """The env names a text mentions as whole words (`rodent_run` is not in `rodent_run_gaps`)."""
    return [n for n in names if re.search(rf"(?<![\w/.-]){re.escape(n)}(?![\w-])", text)]


def agrees(stated_a: str, stated_b: str | None, values: list[float]) -> bool:
    """Whether a stated number (or range) agrees with measured values at the stated precision."""
    if stated_b is None:
        d = _decimals(stated_a)
        return (
            all(round(v, d) == round(_num(stated_a), d) for v in values)
            if len(values) == 1
            else (round(sum(values) / len(values), d) == round(_num(stated_a), d))
        )
    d = max(_decimals(stated_a), _decimals(stated_b))
    lo, hi = sorted((_num(stated_a), _num(stated_b)))
    return all(lo <= round(v, d) <= hi for v in values) and (
        round(min(values), d) == lo and round(max(values), d) == hi
    )


def on_page(a: str, b: str | None, text: str) -> bool:
    """Whether a number (or both ends of a range) is written on a page, as a whole number."""

    def token(x: str) -> bool:
        return re.search(rf"(?<![\d.,]){re.escape(x.lstrip('+'))}(?![\d]|[.,]\d)", text) is not None

    return token(a) and (b is None or token(b))


def result_values(entry: dict[str, Any], unit: str) -> list[float] | None:
    """What a result card measured for a stated unit: minutes (per seed), or the trained forward
    velocity (m/s, per seed); None for other units."""
    seeds = entry["seeds"].values()
    if unit.startswith("min"):
        return [s["minutes"] for s in seeds]
    if unit == "m/s":
        keys = [k for _, k, _ in entry["measures"] if k == "eval/mean_forward_velocity"]
        return [s["trained"][keys[0]] for s in seeds] if keys else None
    return None


def number_faults(page: str, markdown: str, results: dict[str, Any], linked: dict[str, str]) -> list[str]:
    """The measured numbers of a user page (minutes, m/s, steps/s, images/s, speed-ups, R²) that
    have no source or disagree with theirs. Each paragraph's numbers must be one of:

    - about one measured env (results.json) and nothing else: equal to its result card's value at
      the stated precision (minutes of the whole run; the trained policy's forward velocity);
    - in a paragraph that links experiment pages: on one of those pages, as written;
    - in a paragraph that carries a date and its command (a measurement reported in place).

    `linked`: experiment page (docs/experiments/<name>.md) -> its text."""
    faults = []
    names = sorted(results, key=len, reverse=True)
    for para in paragraphs(markdown):
        text = _strip_code(para)
        found = [(m, m["unit"]) for m in MEASURED.finditer(text)] + [(m, "R²") for m in R2.finditer(text)]
        if not found:
            continue
        cited = re.findall(r"(?:\]\((?:\.\./)*|docs/)experiments/([\w-]+\.md)", para)
        cited_text = "\n".join(linked.get(c, "") for c in cited)
        dated = bool(DATE.search(para) and COMMAND.search(para))
        envs = env_names_in(para, names)
        line = para.splitlines()[0][:90]
        for m, unit in found:
            stated = m.group(0).strip()
            if unit == "m/s" and "." not in m["a"]:
                continue  # a whole number of m/s is a setting (a target speed, a cap), not a measurement
            if cited:
                if not on_page(m["a"], m["b"], cited_text):
                    faults.append(f"{page}: {stated!r} is on none of the pages it cites ({', '.join(cited)}): {line}")
                continue
            if dated:
                continue
            values = result_values(results[envs[0]], unit) if len(envs) == 1 else None
            if values is None:
                faults.append(
                    f"{page}: {stated!r} has no source (no result card, no cited experiment, no date and "
                    f"command beside it): {line}"
                )
            elif not agrees(m["a"], m["b"], values):
                got = ", ".join(f"{v:g}" for v in values)
                faults.append(f"{page}: {stated!r} for {envs[0]} disagrees with its result card ({got}): {line}")
    return faults


def table_faults(page: str, markdown: str, facts: Any) -> list[str]:
    """Table rows of a user page that name an env in their first cell and state its observation
    size, action count, control step or episode length, checked against `facts(env)` (a dict with
    `observation`, `actions`, `dt`, `episode`; None for a name that is not an env)."""
    faults = []
    for table in re.findall(r"(?:^\|.*\|[ \t]*\n)+", prose(markdown), re.M):
        rows = [[c.strip() for c in r.strip().strip("|").split("|")] for r in table.strip().splitlines()]
        if len(rows) < 3:
            continue
        header = [h.lower() for h in rows[0]]
        columns = {
            i: kind
            for i, h in enumerate(header)
            for kind, words in (("observation", ("obs", "observation")), ("actions", ("act", "actions")),
                                ("dt", ("control dt", "dt")), ("episode", ("episode",)))
            if h in words or h.startswith(words[0] + " ")
        }  # fmt: skip
        if not columns:
            continue
        for row in rows[2:]:
            name = re.sub(r"[`*\[\]]|\(.*?\)", "", row[0]).strip()
            known = facts(name)
            if known is None:
                continue
            for i, kind in columns.items():
                if i >= len(row) or not re.search(r"\d", row[i]):
                    continue
                stated = float(re.search(r"\d[\d,]*(?:\.\d+)?", row[i]).group(0).replace(",", ""))
                if abs(stated - known[kind]) > 1e-9:
                    faults.append(f"{page}: {name}'s {kind} is {row[i]!r} here, {known[kind]:g} in the code")
    return faults


def preset_comments(yaml_text: str) -> str:
    """A preset file's comments as Markdown paragraphs (each run of whole-line comments is one, and
    each comment at the end of a setting): what an env's reference page shows beside the settings,
    for `number_faults` (a comment cites its evidence as docs/experiments/<page>.md)."""
    paras, run = [], []
    for line in yaml_text.splitlines():
        code, _, comment = line.partition("#")
        if not comment:
            paras.append(" ".join(run))
            run = []
        elif code.strip():
            paras += [" ".join(run), comment.strip()]
            run = []
        else:
            run.append(comment.strip())
    paras.append(" ".join(run))
    return "\n\n".join(p for p in paras if p)


def repeats(markdown: str) -> list[str]:
    """Sentences (of some length) and images a page shows twice: the traces of pages grown by
    appending (issue 52: the first-run page showed one image twice and repeated its sentences)."""
    text = prose(markdown)
    sentences = [s.strip() for s in re.split(r"(?<=[.!?])\s+", text) if len(s.strip()) > 60]
    images = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", text)
    twice = [s for s in dict.fromkeys(sentences) if sentences.count(s) > 1]
    return [f"sentence twice: {s[:80]!r}" for s in twice] + [
        f"image twice: {i}" for i in dict.fromkeys(images) if images.count(i) > 1
    ]
