"""Touch an orb twice, 0.7-0.9 s apart: dm_control's `reach.TwoTouch` as its
`basic_rodent_2020.rodent_two_touch` sets it up.

An orb (a sphere of radius `orb_radius` 0.025 m, centre `orb_height` 0.14 m above the floor) is
placed uniformly in [-1.5, 1.5] x [-1.5, 1.5] m (`target_area`, half-widths); the rat spawns at the
origin facing a random direction. The task's state (`task_logic`, dm_control's `TwoTouchState`):

- **0 pre-touch**: a hand touching the orb is the first touch: `touch_reward` (25), state 1.
- **1 touched once**: a touch at least `touch_debounce` (0.2 s) after the first is the second
  touch; its interval (from the first touch) decides: below `touch_interval` - `interval_tolerance`
  (0.7 s) **3 too soon**; up to `touch_interval` + `interval_tolerance` (0.9 s) **2 touched
  twice**, a correct pair, `touch_reward` again. With no second touch by 0.9 s the window closes
  at the next step: **4 no second touch**.
- After 3 or 4 the trial waits out `failure_timeout` (1.2 s) from the second touch (or the
  window's close); then, as after 2, `reset_delay` (0 s). At the step after that, the orb moves to
  a new random point and the state is 0 again.

Reward terms (`metrics["reward/<term>"]`): `first_touch` and `second_touch` (`touch_reward` at a
first touch and at a correct second one), and on every step, in every state, `closeness` =
0.01 x `touch_reward` x the larger over the two hands of exp(-3 x L1 distance from the hand body's
origin to the orb's centre). No termination but the physics blowing up: 30-s episodes.
Observation: proprioception, `target` (the orb's centre in the root body's frame, with
`observe_target`) and `task_logic`, the state the step began in (after a redraw due): dm_control
takes its observations before it computes the reward, so its `task_logic` shows a touch one step
late, and vnl's does too.

Task measures (`metrics["measure/..."]`, per-step counts): `first_touches`, `correct_pairs`,
`too_soon`, `no_second_touch`. Per-step metrics: `touch_interval`, the interval (s) at each
second touch the task registers (too soon or in the window), 0 at every other step (a recording
keeps it per step: its non-zero values are the episode's inter-touch intervals), and `task_logic`,
the state after the step.

Where vnl differs from dm_control, and why (tests/test_two_touch.py drives both through the same
scripted touches):

- **Touch detection.** dm_control counts a touch when MuJoCo's contact list holds one of the
  hands' geoms (`hand_L`, `hand_R` and their fingers) against the orb, after every 1-ms physics
  step. With MuJoCo 3.17 (vnl's pin) only the hand ellipsoids ever register: MuJoCo adds the two
  geoms' margins, and its mid-phase, which tests the bounding boxes of a body with several geoms
  (the three finger capsules share one), drops every pair whose boxes do not overlap by the
  orb's -2r (with the mid-phase disabled the finger contacts appear); the hand body's single
  ellipsoid skips it and its test reports any overlap. No contact with the orb exerts a force
  (its gap of 2r). vnl's orb is a mocap body outside the physics (no contact pairs for MJX), and
  a touch is that overlap, computed in JAX from the geoms' poses: a colliding geom of the `hands`
  bodies themselves (the ellipsoids; the fingers are child bodies) within r of the orb's centre
  (`vnl.tasks.touch`). MuJoCo C physics returns no contact list, and a jitted step runs no Python
  per physics step, so it is checked once per 20-ms control step, on the state at its end: a
  touch that begins and ends within one control step is missed. (MuJoCo's convex test also
  misses a hand exactly concentric with the orb; vnl counts it.)
- **Time in control steps.** Both take a touch's time at its control step. vnl counts intervals
  in whole steps: too soon below 35, in the window 35-45, the window closes at 46, the timeout
  ends after 60, the debounce is 10 (dm_control's for touches lasting whole control steps; its
  debounce clock starts at the first contact's 1-ms step). dm_control compares float64 sums of
  1-ms steps, so at exactly 0.9 and 1.2 s its outcome depends on rounding: for about 60% of
  start times its window closes after 45 steps and its timeout ends after 60, one step early.
- **A blind rat.** dm_control's rat sees the orb with its 64x64 egocentric camera, and the orb's
  colour shows the state; vnl observes the orb's position (`target`), and `--vision`'s camera sees
  an orb of one colour. The proprioception is vnl's other rat tasks' (no accelerometer, touch or
  torque sensors).
- **Physics and spawn** as vnl's other rat tasks: 2 ms x 10 physics steps (dm_control: 1 ms x
  20), the rat spawned at the lowest height where it touches nothing, joints ±0.01 rad of noise.
  dm_control draws the spawn rotation from NumPy's global generator, outside its seed; vnl from
  the reset key. Orbs after an episode's first are drawn from its key and the step index.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jp
import numpy as np

from vnl.arenas import floor
from vnl.errors import VnlError
from vnl.quiet_mjx import mjx
from vnl.tasks.base import (
    WalkerTask,
    WalkerTaskConfig,
    body_id,
    build_walker,
    check_walker,
    compile_world,
    spawn_height,
)
from vnl.tasks.contract import State
from vnl.tasks.falls import FallRules, fall_terms, fell_metric, zero_metrics
from vnl.tasks.touch import TouchGeoms

PRE_TOUCH, TOUCHED_ONCE, TOUCHED_TWICE, TOUCHED_TOO_SOON, NO_SECOND_TOUCH = range(5)
"""dm_control's `TwoTouchState` values, observed as `task_logic`."""
CLOSENESS_SCALE = 0.01  # dm_control: reward += .01 * closeness * touch reward
CLOSENESS_DECAY = 3.0  # dm_control: closeness = exp(-3 * L1 distance)
_STEP_EPS = 1e-6  # seconds / control step within this of an integer count as it (0.7 / 0.02 = 34.99...)


@dataclasses.dataclass(frozen=True)
class TwoTouchConfig(FallRules, WalkerTaskConfig):
    """`rodent_two_touch`'s rules (dm_control's `basic_rodent_2020.rodent_two_touch`). Times in
    seconds (counted in control steps), lengths in metres. `FallRules` are off here, as in
    dm_control (`vnl.tasks.falls`)."""

    walker: str = "rodent"
    episode_length: int = 1500  # 30 s of 20-ms control steps, dm_control's time limit
    physics_timestep: float = 0.002
    n_substeps: int = 10
    iterations: int = 4  # the rat needs 4 Newton iterations at 2 ms (see run.RODENT_RUN)
    reset_noise_scale: float = 0.01
    floor_size: float = 10.0  # the floor's rendered half-extent (dm_control: Floor(size=(10, 10)))
    # The bodies whose own colliding geoms touch the orb (not their child bodies': the rat's fingers
    # never touch in dm_control, see the module docstring) and whose origins the closeness term
    # measures (dm_control: the rat's hand_L and hand_R).
    hands: tuple[str, ...] = ("hand_L", "hand_R")
    orb_radius: float = 0.025
    orb_height: float = 0.14  # the orb centre's height above the floor (dm_control's z_height)
    target_area: tuple[float, float] = (1.5, 1.5)  # the orb's x, y are uniform in ±these
    touch_reward: float = 25.0  # paid for a first touch and for a correct second one
    touch_interval: float = 0.8  # the wanted time from the first touch to the second
    interval_tolerance: float = 0.1  # a second touch within ± this of touch_interval is correct
    failure_timeout: float = 1.2  # the wait after a second touch too soon or none in the window
    reset_delay: float = 0.0  # the wait before the orb moves, after a correct pair or a timeout
    touch_debounce: float = 0.2  # a touch counts as the second only this long after the first
    observe_target: bool = True  # observe the orb's centre in the root body's frame (`target`)

    def validate(self) -> None:
        super().validate()
        self.check_fall_rules()
        check_walker(self, arena="two-touch floor")
        if not self.hands or any(not isinstance(h, str) or not h for h in self.hands):
            raise VnlError(f"hands must name one or more bodies of the walker, got {list(self.hands)}")
        if not (self.orb_radius > 0 and math.isfinite(self.orb_height) and self.floor_size > 0):
            raise VnlError("orb_radius and floor_size must be > 0 and orb_height a height in metres")
        if len(self.target_area) != 2 or not all(0 < a <= self.floor_size for a in self.target_area):
            raise VnlError(f"target_area must be two half-widths in (0, floor_size], got {list(self.target_area)}")
        if not (math.isfinite(self.touch_reward) and self.touch_reward >= 0):
            raise VnlError(f"touch_reward must be >= 0, got {self.touch_reward}")
        if not 0 <= self.interval_tolerance < self.touch_interval < 1e4:
            raise VnlError(
                "need 0 <= interval_tolerance < touch_interval (< 10,000 s), got "
                f"{self.interval_tolerance} and {self.touch_interval}"
            )
        for key in ("failure_timeout", "reset_delay", "touch_debounce"):
            if not 0 <= getattr(self, key) < 1e4:
                raise VnlError(f"{key} must be a time in [0, 10,000) s, got {getattr(self, key)}")


RODENT_TWO_TOUCH = TwoTouchConfig()
"""`rodent_two_touch`: dm_control's rules (see the module docstring) with vnl's rat physics."""


class TwoTouch(WalkerTask):
    """See the module docstring. `step` is `prepare` (a redraw due moves the orb), the physics,
    then `react` (touches, state, rewards, observation): tests drive `react` with scripted states."""

    def __init__(self, config: TwoTouchConfig) -> None:
        walker = build_walker(config)
        arena = floor.build(config.floor_size)
        orb = arena.worldbody.add("body", name="orb", mocap=True, pos=[config.target_area[0], 0, config.orb_height])
        # No collisions: a touch is a geometric test (vnl.tasks.touch), so MJX gets no pairs for it.
        orb.add(
            "geom", name="orb", type="sphere", size=[config.orb_radius], rgba=[0, 0.6, 0, 1], contype=0, conaffinity=0
        )
        model, report = compile_world(walker, arena)
        super().__init__(config, walker, model, report)
        self._orb_geom = int(np.flatnonzero([model.geom(g).name == "orb" for g in range(model.ngeom)])[0])
        self._orb = int(model.body_mocapid[model.geom_bodyid[self._orb_geom]])
        mocap_bodies = np.flatnonzero(model.body_mocapid >= 0)
        self._mocap0 = np.zeros((model.nmocap, 3), np.float32)
        self._mocap0[model.body_mocapid[mocap_bodies]] = model.body_pos[mocap_bodies]
        try:
            self._hands = np.asarray([body_id(model, h) for h in config.hands], dtype=int)
        except VnlError as e:
            raise VnlError(f"hands: {e}") from None
        self._touch = TouchGeoms.of(model, [int(h) for h in self._hands])
        self._spawn_z = spawn_height(model, 0.0, 0.0)
        dt = self.dt
        self.rule_steps = {  # the rules' times in control steps (see the module docstring)
            "too_soon_below": math.ceil((config.touch_interval - config.interval_tolerance) / dt - _STEP_EPS),
            "window_last": math.floor((config.touch_interval + config.interval_tolerance) / dt + _STEP_EPS),
            "timeout": math.floor(config.failure_timeout / dt + _STEP_EPS),
            "delay": math.floor(config.reset_delay / dt + _STEP_EPS),
            "debounce": math.ceil(config.touch_debounce / dt - _STEP_EPS),
        }

    # Terrain levels (vnl.envs.levels): each env's orb area and height, kept in `info` (`orb_area`,
    # `orb_height`) for the episode's redraws.
    level_fields = ("target_area", "orb_height")
    _PLACEMENT = {"target_area": "orb_area", "orb_height": "orb_height"}

    # --- the contract ----------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        return self.reset_with(rng, {})

    def reset_with(self, rng: jax.Array, values: dict[str, jax.Array]) -> State:
        """`reset`, with the orb drawn in ±`values["target_area"]` (2,) at `values["orb_height"]` if
        given, for this episode's every trial."""
        rng, k_pose, k_vel, k_yaw, k_orb = jax.random.split(rng, 5)
        yaw = jax.random.uniform(k_yaw, (), minval=-jp.pi, maxval=jp.pi)
        qpos = self.initial_qpos(k_pose, jp.array([0.0, 0.0, self._spawn_z]), yaw)
        noise = self._config.reset_noise_scale
        qvel = jax.random.uniform(k_vel, (self._mj_model.nv,), minval=-noise, maxval=noise)
        placement = {self._PLACEMENT[k]: jp.asarray(v, jp.float32) for k, v in values.items()}
        mocap = jp.asarray(self._mocap0).at[self._orb].set(self.draw_orb(k_orb, placement))
        data = self.forward(self.make_data(qpos=qpos, qvel=qvel, mocap_pos=mocap))
        zero, izero = jp.zeros((), jp.float32), jp.zeros((), jp.int32)
        info = {
            "rng": rng,
            "t": izero,  # control steps since reset
            "logic": izero,  # the state (PRE_TOUCH ...) after the last step
            "first": izero,  # the step of the trial's first touch
            "second": izero,  # the step of its second touch, or of the window's close
            "timeout": jp.zeros((), bool),  # waiting out failure_timeout
            "redraw": jp.zeros((), bool),  # the orb moves at the start of the next step
            **placement,
        }
        metrics = {
            **{f"reward/{k}": zero for k in ("closeness", "first_touch", "second_touch")},
            **{f"measure/{k}": zero for k in ("first_touches", "correct_pairs", "too_soon", "no_second_touch")},
            "touch_interval": zero,
            "task_logic": zero,
            "hand_distance": self.hand_distance(data),
            "physics_nan": zero,
            **zero_metrics(self._config),
        }
        return State(data, self._obs(data, izero), zero, zero, metrics, info)

    @property
    def previous_state_reads(self) -> tuple[str, ...]:
        """The hands' positions (hand_distance of a blown-up step reads them) and, with fall rules,
        the root's orientation: docs/experiments/compact-checkpoints.md."""
        return ("xpos",) + (("xmat",) if self._config.healthy_min_upright is not None else ())

    def step(self, state: State, action: jax.Array) -> State:
        state = self.prepare(state)
        data, blew_up = self.physics_step(state.data, self.sanitize_action(action))
        return self.react(state, data, blew_up)

    # --- the step's two halves -------------------------------------------------------------------
    def prepare(self, state: State) -> State:
        """The start of a step (dm_control's `before_step`): a redraw due moves the orb to a new
        random point (drawn from the episode's key and this step's index) and restarts the trial."""
        info = state.info
        redraw = info["redraw"]
        new = self.draw_orb(jax.random.fold_in(info["rng"], info["t"]), info)
        orb = jp.where(redraw, new, state.data.mocap_pos[self._orb])
        data = state.data.replace(mocap_pos=state.data.mocap_pos.at[self._orb].set(orb))
        info = {
            **info,
            "logic": jp.where(redraw, PRE_TOUCH, info["logic"]),
            "timeout": info["timeout"] & ~redraw,
            "redraw": jp.zeros((), bool),
        }
        return state.replace(data=data, info=info)

    def react(self, state: State, data: mjx.Data, blew_up: jax.Array) -> State:
        """The end of a step (dm_control's `get_reward`) on `data`, the physics state after the
        control step of `state` (a `prepare`d state; `blew_up` 1.0 if the physics did)."""
        cfg: TwoTouchConfig = self._config
        ok = 1.0 - blew_up
        t = state.info["t"] + 1
        touching = (self.touches(data) * ok) > 0
        info, events = self.advance(state.info, t, touching)
        closeness = CLOSENESS_SCALE * cfg.touch_reward * self.closeness(data) * ok
        fall, fell = fall_terms(cfg, self.upright_cosine(data), data.xpos[self._root, 2], ok)
        terms = {
            "closeness": closeness,
            "first_touch": cfg.touch_reward * events["first_touch"],
            "second_touch": cfg.touch_reward * events["correct"],
            **fall,
        }
        metrics = {
            **state.metrics,
            **{f"reward/{k}": v for k, v in terms.items()},
            "measure/first_touches": events["first_touch"],
            "measure/correct_pairs": events["correct"],
            "measure/too_soon": events["too_soon"],
            "measure/no_second_touch": events["closed"],
            "touch_interval": events["interval"],
            "task_logic": info["logic"].astype(jp.float32),
            "hand_distance": self.hand_distance(data),
            "physics_nan": blew_up,
            **fell_metric(cfg, fell),
        }
        reward = sum(terms.values())
        obs = self._obs(data, state.info["logic"])  # the state the step began in, as dm_control observes it
        done = jp.maximum(blew_up, fell)
        return state.replace(data=data, obs=obs, reward=reward, done=done, metrics=metrics, info={**info, "t": t})

    def advance(self, info: dict, t: jax.Array, touching: jax.Array) -> tuple[dict, dict[str, jax.Array]]:
        """The state machine at control step `t` (int32) given whether a hand touches the orb:
        the new `info` entries and the step's events (each a float32 scalar, 0 or 1; `interval` in
        seconds). dm_control's `get_reward` branches on the state the step began in; so does this."""
        s = self.rule_steps
        logic, first, second, timeout = info["logic"], info["first"], info["second"], info["timeout"]
        since_first, since_second = t - first, t - second
        first_touch = (logic == PRE_TOUCH) & touching
        once = logic == TOUCHED_ONCE
        second_touch = once & touching & (since_first >= s["debounce"])
        too_soon = second_touch & (since_first < s["too_soon_below"])
        correct = second_touch & ~too_soon & (since_first <= s["window_last"])
        closed = once & (since_first > s["window_last"])  # a touch at this step comes too late too
        waiting = logic >= TOUCHED_TWICE  # after a pair or a failure
        new_logic = jp.select(
            [first_touch, too_soon, correct, closed],
            [jp.int32(TOUCHED_ONCE), jp.int32(TOUCHED_TOO_SOON), jp.int32(TOUCHED_TWICE), jp.int32(NO_SECOND_TOUCH)],
            logic,
        )
        timeout_over = waiting & timeout & (since_second > s["timeout"])
        new = {
            **info,
            "logic": new_logic,
            "first": jp.where(first_touch, t, first),
            "second": jp.where(too_soon | correct | closed, t, second),
            "timeout": (timeout & ~timeout_over) | too_soon | closed,
            "redraw": waiting & ~timeout & (since_second > s["delay"]),
        }
        f32 = jp.float32
        events = {
            "first_touch": first_touch.astype(f32),
            "correct": correct.astype(f32),
            "too_soon": too_soon.astype(f32),
            "closed": closed.astype(f32),
            "interval": jp.where(too_soon | correct, since_first * self.dt, 0.0).astype(f32),
        }
        return new, events

    # --- what the task measures ------------------------------------------------------------------
    def draw_orb(self, key: jax.Array, info: dict[str, jax.Array] | None = None) -> jax.Array:
        """A new orb centre: x, y uniform in ±target_area, z = orb_height (an episode's own, from
        `info["orb_area"]` and `info["orb_height"]` where its level set them); shape (3,)."""
        cfg: TwoTouchConfig = self._config
        info = info or {}
        area = info.get("orb_area", jp.asarray(cfg.target_area, jp.float32))
        height = info.get("orb_height", jp.float32(cfg.orb_height))
        xy = jax.random.uniform(key, (2,), minval=-1.0, maxval=1.0) * area
        return jp.concatenate([xy, jp.reshape(height, (1,)).astype(jp.float32)])

    def orb(self, data: mjx.Data) -> jax.Array:
        """The orb's centre (world frame), shape (3,)."""
        return data.mocap_pos[self._orb]

    def touches(self, data: mjx.Data) -> jax.Array:
        """1.0 when a hand geom overlaps the orb (where MuJoCo would list a contact), else 0.0."""
        return self._touch.overlaps(data, self.orb(data), self._config.orb_radius)

    def closeness(self, data: mjx.Data) -> jax.Array:
        """dm_control's closeness: max over the hands of exp(-3 x L1 distance from the hand body's
        origin to the orb's centre), a scalar in (0, 1]."""
        l1 = jp.sum(jp.abs(data.xpos[self._hands] - self.orb(data)), axis=-1)
        return jp.max(jp.exp(-CLOSENESS_DECAY * l1))

    def hand_distance(self, data: mjx.Data) -> jax.Array:
        """The smallest distance (m) from a hand body's origin to the orb's centre, a scalar."""
        return jp.min(jp.linalg.norm(data.xpos[self._hands] - self.orb(data), axis=-1))

    # --- observation -----------------------------------------------------------------------------
    def _obs(self, data: mjx.Data, logic: jax.Array) -> jax.Array:
        parts = [self.proprioception(data), *self.heading(data)]
        if self._config.observe_target:
            parts.append(self.egocentric(data, self.orb(data)[None])[0])
        parts.append(logic.astype(jp.float32)[None])
        return jp.concatenate(parts + self.clock(data)).astype(jp.float32)

    def observation_layout(self) -> list[tuple[str, int]]:
        target = [("target", 3)] if self._config.observe_target else []
        return self.proprioception_layout() + self.heading_layout() + target + [("task_logic", 1)] + self.clock_layout()
