"""Batched rollouts of a policy in an env: the one engine (`run_episodes`) that `vnl eval`,
`render`, `record` and `view` share, eval's summary, and policy videos."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jp
import numpy as np

from vnl.errors import VnlError
from vnl.io import video
from vnl.policy import LoadedRun, Policy, RecurrentPolicy, stateful
from vnl.quiet_mjx import mjx
from vnl.tasks.contract import Env
from vnl.vision.camera import Camera
from vnl.vision.env import VisionEnv, default_camera

Actor = Callable[[Any, Any, jax.Array], tuple[dict[str, jax.Array], Any]]
"""`actor(obs, core, key) -> ({"action": (..., act), ...}, core)`: the step's action, anything else
to keep of the step (a network's layers), and the actor's new state (`()` for a feed-forward one)."""


@dataclasses.dataclass
class Episodes:
    """What `run_episodes` keeps of E episodes of T control steps. Step t is the state s_t the
    actor acted in and the transition s_t -> s_{t+1}; arrays are episode-major.

    Attributes:
      states: field -> (E, T + 1, ...) the states' `mjx.Data` fields s_0, ..., s_T (`qpos`, ...).
      obs: the observations (E, T, ...) of s_0 .. s_{T-1} (a dict for a pixel env), or None.
      acted: name -> (E, T, ...) what the actor returned for each step ("action", layers).
      reward, done: (E, T) of each transition. active: (E, T) 1.0 for the steps up to and
        including the one that ended the episode.
      metrics: name -> (E, T) the metrics of s_{t+1}. metrics0: name -> (E,) those of s_0.
      info0: the reset states' `info` (e.g. the gaps corridor's `layout`).
    """

    states: dict[str, np.ndarray]
    obs: Any
    acted: dict[str, np.ndarray]
    reward: np.ndarray
    done: np.ndarray
    active: np.ndarray
    metrics: dict[str, np.ndarray]
    metrics0: dict[str, np.ndarray]
    info0: Any


def run_episodes(
    env: Env,
    actor: Actor,
    initial_core: Any,
    rng: jax.Array,
    episodes: int,
    steps: int,
    fields: tuple[str, ...] = ("qpos", "mocap_pos"),
    observations: bool = False,
) -> Episodes:
    """Runs `episodes` episodes in parallel for `steps` control steps (no auto-reset): the one
    rollout engine of `vnl eval`, `render`, `record` and `view`. `rng` is split into the resets'
    keys and one key per step (shared by the episodes); `initial_core` is the actor's state at
    the start (batched over episodes); `fields` are the `mjx.Data` fields kept of every state;
    `observations` keeps each step's observation."""

    @jax.jit
    def go(rng: jax.Array) -> Any:
        k_reset, k_act = jax.random.split(rng)
        state = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))

        def body(carry: Any, key: jax.Array) -> Any:
            state, core, alive = carry
            acted, core = actor(state.obs, core, key)
            nxt = jax.vmap(env.step)(state, acted["action"])
            out = {
                "state": {f: getattr(state.data, f) for f in fields},
                "obs": state.obs if observations else None,
                "acted": acted,
                "reward": nxt.reward,
                "done": nxt.done,
                "active": alive,
                "metrics": nxt.metrics,
            }
            return (nxt, core, alive * (1.0 - nxt.done)), out

        keys = jax.random.split(k_act, steps)
        (last, _, _), out = jax.lax.scan(body, (state, initial_core, jp.ones((episodes,))), keys)
        final = {f: getattr(last.data, f) for f in fields}
        return out, final, state.metrics, state.info

    out, final, metrics0, info0 = jax.device_get(go(rng))
    states = {f: np.concatenate([_et(out["state"][f]), np.asarray(final[f])[:, None]], axis=1) for f in fields}
    return Episodes(
        states=states,
        obs=jax.tree.map(_et, out["obs"]),
        acted={k: _et(v) for k, v in out["acted"].items()},
        reward=_et(out["reward"]),
        done=_et(out["done"]),
        active=_et(out["active"]),
        metrics={k: _et(v) for k, v in out["metrics"].items()},
        metrics0={k: np.asarray(v) for k, v in metrics0.items()},
        info0=info0,
    )


def _et(x: Any) -> np.ndarray:
    """(T, E, ...) -> (E, T, ...)."""
    return np.swapaxes(np.asarray(x), 0, 1)


@dataclasses.dataclass
class Rollout:
    """Arrays from `rollout`, with E episodes and T steps.

    Attributes:
      qpos: (E, T + 1, nq) positions, starting with the reset state.
      mocap_pos: (E, T + 1, nmocap, 3) mocap body positions (e.g. the gaps corridor's platforms).
      reward: (E, T) rewards. done: (E, T) 1.0 where the episode ended.
      active: (E, T) 1.0 for steps up to and including the episode's end.
      metrics: name -> (E, T) per-step metrics.
      metrics0: name -> (E,) metrics of the reset states.
    """

    qpos: np.ndarray
    mocap_pos: np.ndarray
    reward: np.ndarray
    done: np.ndarray
    active: np.ndarray
    metrics: dict[str, np.ndarray]
    metrics0: dict[str, np.ndarray]

    @property
    def lengths(self) -> np.ndarray:
        """(E,) episode lengths in steps."""
        return self.active.sum(axis=1)


def rollout(env: Env, policy: Policy | RecurrentPolicy, rng: jax.Array, episodes: int, steps: int) -> Rollout:
    """Runs `episodes` episodes of `policy` in parallel for `steps` control steps (no auto-reset;
    `run_episodes`); a recurrent policy's state starts at its initial state."""
    initial_state, act = stateful(policy)

    def actor(obs: Any, core: Any, key: jax.Array) -> tuple[dict[str, jax.Array], Any]:
        action, core = act(obs, core, key)
        return {"action": action}, core

    e = run_episodes(env, actor, initial_state((episodes,)), rng, episodes, steps)
    return Rollout(e.states["qpos"], e.states["mocap_pos"], e.reward, e.done, e.active, e.metrics, e.metrics0)


def summarize(r: Rollout, dt: float) -> dict[str, Any]:
    """Per-episode statistics (mean and std over episodes) of a rollout.

    Sums (reward, each `reward/<term>` and each task measure `measure/<name>`, reported as
    `<name>`) run over each episode's active steps; forward distance is the root's x displacement
    from reset to the episode's last active step; mean forward velocity is that distance over the
    episode's duration; `upright_fraction` is the time upright over the rollout's full length;
    `ended_early` is the fraction of episodes that ended (a fall, an escape: the task's end)
    before the rollout's last step, so 0 means every episode ran its full length; `fell` the
    fraction a fall ended (tasks with a `fell` metric); `time_to_escape` is the time in the bowl
    over the episodes that left it (NaN if none did).
    """
    mask = r.active
    lengths = r.lengths
    per_episode: dict[str, np.ndarray] = {
        "episode_reward": (r.reward * mask).sum(1),
        "episode_length": lengths,
        "ended_early": (lengths < r.reward.shape[1]).astype(np.float64),
    }
    for k, v in r.metrics.items():
        if k.startswith("reward/"):
            per_episode[f"episode_{k}"] = (v * mask).sum(1)
    if "x_position" in r.metrics and "x_position" in r.metrics0:
        last = np.maximum(lengths.astype(int) - 1, 0)
        x_end = r.metrics["x_position"][np.arange(len(last)), last]
        distance = x_end - r.metrics0["x_position"]
        per_episode["forward_distance"] = distance
        per_episode["mean_forward_velocity"] = distance / np.maximum(lengths * dt, 1e-9)
    if "physics_nan" in r.metrics:
        per_episode["physics_nan"] = (r.metrics["physics_nan"] * mask).sum(1)
    if "fell" in r.metrics:  # 1 at the step a fall ended the episode (vnl.tasks.falls, run_gaps' failures)
        per_episode["fell"] = (r.metrics["fell"] * mask).sum(1)
    # Task measures: per-step increments whose episode sums say what the animal did.
    for k, v in r.metrics.items():
        if k.startswith("measure/"):
            per_episode[k.removeprefix("measure/")] = (v * mask).sum(1)
    if "upright_time" in per_episode:
        per_episode["upright_fraction"] = per_episode["upright_time"] / (r.reward.shape[1] * dt)
    out: dict[str, Any] = {"episodes": int(len(lengths))}
    for k, v in per_episode.items():
        out[k] = {"mean": float(np.mean(v)), "std": float(np.std(v))}
    if "escaped" in per_episode:  # time to leave the bowl, over the episodes that left it
        left = per_episode["escaped"] > 0
        times = per_episode["time_in_bowl"][left]
        out["time_to_escape"] = {
            "mean": float(times.mean()) if left.any() else float("nan"),
            "std": float(times.std()) if left.any() else float("nan"),
        }
    return out


def policy_video(
    env: Env,
    policy: Policy,
    path: str,
    camera: str | None = None,
    steps: int | None = None,
    width: int = 480,
    height: int = 360,
    seed: int = 0,
) -> tuple[str, int]:
    """Renders one episode of `policy` (until it ends or `steps`) to an .mp4; returns (path, frames).

    With the env's egocentric camera (or, for a vision env, the camera the policy sees through),
    each frame shows the default external camera on the left and, on the right, the in-graph
    camera's image at the policy's resolution (upscaled without smoothing): what the policy saw.

    Raises `VnlError` for an unknown camera (before rolling out) or when OpenGL is unavailable.
    """

    cam_id = video.resolve_camera(env.mj_model, camera)
    view = _policy_view(env, cam_id)
    steps = steps or int(round(10.0 / env.dt))
    r = rollout(env, policy, jax.random.PRNGKey(seed), episodes=1, steps=steps)
    n = int(r.lengths[0]) + 1  # the reset frame plus every active step
    qpos, mocap = r.qpos[0, :n], r.mocap_pos[0, :n]
    if view is None:
        frames = video.render_frames(env.mj_model, qpos, camera, width, height, mocap_pos=mocap)
    else:  # the default external camera | what the in-graph camera (the policy's eyes) sees
        outside = video.render_frames(env.mj_model, qpos, None, width, height, mocap_pos=mocap)
        frames = np.concatenate([outside, _upscale(camera_frames(env, view, qpos, mocap), height)], axis=2)
    video.write_mp4(frames, path, fps=1.0 / env.dt)
    return str(path), n


def final_video(run: LoadedRun, name: str = "final_policy.mp4") -> tuple[str, int]:
    """`name` in the run directory: one episode of the run's policy with the run's `log.video_*`
    settings (camera, seconds, size); returns (path, frames)."""
    log = run.config.log
    steps = int(round(log.video_seconds / run.env.dt))
    out = str(Path(run.run_dir) / name)
    return policy_video(run.env, run.policy, out, log.video_camera, steps, log.video_width, log.video_height)


def _policy_view(env: Env, cam_id: int) -> Any:
    """The in-graph `Camera` for a side-by-side video when `cam_id` is the camera the policy sees
    through (a vision env's camera, else the model's egocentric camera at 64x64), else None."""

    if isinstance(env, VisionEnv):
        if cam_id == env.camera.camera_id:
            return env.camera
        return None
    try:
        name = default_camera(env.mj_model)
    except VnlError:  # no egocentric camera: nothing to put side by side
        return None
    camera = Camera(env.mj_model, name, skip_unsupported=True)
    return camera if cam_id == camera.camera_id else None


def camera_frames(env: Env, camera: Any, qpos: np.ndarray, mocap_pos: np.ndarray) -> np.ndarray:
    """In-graph camera RGB images of the states (T, nq) / (T, nmocap, 3): uint8 (T, H, W, 3)."""

    model = env.mjx_model

    @jax.jit
    def images(q: jax.Array, m: jax.Array) -> jax.Array:
        def one(q: jax.Array, m: jax.Array) -> jax.Array:
            data = mjx.make_data(model).replace(qpos=q, mocap_pos=m)
            data = mjx.camlight(model, mjx.com_pos(model, mjx.kinematics(model, data)))
            return camera.render(data)[0]

        return jax.lax.map(lambda x: one(*x), (q, m), batch_size=4)

    return np.asarray(images(jp.asarray(qpos, jp.float32), jp.asarray(mocap_pos, jp.float32)))


def _upscale(images: np.ndarray, height: int) -> np.ndarray:
    """Nearest-neighbour upscaling of (T, h, w, C) to (T, height, height * w // h, C)."""
    h, w = images.shape[1:3]
    rows = np.arange(height) * h // height
    width = height * w // h
    cols = np.arange(width) * w // width
    return images[:, rows][:, :, cols]
