"""The generated reference pages of the docs site: the CLI from its argparse parser, every config
key from the config dataclasses, one page per registered env from the registry, its presets and
its built env. `scripts/docs/gen_pages.py` writes them into the site at build time (mkdocs-gen-files);
tests/test_docs.py checks them. Nothing here is typed by hand from the code it describes.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import html
import inspect
import io
import sys
import textwrap
import tokenize
import typing
from typing import Any


# --- the CLI ------------------------------------------------------------------------------------
def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _help(parser: argparse.ArgumentParser, name: str) -> str:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return next((c.help or "" for c in action._choices_actions if c.dest == name), "")


def _cell(text: Any) -> str:
    """`text` as one Markdown table cell: on one line; outside its `code spans`, `|` escaped (a
    column separator otherwise) and `<`, `>`, `&` as entities (else `<env>` is an unknown HTML tag the
    browser drops); inside code spans, as written (Python-Markdown's tables leave a span's `|` alone,
    and an escape there would show)."""
    parts = str(text).replace("\n", " ").split("`")
    for i in range(0, len(parts), 2):  # the even parts are outside code spans
        parts[i] = html.escape(parts[i], quote=False).replace("|", "\\|")
    return "`".join(parts) if len(parts) % 2 else html.escape(str(text), quote=False).replace("|", "\\|")


def _code(text: Any) -> str:
    """`text` as one inline code span (for a table cell: one line; a backtick inside fenced by two)."""
    text = str(text).replace("\n", " ")
    return f"`` {text} ``" if "`" in text else f"`{text}`"


def flag_rows(p: argparse.ArgumentParser) -> list[tuple[str, str, str, str]]:
    """(flags, value, default, help) of every argument of `p` but --help, in the parser's order."""
    rows = []
    for a in p._actions:
        if isinstance(a, argparse._HelpAction):
            continue
        flags = ", ".join(f"`{s}`" for s in a.option_strings) or f"`{a.metavar or a.dest}` (positional)"
        if a.nargs == 0:
            value = "—"
        elif a.choices:
            value = " \\| ".join(f"`{c}`" for c in a.choices)
        else:
            kind = getattr(a.type, "__name__", None) if a.type else "text"
            value = f"`{a.metavar}`" if a.metavar and a.option_strings else (kind or "text")
            if a.nargs in ("+", "*"):
                value += " ..."
        repeat = " (repeatable)" if isinstance(a, argparse._AppendAction) else ""
        default = "" if a.default in (None, False, [], argparse.SUPPRESS) else _code(a.default)
        rows.append((flags, value + repeat, default, _cell(a.help or "")))
    return rows


def cli_markdown(parser: argparse.ArgumentParser) -> str:
    """The CLI reference: every command, its usage and every flag with its help."""
    out = [
        "# Command line",
        "",
        "Generated from `vnl.cli.build_parser()` when the site is built: every command and every flag,",
        "with the help text `vnl COMMAND --help` prints.",
        "",
    ]
    for name, p in _subparsers(parser).items():
        out += _section("##", f"vnl {name}", _help(parser, name), p)
        if any(isinstance(a, argparse._SubParsersAction) for a in p._actions):  # `vnl mocap fit|render`
            for sub, q in _subparsers(p).items():
                out += _section("###", f"vnl {name} {sub}", _help(p, sub), q)
    return "\n".join(out)


def _section(level: str, title: str, help: str, p: argparse.ArgumentParser) -> list[str]:
    """One command's heading, help, usage and table of flags (those of its subcommands follow)."""
    out = [f"{level} {title}", "", _cell(help), "", "```", p.format_usage().strip(), "```", ""]
    rows = [row for row in flag_rows(p) if "{" not in row[0]]  # the subcommands' choice is their sections
    if rows:
        out += ["| flag | value | default | what it does |", "|---|---|---|---|"]
        out += [f"| {' | '.join(row)} |" for row in rows]
    return [*out, ""]


# --- config dataclasses -------------------------------------------------------------------------
@dataclasses.dataclass
class FieldDoc:
    name: str
    type: str
    default: str
    doc: str


def _comments(source: str) -> dict[int, str]:
    """Line number (1-based) -> the comment on that line."""
    found = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            found[tok.start[0]] = tok.string.lstrip("#").strip()
    return found


def field_docs(cls: type) -> list[FieldDoc]:
    """Each init field of dataclass `cls`: its annotation and default as written in the source, and
    its comments (the lines of comment right above it, and the one at its end)."""
    source = textwrap.dedent(inspect.getsource(cls))
    lines = source.splitlines()
    comments = _comments(source)
    body = ast.parse(source).body[0]
    assert isinstance(body, ast.ClassDef)
    init = {f.name for f in dataclasses.fields(cls) if f.init}
    docs = []
    for node in body.body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.target.id in init):
            continue
        above, n = [], node.lineno - 1
        while n >= 1 and lines[n - 1].strip().startswith("#"):
            above.insert(0, comments.get(n, ""))
            n -= 1
        trailing = comments.get(node.end_lineno or node.lineno, "")
        default = ast.get_source_segment(source, node.value) if node.value is not None else "(required)"
        doc = " ".join(x for x in [*above, trailing] if x)
        docs.append(FieldDoc(node.target.id, ast.get_source_segment(source, node.annotation) or "", default or "", doc))
    return docs


def _nested(cls: type) -> dict[str, type]:
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls) if dataclasses.is_dataclass(hints[f.name])}


def config_section(cls: type, prefix: str) -> list[str]:
    """A table of `cls`'s keys (`prefix.key`) with type, default and comment, after its docstring."""
    out = [inspect.cleandoc(cls.__doc__ or ""), ""] if cls.__doc__ else []
    out += ["| key | type | default | notes |", "|---|---|---|---|"]
    for f in field_docs(cls):
        out.append(f"| `{prefix}{f.name}` | {_code(f.type)} | {_code(f.default)} | {_cell(f.doc)} |")
    return out + [""]


def config_markdown() -> str:
    """Every key of a training config (`TrainConfig` and its sections)."""
    from vnl.train.config import StageConfig, TrainConfig

    out = [
        "# Config keys",
        "",
        "Generated from the config dataclasses (`vnl/train/config.py` and the sections it holds) when",
        "the site is built. A run's `config.yaml` holds every key; `--set KEY=VALUE`, a `--config` YAML",
        "file and the presets set them (precedence: preset < file < `--set` < flags).",
        "`vnl train ENV --print-config` prints the resolved config of a command line.",
        "",
        "## Top level",
        "",
        *config_section(TrainConfig, ""),
    ]
    for name, cls in _nested(TrainConfig).items():
        out += [f"## {name}", "", *config_section(cls, f"{name}.")]
    out += ["## curriculum", "", "A list of stages, each:", "", *config_section(StageConfig, "curriculum[i].")]
    out += [
        "## env_config",
        "",
        "The env's own config: its keys differ per env, and each env's page lists them.",
        "",
    ]
    return "\n".join(out)


def all_field_docs(cls: type) -> list[FieldDoc]:
    """`field_docs` over `cls` and the dataclasses it derives from (a base's field first, a
    subclass's redefinition replacing it)."""
    docs: dict[str, FieldDoc] = {}
    for base in reversed(cls.__mro__):
        if dataclasses.is_dataclass(base) and base.__module__.startswith("vnl"):
            docs.update({d.name: d for d in field_docs(base)})
    order = [f.name for f in dataclasses.fields(cls) if f.init]
    return [docs[n] for n in order if n in docs]


def _value(value: Any) -> str:
    import yaml

    from vnl import typed_config

    text = yaml.safe_dump(typed_config.to_dict(value), default_flow_style=True, width=10_000)
    return text.strip().removesuffix("...").strip()


# --- envs ---------------------------------------------------------------------------------------
def env_names() -> list[str]:
    from vnl.envs import registry

    return registry.names()


_LAYOUTS: dict[str, tuple[list[tuple[str, int]], Any]] = {}


def _built(env: str, preset: str) -> Any:
    """The env `vnl train ENV --preset P` trains (the first stage's with a curriculum), built once
    per distinct env config (physics settings aside: they change no observation)."""
    from vnl.train import config as train_config
    from vnl.train.worlds import Worlds

    config = Worlds(train_config.build(env, preset)).config_of(0)
    key = repr((env, sorted((k, repr(v)) for k, v in config.env_config.items() if k not in ("impl", "threads"))))
    if key not in _LAYOUTS:
        # the state alone: a camera the presets turn on is stated beside it (env_markdown)
        values = {"env_config": {"impl": "c", "threads": 1}, "vision": {"enabled": False}}
        built = train_config.build(env, preset, file_values=values)
        e = Worlds(built).env(0)
        _LAYOUTS[key] = (e.observation_layout(), e)
    return _LAYOUTS[key]


def _camera_on(env: str) -> bool:
    """Whether `env`'s presets turn the camera on (`rodent_run_gaps_vision`: under every preset)."""
    from vnl.train import config as train_config

    return train_config.build(env, "cpu").vision.enabled


def _layout_table(layout: list[tuple[str, int]]) -> list[str]:
    rows, start = [], 0
    for name, width in layout:
        rows.append(f"| `{name}` | {width} | {start}–{start + width - 1} |")
        start += width
    return ["| entry | width | indices |", "|---|---:|---|", *rows, f"| **total** | **{start}** | |"]


def env_markdown(name: str) -> str:
    """One registered env: what it is, its config keys and defaults, its observation (one, under every preset),
    reward terms, task measures, cameras and presets (generated from the registry and the built env)."""
    import jax
    import jax.numpy as jp

    from vnl.envs import registry
    from vnl.io import video
    from vnl.train import presets

    entry = registry.entry(name)
    task = sys.modules[entry.factory.__module__]
    out = [f"# {name}", "", _cell(entry.description), ""]
    out += [f"![{name} right after reset, from its default video camera]({name}.png)", ""]
    if name in registry.ALIASES:
        alias = registry.ALIASES[name]
        out += [f"Its defaults are those of [{alias}]({alias}.md), for any walker.", ""]
    layouts = {preset: _built(name, preset) for preset in presets.names()}
    distinct = {repr(layout) for layout, _ in layouts.values()}
    if len(distinct) != 1:  # an env name is one task: tests/test_presets.py keeps it so
        raise ValueError(f"{name}: the presets train different observations: {sorted(distinct)}")
    layout, env = layouts["cpu"]
    size = sum(w for _, w in layout)
    out += [
        "## Observation",
        "",
        f"**Observation size {size}**, the same under every preset (`{'`, `'.join(presets.names())}`) and in "
        f"`vnl.make({name!r})`: presets choose compute, never the task.",
        "",
        *_layout_table(layout),
        "",
    ]
    camera = registry.vision_defaults(name)
    settings = ", ".join(f"`{k}: {v}`" for k, v in camera.items()) or "the defaults (the egocentric camera, 64x64 RGB)"
    if registry.is_suite(name):
        out += ["With `--vision`: not yet for a suite (its observation is its members' flat union).", ""]
    elif _camera_on(name):
        out += [
            f"With `--vision`, on in every preset of this env, the policy also sees a camera: {settings} "
            "(`--set vision.enabled=false`: the same task blind).",
            "",
        ]
    else:
        out += [
            f"With `--vision` (or `vnl.make({name!r}, vision=True)`) the policy also sees a camera: {settings}.",
            "",
        ]
    tasks = list(getattr(env, "views", {"": env}).values())  # a suite: each member's
    metrics = {k for t in tasks for k in jax.eval_shape(t.reset, jax.ShapeDtypeStruct((2,), jp.uint32)).metrics}
    rewards = sorted(k.removeprefix("reward/") for k in metrics if k.startswith("reward/"))
    measures = sorted(k.removeprefix("measure/") for k in metrics if k.startswith("measure/"))
    cameras = sorted({c for t in tasks for c in video.camera_names(t.mj_model)})
    out += [
        "## Actions, time, cameras",
        "",
        f"- actions: {env.action_size}, in [-1, 1] (scaled to the actuators' control ranges)",
        f"- control step: {env.dt:.3f} s; episode: {env.config.episode_length} control steps "
        f"({env.config.episode_length * env.dt:g} s) by default",
        f"- reward terms (`metrics['reward/<term>']`, summing to the reward): {', '.join(f'`{r}`' for r in rewards)}",
        f"- task measures (`metrics['measure/<name>']`, summed over an episode; `eval/episode_measure/<name>` "
        f"in metrics.jsonl): {', '.join(f'`{m}`' for m in measures) or 'none'}",
        f"- cameras (`vnl render --camera`): {', '.join(f'`{c}`' for c in cameras)}",
        f"- level fields (what [terrain levels](../../how-to/curricula.md#terrain-levels) may vary per episode, "
        f"`levels.easiest`): {', '.join(f'`{f}`' for f in getattr(env, 'level_fields', ())) or 'none'}",
        *_suite_lines(env),
        "",
        "## The task",
        "",
        f"`{entry.factory.__module__}.{entry.factory.__name__}`:",
        "",
        inspect.cleandoc(task.__doc__ or ""),
        "",
        "## env_config keys and defaults",
        "",
        f"`vnl train {name} --set env_config.KEY=VALUE`, `vnl.make({name!r}, KEY=VALUE)`.",
        "",
        "| key | type | default | notes |",
        "|---|---|---|---|",
    ]
    default = registry.default_config(name)
    if registry.is_suite(name):
        out += _suite_config_rows(default)
    for f in [] if registry.is_suite(name) else all_field_docs(type(default)):
        out.append(f"| `{f.name}` | {_code(f.type)} | {_code(_value(getattr(default, f.name)))} | {_cell(f.doc)} |")
    out += ["", "## Presets", ""]
    path = presets.path(name)
    if path is None:
        out += ["This env has no presets of its own: the generic ones apply (`vnl/train/presets/base.yaml`).", ""]
    else:
        text = path.read_text()
        starts = [line.split(":", 1)[1].strip() for line in text.splitlines() if line.startswith("extends:")]
        extends = starts[0] if starts else None
        out += [f"`vnl/train/presets/{path.name}`, over the generic presets (`base.yaml`)"]
        out[-1] += f" and `{extends}.yaml`:" if extends else ":"
        out += ["", "```yaml", text.rstrip(), "```", ""]
        if extends:
            shared = (path.parent / f"{extends}.yaml").read_text().rstrip()
            out += [f"`{extends}.yaml`:", "", "```yaml", shared, "```", ""]
    out += [f"`vnl train {name} --preset cpu --print-config` prints a preset's whole resolved config.", ""]
    return "\n".join(out)


def _suite_lines(env: Any) -> list[str]:
    """A suite's members, their shares of the batch and episodes (nothing for another env)."""
    views = getattr(env, "views", None)
    if views is None:
        return []
    shares = dict(zip(env.tasks, env.shares, strict=True))
    rows = [
        f"    - [{name}]({name}.md): {shares.get(name, 0)} of {sum(env.shares)} of the batch, episodes of "
        f"{view.config.episode_length} steps"
        for name, view in views.items()
    ]
    return [
        "- a suite (`vnl.envs.suite`): one policy on its members' tasks, each on its share of the batch "
        "and evaluated on its own (`eval/<task>/...`; `eval/episode_reward` is their mean). `vnl eval` evaluates "
        "each; `--set env_config.task=NAME` picks one for eval, record and render. Members:",
        *rows,
    ]


def _suite_config_rows(default: Any) -> list[str]:
    """The env_config table's rows of a suite: each member's config, then the suite's own keys."""
    rows = [
        f"| `{name}` | its config | [{name}]({name}.md)'s defaults | the member's keys: `env_config.{name}.KEY` |"
        for name in default.members()
    ]
    own = {
        "tasks": "the members trained on (all are evaluated)",
        "shares": "their relative numbers of envs in the batch (null: equal)",
        "task": "one member alone, observing the suite's layout (eval, record, render; not training)",
        "impl": "the physics of every member",
        "threads": "MuJoCo C's threads, every member's",
    }
    for key, doc in own.items():
        if hasattr(default, key):
            rows.append(f"| `{key}` | | {_code(_value(getattr(default, key)))} | {doc} |")
    return rows


def envs_table(names: list[str], link: str = "{name}.md") -> list[str]:
    """The table `vnl list` prints, from the registry and each env as `vnl.make` builds it: name
    (linked to its page, `link` formatted with the name), observation size, actions, control step,
    episode length, description."""
    from vnl.envs import registry

    out = [
        "| env | observation | actions | control step | episode | what it is |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for name in names:
        layout, env = _built(name, "cpu")
        size = sum(w for _, w in layout)
        steps = env.config.episode_length
        out.append(
            f"| [{name}]({link.format(name=name)}) | {size} | {env.action_size} | {env.dt:.3g} s | "
            f"{steps} steps ({steps * env.dt:g} s) | {_cell(registry.entry(name).description)} |"
        )
    return out


def envs_index(names: list[str]) -> str:
    """The table of registered envs: description, observation size, actions, time."""
    out = [
        "# Environments",
        "",
        "Every registered env (`vnl list`), generated from the registry when the site is built. Each page",
        "shows the env at reset and gives its observation (the same under every preset), the reward terms, task",
        "measures, cameras, config keys and presets.",
        "",
        *envs_table(names),
    ]
    return "\n".join(out + [""])


def env_picture(name: str, width: int = 480, height: int = 360) -> bytes:
    """A PNG of env `name` as `vnl.make(name)` builds it (MuJoCo C physics), right after
    `reset(PRNGKey(0))`, from the camera its videos use by default (`vnl.io.video.resolve_camera`).
    Needs OpenGL (EGL or OSMesa), as `vnl render` does."""
    import io as _io

    import jax
    import numpy as np
    from PIL import Image

    import vnl
    from vnl.io import video

    env = vnl.make(name, impl="c", threads=1)
    frames = []
    for task in getattr(env, "views", {"": env}).values():  # a suite: its members side by side
        state = jax.jit(task.reset)(jax.random.PRNGKey(0))
        qpos, mocap = np.asarray(state.data.qpos)[None], np.asarray(state.data.mocap_pos)[None]
        w = width // len(getattr(env, "views", [env]))
        frames.append(video.render_frames(task.mj_model, qpos, None, w, height, mocap_pos=mocap)[0])
    frame = np.concatenate(frames, axis=1)
    buf = _io.BytesIO()
    Image.fromarray(frame).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


GENERIC_ENV = "brax_ant_run"  # an env without a preset file of its own: it trains the generic presets


def presets_table(env: str = GENERIC_ENV) -> list[str]:
    """The generic presets side by side (the PPO and network keys where `cpu`, `gpu` and `tiny`
    differ), resolved for an env without a preset file of its own; an env's file changes some of
    them (its reference page shows the file)."""
    from vnl import typed_config
    from vnl.train import config as train_config
    from vnl.train import presets

    def flat(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in d.items():
            out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) and v else {f"{prefix}{k}": v})
        return out

    names = presets.names()
    resolved = {p: flat(typed_config.to_dict(train_config.build(env, p))) for p in names}
    keys = [k for k in resolved[names[0]] if k.startswith(("ppo.", "network."))]
    differ = [k for k in keys if len({repr(resolved[p].get(k)) for p in names}) > 1]
    out = ["| key | " + " | ".join(f"`{p}`" for p in names) + " |", "|---|" + "---:|" * len(names)]
    for k in differ:
        out.append(f"| `{k}` | " + " | ".join(_code(_value(resolved[p].get(k))) for p in names) + " |")
    return out
