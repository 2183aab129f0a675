"""Domain randomization: per-environment physical parameters, as batched `mjx.Model` fields.

`RandomizeConfig` (the `randomize:` section of a training config) gives ranges of multiplicative
factors on the model's own values; `randomizer(config)` returns a function with the signature of
Brax's `randomization_fn` hook, `fn(mjx_model, rng) -> (batched_model, in_axes)`, where `rng`
has shape (num_envs, 2) and every randomized field gets a leading env axis (in_axes 0); other
fields are shared (in_axes None). `RandomizedVmapWrapper` steps each env with its own model, as
Brax's `DomainRandomizationVmapWrapper` and MuJoCo Playground's wrapper do.

What is drawn, per environment:

- `friction`: one factor for the whole world: every geom's sliding friction × f (MuJoCo uses the
  larger friction of the two geoms in contact, so this scales every contact's friction).
- `actuator_gain`: one factor per actuator: gain × f; for position-like actuators (bias
  `-kp·q`, i.e. `biasprm[1] == -gainprm[0]`) the bias term is scaled with it, so the actuator
  still holds its target (as the seed notebooks and Playground do).
- `body_mass`: one factor per body: mass and rotational inertia × f (the same body scaled in
  density: shape and centre of mass unchanged).
- `joint_damping`: one factor per degree of freedom: damping × f.

Ranges are `[lo, hi]` with 0 < lo <= hi; a missing (null) range leaves that field as in the model.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jp
import numpy as np
from brax.envs.wrappers import training as brax_training

from vnl.errors import VnlError
from vnl.quiet_mjx import mjx

Range = tuple[float, float] | None
RandomizationFn = Callable[[mjx.Model, jax.Array], tuple[mjx.Model, mjx.Model]]

FIELDS = {  # config key -> the mjx.Model fields it batches
    "friction": ("geom_friction",),
    "actuator_gain": ("actuator_gainprm", "actuator_biasprm"),
    "body_mass": ("body_mass", "body_inertia"),
    "joint_damping": ("dof_damping",),
}


@dataclasses.dataclass(frozen=True)
class RandomizeConfig:
    """Ranges [lo, hi] of multiplicative factors drawn per environment (null: not randomized)."""

    friction: Range = None
    actuator_gain: Range = None
    body_mass: Range = None
    joint_damping: Range = None

    def validate(self) -> None:
        for key in FIELDS:
            r = getattr(self, key)
            if r is None:
                continue
            if len(r) != 2:
                raise VnlError(f"{key} must be a range [lo, hi], got {list(r)}")
            lo, hi = r
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
                raise VnlError(
                    f"{key} must be [lo, hi] with 0 < lo <= hi (factors on the model's value), got {list(r)}"
                )

    @property
    def enabled(self) -> bool:
        return any(getattr(self, key) is not None for key in FIELDS)


def _uniform(key: jax.Array, shape: tuple[int, ...], r: tuple[float, float]) -> jax.Array:
    return jax.random.uniform(key, shape, minval=r[0], maxval=r[1], dtype=jp.float32)


def randomizer(config: RandomizeConfig) -> RandomizationFn:
    """Brax's `randomization_fn(model, rng)` for `config`; `rng` shape (num_envs, 2)."""

    def fn(model: mjx.Model, rng: jax.Array) -> tuple[mjx.Model, mjx.Model]:
        def one(key: jax.Array) -> dict[str, jax.Array]:
            k_fric, k_gain, k_mass, k_damp = jax.random.split(key, 4)
            out: dict[str, jax.Array] = {}
            if config.friction is not None:
                f = _uniform(k_fric, (), config.friction)
                out["geom_friction"] = model.geom_friction.at[:, 0].multiply(f)
            if config.actuator_gain is not None:
                f = _uniform(k_gain, (model.nu,), config.actuator_gain)
                gain, bias = model.actuator_gainprm, model.actuator_biasprm
                position_like = jp.isclose(bias[:, 1], -gain[:, 0]) & (gain[:, 0] != 0)
                out["actuator_gainprm"] = gain.at[:, 0].multiply(f)
                out["actuator_biasprm"] = bias.at[:, 1].set(jp.where(position_like, bias[:, 1] * f, bias[:, 1]))
            if config.body_mass is not None:
                f = _uniform(k_mass, (model.nbody,), config.body_mass)
                out["body_mass"] = model.body_mass * f
                out["body_inertia"] = model.body_inertia * f[:, None]
            if config.joint_damping is not None:
                f = _uniform(k_damp, (model.nv,), config.joint_damping)
                out["dof_damping"] = model.dof_damping * f
            return out

        fields = jax.vmap(one)(rng)
        in_axes = jax.tree.map(lambda _: None, model)
        in_axes = in_axes.tree_replace({name: 0 for name in fields})
        return model.tree_replace(fields), in_axes

    return fn


def summary(model: mjx.Model, batched: mjx.Model, config: RandomizeConfig) -> dict[str, dict[str, float]]:
    """Mean/min/max over envs (and elements) of each randomized factor, e.g.
    `{"friction": {"mean": 1.02, "min": 0.81, "max": 1.19}}` (factor = new value / model value)."""
    out: dict[str, dict[str, float]] = {}
    pairs = {
        "friction": (batched.geom_friction[..., 0], model.geom_friction[:, 0]),
        "actuator_gain": (batched.actuator_gainprm[..., 0], model.actuator_gainprm[:, 0]),
        "body_mass": (batched.body_mass, model.body_mass),
        "joint_damping": (batched.dof_damping, model.dof_damping),
    }
    for key, (new, old) in pairs.items():
        if getattr(config, key) is None:
            continue
        new, old = np.asarray(new, np.float64), np.asarray(old, np.float64)
        ratio = new[:, old != 0] / old[old != 0]
        if ratio.size == 0:
            continue
        out[key] = {"mean": float(ratio.mean()), "min": float(ratio.min()), "max": float(ratio.max())}
    return out


class RandomizedVmapWrapper(brax_training.Wrapper):
    """Vmaps `reset`/`step` over envs, each with its own model from `randomization_fn`.

    Replaces Brax's `VmapWrapper`. With `axis_name` (inside `jax.pmap`), the batched model holds
    the envs of every device, shape (devices × envs per device, ...), and each device takes its
    own slice, so no two envs share parameters (Brax's wrapper gives every device the same ones).

    Args:
      env: the env to batch.
      randomization_fn: `fn(mjx_model) -> (batched_model, in_axes)`, e.g. Brax's hook with its
        `rng` bound: `functools.partial(randomizer(config), rng=keys)`.
      axis_name: the pmap axis, when the batched model holds the envs of every device.
    """

    def __init__(
        self,
        env: Any,
        randomization_fn: Callable[[mjx.Model], tuple[mjx.Model, mjx.Model]],
        axis_name: str | None = None,
    ) -> None:
        if env is not env.unwrapped:
            raise VnlError("RandomizedVmapWrapper wraps a vnl Env itself (it steps copies with other models)")
        super().__init__(env)
        self.model, self.in_axes = randomization_fn(env.mjx_model)
        sizes: set[int] = set()
        jax.tree.map(
            lambda a, x: sizes.add(int(x.shape[0])) if a is not None else None,
            self.in_axes,
            self.model,
            is_leaf=lambda x: x is None,
        )
        if len(sizes) > 1:
            raise VnlError(f"randomized model fields have different batch sizes {sorted(sizes)}")
        self.num_models = sizes.pop() if sizes else 0
        self.axis_name = axis_name
        # Physics outside JAX (impl c) receives the env's values of these fields with every call.
        batched = [n for names in FIELDS.values() for n in names if getattr(self.in_axes, n) is not None]
        env.set_per_env_fields(tuple(batched))

    def _local_model(self, batch: int) -> mjx.Model:
        if self.axis_name is None:
            if batch != self.num_models:
                raise VnlError(f"{batch} envs but {self.num_models} randomized models; they must match")
            return self.model
        start = jax.lax.axis_index(self.axis_name) * batch

        def take(axis: int | None, x: jax.Array) -> jax.Array:
            return x if axis is None else jax.lax.dynamic_slice_in_dim(x, start, batch, axis=0)

        return jax.tree.map(take, self.in_axes, self.model, is_leaf=lambda x: x is None)

    def reset(self, rng: jax.Array) -> Any:
        model = self._local_model(rng.shape[0])
        return jax.vmap(lambda m, k: self.env.with_model(m).reset(k), in_axes=(self.in_axes, 0))(model, rng)

    def step(self, state: Any, action: jax.Array) -> Any:
        model = self._local_model(action.shape[0])
        return jax.vmap(lambda m, s, a: self.env.with_model(m).step(s, a), in_axes=(self.in_axes, 0, 0))(
            model, state, action
        )
