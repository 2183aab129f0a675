"""`EnvAdapter`: the base of an env that wraps another and changes part of its contract (its
observation or its actions), delegating the rest: the model, physics, compact-checkpoint reads,
randomized fields and the task's own attributes (cameras, walker, ...)."""

from __future__ import annotations

from typing import Any

from vnl.tasks.contract import Env


class EnvAdapter(Env):
    """`inner`'s model, physics and task attributes; subclasses implement `reset`, `step` and
    what they change. Not `Env.__init__`: the wrapped env owns the model (no second
    `mjx.put_model`)."""

    def __init__(self, inner: Env) -> None:
        self.inner = inner
        self._config = inner.config
        self._mj_model = inner.mj_model
        self._mjx_model = inner.mjx_model
        self._n_substeps = inner.n_substeps

    @property
    def action_size(self) -> int:
        return self.inner.action_size

    @property
    def unwrapped(self) -> Env:
        return self.inner.unwrapped

    @property
    def backend(self) -> str:
        return self.inner.backend

    @property
    def physics(self) -> Any:
        return self.inner.physics

    @property
    def previous_state_reads(self) -> tuple[str, ...] | None:  # type: ignore[override]
        """The wrapped env's: an adapter reads nothing of a previous state's physics itself."""
        return self.inner.previous_state_reads

    def set_per_env_fields(self, names: tuple[str, ...]) -> None:
        self.inner.set_per_env_fields(names)

    def __getattr__(self, name: str) -> Any:  # task attributes (cameras, walker, ...) of the wrapped env
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)
