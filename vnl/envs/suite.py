"""Suites: several tasks as one env, for one network trained on all of them (Merel et al. 2020's
one brain on four tasks; docs/how-to/multitask.md).

A suite has K member envs, each built with its own world (`mj_model`) and its own task code,
unchanged. What makes them one env for one network:

- one observation layout, the union of the members' (`union_layout`): blocks with the same name
  and width are shared, a name seen with two widths is namespaced `<task>/<block>`, and a one-hot
  block `task` (K wide) is appended. A member's observation is embedded in it (`TaskView`): the
  blocks it lacks are 0, and the one-hot says which task it is;
- one action space and one control step: every member must have the same actuators and `dt`;
- a batch split for training (`SuiteWrapper`): member k steps a fixed, contiguous share of every
  device's envs, each slice wrapped for training (episode limit, auto-reset) as a lone env is.
  Drawing the task per episode inside one slot would need the same physics state in every slot,
  and the members' worlds differ (bodies, mocap targets), so the task is drawn per env slot.

`define(members)` returns the suite's factory and default config; `config.task` set to a member's
name builds that member's `TaskView` alone (what evaluation, recording and rendering of one task
use), else the factory builds a `SuiteEnv`.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

import jax
import jax.numpy as jp
import numpy as np

from vnl.envs.adapter import EnvAdapter
from vnl.errors import VnlError
from vnl.tasks.contract import Env, State

TASK_BLOCK = "task"
"""The name of the one-hot block (K wide) that says which member an observation comes from."""

Layout = list[tuple[str, int]]


def union_layout(layouts: Mapping[str, Layout]) -> tuple[Layout, dict[str, list[str]]]:
    """The suite's layout from each member's `[(block, width), ...]`, in member order; returns
    (union layout, {member: the union name of each of its blocks, in its order}).

    A block whose name and width are already in the union is shared; a name already there with
    another width (or named `task`) becomes `<member>/<block>`. A new block goes before the first
    of its member's later blocks already in the union, else at the end, so a member whose shared
    blocks keep one order is an ordered subsequence of the union. The one-hot `task` block is last.
    """
    union: Layout = []
    names: dict[str, list[str]] = {}
    for member, layout in layouts.items():
        widths = dict(union)
        keys = []
        for block, width in layout:
            shared = block != TASK_BLOCK and widths.get(block, width) == width
            keys.append(block if shared else f"{member}/{block}")
        for i, ((_, width), key) in enumerate(zip(layout, keys, strict=True)):
            if key in widths:
                continue
            later = [k for k in keys[i + 1 :] if k in widths]
            at = [name for name, _ in union].index(later[0]) if later else len(union)
            union.insert(at, (key, int(width)))
            widths[key] = int(width)
        names[member] = keys
    return [*union, (TASK_BLOCK, len(layouts))], names


def gather_index(union: Layout, keys: Sequence[str], layout: Layout, index: int) -> np.ndarray:
    """For each entry of the union observation (W,), where to read it from a member's observation
    (O,) extended with [0, 1]: an entry of that observation, O (a 0: a block it lacks) or O + 1
    (a 1: its own entry of the one-hot). `keys` are its blocks' union names, `index` its position."""
    starts, at = {}, 0
    for key, (_, width) in zip(keys, layout, strict=True):
        starts[key] = at
        at += width
    zero, one = at, at + 1
    source: list[int] = []
    for name, width in union:
        if name == TASK_BLOCK:
            source += [one if k == index else zero for k in range(width)]
        elif name in starts:
            source += range(starts[name], starts[name] + width)
        else:
            source += [zero] * width
    return np.asarray(source, dtype=np.int32)


class TaskView(EnvAdapter):
    """Member `name` (the `index`-th) of a suite, observing the suite's layout: its observation
    (O,) embedded in the union (W,) as `gather_index` says. Everything else (physics, rewards,
    metrics, cameras, the task's attributes) is the member's: `unwrapped` is the member itself."""

    def __init__(self, env: Env, name: str, index: int, union: Layout, keys: Sequence[str]) -> None:
        super().__init__(env)
        self.task_name = name
        self.task_index = int(index)
        self._union = list(union)
        self._source = jp.asarray(gather_index(union, keys, env.observation_layout(), index))

    def embed(self, obs: jax.Array) -> jax.Array:
        """The member's observations (..., O) in the suite's layout (..., W)."""
        ends = jp.broadcast_to(jp.asarray([0.0, 1.0], obs.dtype), (*obs.shape[:-1], 2))
        return jp.take(jp.concatenate([obs, ends], axis=-1), self._source, axis=-1)

    def reset(self, rng: jax.Array) -> State:
        state = self.inner.reset(rng)
        return state.replace(obs=self.embed(state.obs))

    def step(self, state: State, action: jax.Array) -> State:
        new = self.inner.step(state, action)  # every task's step sets its own obs (none reads state.obs)
        return new.replace(obs=self.embed(new.obs))

    def observation_layout(self) -> Layout:
        return list(self._union)

    @property
    def observation_shape(self) -> Any:
        return (sum(w for _, w in self._union),)

    def with_model(self, mjx_model: Any) -> Env:
        view = TaskView.__new__(TaskView)
        view.__dict__.update(self.__dict__, inner=self.inner.with_model(mjx_model), _mjx_model=mjx_model)
        return view


RODENT_SUITE = ("rodent_run_gaps", "rodent_maze_forage", "rodent_escape_bowl", "rodent_two_touch")
"""Merel et al. 2020's four tasks, as vnl's env names."""


class SuiteConfig:
    """What every suite config has besides one field per member (that member's config):

    - `tasks`: the members trained on (default all of them); `shares`: their relative numbers of
      envs in the batch (None: equal); `reward_scales`: what each task's reward is multiplied by
      in training (None: 1 each; evaluations report the task's own reward);
    - `task`: a member's name to build that member alone, observing the suite's layout (evaluating,
      recording, rendering one task); None: the suite;
    - `impl`, `threads`: the physics of every member (copied into their configs).
    """

    _members: ClassVar[dict[str, Callable[[Any], Env]]] = {}

    def __post_init__(self) -> None:
        for name in self._members:
            member = getattr(self, name)
            compute = {k: getattr(self, k) for k in ("impl", "threads") if hasattr(self, k) and hasattr(member, k)}
            object.__setattr__(self, name, dataclasses.replace(member, **compute))

    def validate(self) -> None:
        names = list(self._members)
        tasks = list(self.tasks)
        odd = [t for t in [*tasks, *([self.task] if self.task is not None else [])] if t not in names]
        if odd or not tasks or len(set(tasks)) != len(tasks):
            bad = f"{odd[0]!r} is not a member" if odd else "give each member at most once, at least one"
            raise VnlError(f"tasks/task: {bad}; this suite's members are: {', '.join(names)}")
        if self.shares is not None and (len(self.shares) != len(tasks) or min(self.shares) < 1):
            raise VnlError(f"shares: one positive integer per entry of tasks ({len(tasks)}), got {list(self.shares)}")
        scales = self.reward_scales
        if scales is not None and (
            len(scales) != len(tasks) or not all(math.isfinite(x) and x >= 0 for x in scales) or max(scales) <= 0
        ):
            raise VnlError(
                f"reward_scales: one finite number >= 0 per entry of tasks ({len(tasks)}), not all 0; "
                f"got {list(scales)}"
            )

    @property
    def episode_length(self) -> int:
        """`task`'s episode (control steps) when one is picked, else the longest member's (each
        member still ends its own)."""
        if self.task is not None:
            return getattr(self, self.task).episode_length
        return max(getattr(self, name).episode_length for name in self._members)

    def members(self) -> dict[str, Any]:
        """{member name: its config}, in member order."""
        return {name: getattr(self, name) for name in self._members}


def define(
    members: Mapping[str, tuple[Callable[[Any], Env], Any]], shares: tuple[int, ...] | None = None
) -> tuple[Callable[[Any], Any], Any]:
    """A suite of `members` ({env name: (factory, default config)}, in order), split `shares`
    between them by default (None: equally); returns its factory (`factory(config) -> SuiteEnv`,
    or the `TaskView` of `config.task`) and its default config."""
    if len(members) < 2:
        raise VnlError(f"a suite needs at least two members, got {list(members)}")
    first = next(iter(members.values()))[1]
    fields: list[Any] = [
        (name, type(config), dataclasses.field(default=config)) for name, (_, config) in members.items()
    ]
    fields += [
        ("tasks", tuple[str, ...], dataclasses.field(default=tuple(members))),
        ("shares", tuple[int, ...] | None, dataclasses.field(default=shares)),
        ("reward_scales", tuple[float, ...] | None, dataclasses.field(default=None)),
        ("task", str | None, dataclasses.field(default=None)),
    ]
    hints = typing.get_type_hints(type(first))  # the members' modules may defer annotations
    fields += [(k, hints[k], dataclasses.field(default=getattr(first, k))) for k in ("impl", "threads") if k in hints]
    cls = dataclasses.make_dataclass(
        "SuiteConfig_" + "_".join(members),
        fields,
        bases=(SuiteConfig,),
        namespace={"_members": {name: factory for name, (factory, _) in members.items()}},
        frozen=True,
    )
    return build, cls()


def build(config: Any) -> SuiteEnv | TaskView:
    """The suite of `config` (a `define`d config): every member built, checked to share actuators
    and control step; the `TaskView` of `config.task` when it is set."""
    members = {name: factory(getattr(config, name)) for name, factory in config._members.items()}
    suite = SuiteEnv(config, members)
    return suite.views[config.task] if config.task is not None else suite


def _actuators(env: Env) -> list[str]:
    return [env.mj_model.actuator(i).name for i in range(env.mj_model.nu)]


class SuiteEnv:
    """Members' envs under one observation layout (`union_layout`), one action space and one `dt`.

    Not an `Env`: it has K worlds, not one model. `views[name]` is each member's `TaskView`;
    training steps them together through `SuiteWrapper`.
    """

    def __init__(self, config: Any, members: dict[str, Env]) -> None:
        first_name, first = next(iter(members.items()))
        for name, env in members.items():
            # observation_size reads a walker task's layout; observation_shape would trace its reset (~10 s for
            # a rat on MJX, 4 times for rodent_suite: docs/how-to/multitask.md)
            if not isinstance(env.observation_size, int):
                raise VnlError(f"suite member {name}: a suite needs flat observations (no vision), got a dict")
            if abs(env.dt - first.dt) > 1e-9 or _actuators(env) != _actuators(first):
                raise VnlError(
                    f"suite members {first_name} and {name} differ in their control step ({first.dt:g} s, "
                    f"{env.dt:g} s) or actuators ({env.action_size} vs {first.action_size}): one policy "
                    "acts in every member, so they must share both"
                )
        self.config = config
        self.members = members
        self.tasks = tuple(config.tasks)
        self.shares = tuple(config.shares) if config.shares is not None else (1,) * len(self.tasks)
        scales = getattr(config, "reward_scales", None)
        self.reward_scales = tuple(float(x) for x in scales) if scales is not None else (1.0,) * len(self.tasks)
        self._layout, keys = union_layout({name: env.observation_layout() for name, env in members.items()})
        self.views = {
            name: TaskView(env, name, i, self._layout, keys[name]) for i, (name, env) in enumerate(members.items())
        }

    def observation_layout(self) -> Layout:
        return list(self._layout)

    @property
    def observation_size(self) -> int:
        return sum(width for _, width in self._layout)

    @property
    def observation_shape(self) -> tuple[int]:
        return (self.observation_size,)

    @property
    def action_size(self) -> int:
        return next(iter(self.members.values())).action_size

    @property
    def dt(self) -> float:
        return next(iter(self.members.values())).dt

    @property
    def physics(self) -> Any:
        return next(iter(self.members.values())).physics

    @property
    def backend(self) -> str:
        return next(iter(self.members.values())).backend

    @property
    def unwrapped(self) -> SuiteEnv:
        return self

    @property
    def previous_state_reads(self) -> dict[str, tuple[str, ...] | None]:
        """Each member's, by the path of its state in the training state (`SuiteWrapper`:
        `.info['tasks'][name]`): a checkpoint keeps of each member what that member reads
        (`physics.derived_paths`); a member's None (unknown) keeps its state whole."""
        return {f".info['tasks'][{name!r}]": env.previous_state_reads for name, env in self.members.items()}

    def episode_lengths(self, episode_length: int | None = None) -> dict[str, int]:
        """{task trained on: its episode length}: `episode_length` for all when given (a training
        preset's `ppo.episode_length`), else each member's own."""
        return {name: episode_length or self.members[name].config.episode_length for name in self.tasks}

    def __getattr__(self, name: str) -> Any:
        if name in ("mj_model", "mjx_model", "n_substeps", "reset", "step"):
            raise VnlError(
                f"a suite has {len(self.members)} worlds, not one, so it has no {name}: pick one task with --set "
                f"env_config.task=NAME (one of {', '.join(self.members)})"
            )
        raise AttributeError(name)


def split_counts(n: int, shares: Sequence[int]) -> list[int]:
    """Envs of each member in a batch of `n` split by `shares` (n must be a multiple of their sum)."""
    total = sum(shares)
    if n % total:
        raise VnlError(f"a batch of {n} envs cannot be split {':'.join(map(str, shares))} between the suite's tasks")
    return [n // total * s for s in shares]


class SuiteWrapper:
    """The suite's `tasks` stepped as one batch: member k takes the k-th contiguous slice of the
    batch's rows (`split_counts` by the suite's shares), wrapped for training on its own
    (`wrap_for_training`: its episode length, auto-reset). States hold each member's batch state
    in `info["tasks"][name]`; `obs` (n, W), `reward`, `done` (n,) and the episode bookkeeping that
    PPO reads (`info["truncation"]`, `["episode_done"]`, `["episode_metrics"]`: `sum_reward`,
    `length`) are the members' concatenated in order. `data` is empty: the physics lives per member.
    """

    def __init__(self, suite: SuiteEnv, episode_length: int | None = None, action_repeat: int = 1) -> None:
        self.suite = suite
        lengths = suite.episode_lengths(episode_length)
        # Imported here: brax's wrappers import jaxopt, whose deprecation warning `import vnl` must not print.
        from vnl.envs.wrappers import wrap_for_training

        self.envs = {name: wrap_for_training(suite.views[name], lengths[name], action_repeat) for name in suite.tasks}

    def _slices(self, n: int) -> dict[str, slice]:
        counts = split_counts(n, self.suite.shares)
        ends = np.cumsum(counts)
        return {name: slice(int(e - c), int(e)) for name, c, e in zip(self.suite.tasks, counts, ends, strict=True)}

    def reset(self, rng: jax.Array) -> State:
        """States of `rng.shape[0]` envs from keys `rng` (n, 2)."""
        slices = self._slices(rng.shape[0])
        return self._combine({name: env.reset(rng[slices[name]]) for name, env in self.envs.items()})

    def step(self, state: State, action: jax.Array) -> State:
        """The next states after actions `action` (n, A)."""
        slices = self._slices(action.shape[0])
        tasks = state.info["tasks"]
        return self._combine({name: env.step(tasks[name], action[slices[name]]) for name, env in self.envs.items()})

    def _combine(self, states: dict[str, State]) -> State:
        def cat(get: Callable[[State], jax.Array]) -> jax.Array:
            return jp.concatenate([get(s) for s in states.values()])

        scales = dict(zip(self.suite.tasks, self.suite.reward_scales, strict=True))

        info = {
            "tasks": states,
            **{k: cat(lambda s, k=k: s.info[k]) for k in ("steps", "truncation", "episode_done")},
            "episode_metrics": {k: cat(lambda s, k=k: s.info["episode_metrics"][k]) for k in ("sum_reward", "length")},
        }
        return State(
            data={},
            obs=cat(lambda s: s.obs),
            # what PPO learns from: each task's reward times its scale (the episode metrics keep the task's own)
            reward=jp.concatenate([s.reward * scales[name] for name, s in states.items()]),
            done=cat(lambda s: s.done),
            metrics={},
            info=info,
        )
