"""Neural recordings of a trained virtual animal: `vnl record`.

`record` rolls out a trained run's policy and returns an `xarray.Dataset` with, per episode and
time step: the observation, the activations of every layer of the policy and value networks, the
action, the reward and its terms, the env's metrics, and the walker's joint angles, joint
velocities and body poses (positions and orientations). `write` (`vnl.recording.netcdf.write`)
saves it as NetCDF-4 (HDF5, through h5netcdf) with named dimensions, readable with xarray or h5py
alone.

Timing: variables indexed by `time` t describe the step that starts in state s_t: the observation
o_t, the network activity computed from o_t, the action a_t chosen from it, the body pose in s_t
and the reward r_t received on the transition to s_{t+1}. `active` is 1 up to and including the
step at which the episode ended (later steps repeat a frozen state and should be ignored).

Activations are captured from the very forward pass that chose the action (flax method
interception of every `Dense` layer of Brax's MLPs): `policy_hidden_<i>` / `value_hidden_<i>` are
the outputs of hidden layer i after the nonlinearity, the inputs the next layer receives;
`policy_output` holds the raw output layer (with `network.distribution_type: tanh_normal` the
action distribution's location, then its pre-softplus scale, the deterministic action being
tanh(location); with `normal` the location alone, the deterministic action, clipped by the env),
`value_output` the value estimate.
"""

from __future__ import annotations

import json
import os
from typing import Any

import jax
import jax.numpy as jp
import numpy as np

from vnl.errors import VnlError
from vnl.policy import LoadedRun
from vnl.ppo.intention_core import latent_draw
from vnl.ppo.networks import ACTIVATIONS, make_network
from vnl.ppo.recurrent import make_recurrent_networks
from vnl.ppo.sac import make_q_network
from vnl.recording import behaviour, model
from vnl.recording.netcdf import write  # noqa: F401 (`vnl.record.write`, the name the tutorials use)
from vnl.rollout import run_episodes


def _dense_outputs(apply: Any, *args: Any, within: str | None = None) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Calls a Brax network's `apply` and returns (output, {dense layer name: its output}); with
    `within`, only the layers of the submodule of that name (e.g. a Q network's first MLP, `MLP_0`)."""
    from flax import linen

    captured: dict[str, jax.Array] = {}

    def interceptor(next_fun: Any, f_args: Any, f_kwargs: Any, context: Any) -> Any:
        out = next_fun(*f_args, **f_kwargs)
        if isinstance(context.module, linen.Dense) and context.method_name == "__call__":
            if within is None or within in context.module.path:
                captured[context.module.name] = out
        return out

    with linen.intercept_methods(interceptor):
        out = apply(*args)
    return out, captured


def network_activity(
    run: LoadedRun, obs: jax.Array, key: jax.Array, deterministic: bool = True, core: Any = ()
) -> tuple[dict[str, Any], Any]:
    """The action chosen for `obs` (..., obs_size) and every layer's activity on the way.

    Returns ({"action": (..., act), "policy_hidden_<i>": (..., units), "policy_output": ...,
    "value_hidden_<i>": ..., "value_output": (...,)}, the core state after this step). The action
    equals the run's policy's. A recurrent run (`network.core`) takes and returns its cores' state
    `core` ({"policy": carry, "value": carry}; `initial_core`) and adds `<net>_core_h` (and
    `<net>_core_c` for an LSTM): the core's state after reading `obs`, from which the step's
    output (and action) is computed. Merel's network (`network.architecture: merel`) has
    `encoder_hidden_<i>`, `encoder_vision_<camera>`, `core_h`/`core_c`, `policy_core_<i>_h`/`_c`,
    `policy_output` and `value_output` (`vnl.ppo.merel`). The intention network
    (`network.architecture: intention`, `vnl.ppo.intention`) has `encoder_hidden_<i>`, the latent's
    `encoder_intention_mean` and `encoder_intention_log_std`, `policy_intention` (the latent its
    decoder read: the mean, or a draw when not `deterministic`), the decoder's `policy_hidden_<i>`,
    `policy_output`, and the value MLP's layers; with `network.core` (a recurrent decoder,
    `vnl.ppo.intention_core`) also `policy_core_h`/`_c`, and the value's `value_hidden_<i>`,
    `value_core_h`/`_c`. A run through a frozen decoder (`decoder.run`,
    `vnl.train.frozen_decoder`) adds the decoder's layers: `policy_decoder_intention` (the latent
    it read: the action × `decoder.latent_scale`), `policy_decoder_hidden_<i>`,
    `policy_decoder_output` and `body_action`, the action the decoder gave the body (a recording
    stores it as `action`, and the policy's own as `latent_action`). A soft actor-critic run
    (`algorithm: sac`) has the policy's layers and, as `value_hidden_<i>`, its first Q network's
    layers at the chosen action, and as `value_output` min(Q1, Q2) there.
    """
    if not _stateful_decoder(run):
        out, core = _own_activity(run, obs, key, deterministic, core)
        return _with_decoder(run, out, obs)[0], core
    out, own = _own_activity(run, obs, key, deterministic, core["own"])
    out, decoder = _with_decoder(run, out, obs, core["decoder"])
    return out, {"own": own, "decoder": decoder}


def _stateful_decoder(run: LoadedRun) -> bool:
    """Whether the run acts through a frozen decoder with a memory (`decoder.run` of a recurrent decoder)."""
    return bool(getattr(run.env, "stateful", False))


def _own_activity(
    run: LoadedRun, obs: jax.Array, key: jax.Array, deterministic: bool, core: Any
) -> tuple[dict[str, Any], Any]:
    """`network_activity` of the run's own networks (without a frozen decoder's layers)."""
    if run.config.network.core is not None:
        return _recurrent_activity(run, obs, key, deterministic, core)
    network = make_network(run.config, run.env)
    normalizer, policy_params, value_params = run.params
    act = ACTIVATIONS[run.config.network.activation]
    out: dict[str, Any] = {}
    nets = [("policy", network.policy_network, policy_params), ("value", network.value_network, value_params)]
    if run.config.network.architecture == "intention":
        out = _intention_activity(network, normalizer, policy_params, obs, key, deterministic)
        nets = nets[1:]
    if run.config.algorithm == "sac":  # its critic reads the action too (below)
        nets = nets[:1]
    for prefix, net, params in nets:
        result, dense = _dense_outputs(net.apply, normalizer, params, obs)
        # Brax's MLP layers are hidden_0..hidden_N; a `normal` policy's location layer
        # (Dense_0) follows its MLP's hidden layers.
        names = sorted(dense, key=lambda n: (not n.startswith("hidden_"), int(n.split("_")[-1])))
        for name in names[:-1]:
            out[f"{prefix}_{name}"] = act(dense[name])
        out[f"{prefix}_output"] = dense[names[-1]] if prefix == "policy" else result
        if prefix == "policy":
            out["action"] = _action(network.parametric_action_distribution, result, key, deterministic)
    if run.config.algorithm == "sac":  # the first Q network's layers, at the chosen action
        q_net = make_q_network(run.config, run.env)
        q, dense = _dense_outputs(q_net.apply, normalizer, value_params, obs, out["action"], within="MLP_0")
        hidden = sorted(dense, key=lambda n: int(n.split("_")[-1]))[:-1]  # the last layer is Q1
        out.update({f"value_{name}": act(dense[name]) for name in hidden})
        out["value_output"] = jp.min(q, axis=-1)
    return out, core


def _with_decoder(run: LoadedRun, out: dict[str, Any], obs: jax.Array, state: Any = None) -> tuple[dict[str, Any], Any]:
    """(`out` with a frozen decoder's layers (`decoder.run`: the env turns the action into the
    body's), the decoder's state after this step: `state` is a recurrent decoder's before it)."""
    if not hasattr(run.env, "decoder_activity"):
        return out, state
    out.update(run.env.decoder_activity(out["action"], obs, state))
    out["body_action"], state = run.env.decoded(out["action"], obs, state)
    return out, state


def _intention_activity(
    network: Any, normalizer: Any, params: Any, obs: jax.Array, key: jax.Array, deterministic: bool
) -> dict[str, Any]:
    """The intention network's layers (`vnl.ppo.intention`) and action for `obs`, drawing the
    latent and the action from `key` as its inference function does (the mean latent and the
    mode when `deterministic`)."""
    key_latent, key_action = jax.random.split(key)
    policy = network.policy_network
    noise = None if deterministic else jax.random.normal(key_latent, obs.shape[:-1] + (policy.intention_size,))
    out, head = policy.activity(normalizer, params, obs, noise)
    out["action"] = _action(network.parametric_action_distribution, head, key_action, deterministic)
    return out


def _action(dist: Any, logits: Any, key: jax.Array, deterministic: bool) -> jax.Array:
    return dist.mode(logits) if deterministic else dist.postprocess(dist.sample_no_postprocessing(logits, key))


def episode_activity(run: LoadedRun, obs: np.ndarray) -> dict[str, np.ndarray]:
    """Every layer's activity (and the deterministic action) on recorded episodes' observations
    `obs` (episodes, time, width): name -> (episodes, time, ...). A recurrent run's cores start
    each episode at their initial state and carry it through the episode's steps."""
    obs = jp.asarray(obs, jp.float32)
    key = jax.random.PRNGKey(0)
    if run.config.network.core is None and not _stateful_decoder(run):
        activity, _ = network_activity(run, obs, key)
        return jax.device_get(activity)

    def body(core: Any, o: jax.Array) -> tuple[Any, Any]:
        activity, core = network_activity(run, o, key, True, core)
        return core, activity

    _, activity = jax.lax.scan(body, initial_core(run, (obs.shape[0],)), jp.swapaxes(obs, 0, 1))
    return {k: np.swapaxes(np.asarray(v), 0, 1) for k, v in jax.device_get(activity).items()}


def initial_core(run: LoadedRun, batch_shape: tuple[int, ...]) -> Any:
    """The cores' state at the start of an episode (a recurrent run), else (); through a recurrent
    frozen decoder, {"own": that, "decoder": the decoder's state batch_shape + (...)}."""
    own: Any = ()
    if run.config.network.core is not None:
        from vnl.ppo.recurrent_ppo import zero_carry

        own = zero_carry(make_recurrent_networks(run.config, run.env), batch_shape)
    if not _stateful_decoder(run):
        return own
    decoder = jax.tree.map(lambda x: jp.broadcast_to(x, batch_shape + x.shape), run.env.decoder_state)
    return {"own": own, "decoder": decoder}


def _recurrent_activity(
    run: LoadedRun, obs: jax.Array, key: jax.Array, deterministic: bool, core: Any
) -> tuple[dict[str, Any], Any]:
    """`network_activity` of a recurrent run: the encoder's layers (`hidden_<i>`, intercepted),
    the core's new state, the head's output."""
    networks = make_recurrent_networks(run.config, run.env)
    normalizer, policy_params, value_params = run.params
    if run.config.network.architecture == "merel":
        out, logits, new_core = networks.activity(normalizer, policy_params, value_params, obs, core)
        out["action"] = _action(networks.parametric_action_distribution, logits, key, deterministic)
        return out, new_core
    act = ACTIVATIONS[run.config.network.activation]
    no_reset = jp.zeros(core["policy"][0].shape[:-1])
    out: dict[str, Any] = {}
    new_core = {}
    nets = [("value", networks.value_network, value_params)]
    if run.config.network.architecture == "intention":  # a recurrent decoder (vnl.ppo.intention_core)
        latent, key = latent_draw(networks, key, no_reset.shape, deterministic)
        activity = networks.policy_activity(normalizer, policy_params, obs, core["policy"], **latent)
        out, head, new_core["policy"] = activity
        out["action"] = _action(networks.parametric_action_distribution, head, key, deterministic)
    else:
        nets.insert(0, ("policy", networks.policy_network, policy_params))
    for prefix, net, params in nets:
        (result, carry, _), dense = _dense_outputs(net.step, normalizer, params, obs, core[prefix], no_reset)
        hidden = sorted((n for n in dense if n.startswith("hidden_")), key=lambda n: int(n.split("_")[-1]))
        for name in hidden:
            out[f"{prefix}_{name}"] = act(dense[name])
        out[f"{prefix}_core_h"] = carry[-1]
        if len(carry) == 2:
            out[f"{prefix}_core_c"] = carry[0]
        out[f"{prefix}_output"] = result[0] if isinstance(result, tuple) else result
        new_core[prefix] = carry
        if prefix == "policy":
            out["action"] = _action(networks.parametric_action_distribution, result, key, deterministic)
    out["value_output"] = jp.squeeze(out["value_output"], -1)
    return out, new_core


def record(run: LoadedRun, episodes: int, steps: int, seed: int = 0, deterministic: bool = True) -> Any:
    """Rolls out `episodes` episodes of `steps` control steps (`vnl.rollout.run_episodes`, with
    every layer's activity kept) and returns an xarray.Dataset (see the module docstring; a pixel
    env's images are stored as `pixels_<camera>`)."""
    if episodes < 1 or steps < 1:
        raise VnlError(f"--episodes and --steps must be >= 1, got {episodes} and {steps}")
    env = run.env

    def actor(obs: Any, core: Any, key: jax.Array) -> tuple[dict[str, Any], Any]:
        return network_activity(run, obs, key, deterministic, core)

    fields = ("qpos", "qvel", "xpos", "xquat") + (("mocap_pos",) if env.mj_model.nmocap else ())
    core = initial_core(run, (episodes,))
    e = run_episodes(env, actor, core, jax.random.PRNGKey(seed), episodes, steps, fields, observations=True)
    raw = {_STATE_NAMES.get(f, f): e.states[f][:, :steps] for f in fields}  # s_0 .. s_{T-1}
    raw.update(reward=e.reward, done=e.done, active=e.active, metrics=e.metrics, **e.acted)
    if "body_action" in raw:  # a frozen decoder's run: `action` is what the body did, the policy's is the latent
        raw["latent_action"], raw["action"] = raw["action"], raw.pop("body_action")
    layout = e.info0.get("layout") if isinstance(e.info0, dict) else None
    if layout is not None:  # a gaps corridor: each episode's platforms, (episodes, platforms)
        raw["layout_start"], raw["layout_length"] = np.asarray(layout.start), np.asarray(layout.length)
    poses = getattr(env.unwrapped, "reference_poses", None)
    if poses is not None:  # an imitation: the reference pose the body was asked to take at each step
        ref = poses(np.asarray(e.info0["clip"]), np.asarray(e.info0["frame"]), steps)
        raw["reference_qpos"], raw["reference_body_pos"] = ref["qpos"], ref["body_pos"]
    return _dataset(run, raw, e.obs, seed, deterministic)


def task_steps(run: LoadedRun, steps: int | None = None) -> dict[str, int]:
    """The control steps `record_tasks` records of each task of a suite's run: `steps`, else the
    run's `ppo.episode_length`, else the task's own episode length."""
    views = getattr(run.env, "views", None)
    if not views:
        raise VnlError(f"{run.config.env} is one task, not a suite: record it with `record`")
    return {n: steps or run.config.ppo.episode_length or v.config.episode_length for n, v in views.items()}


def record_tasks(
    run: LoadedRun, episodes: int, steps: int | None = None, seed: int = 0, deterministic: bool = True, say: Any = None
) -> Any:
    """A suite's policy (`run.env` a `vnl.envs.suite` env) recorded on each of its tasks: `episodes`
    episodes of each, `steps` control steps (None: each task's own episode length), stacked into
    one recording (`vnl.recording.stack.stack_tasks`: episodes (K * episodes,), `task` (episode,
    time) the index into the `tasks` attribute). `say(text)` hears which task is being recorded."""
    import dataclasses

    from vnl.recording import stack

    parts = {}
    for name, length in task_steps(run, steps).items():
        one = dataclasses.replace(run, env=run.env.views[name], env_set=(*run.env_set, f"env_config.task={name}"))
        if say is not None:
            say(f"recording task {name}: {episodes} episodes x {length} steps")
        parts[name] = record(one, episodes, length, seed, deterministic)
    return stack.stack_tasks(parts)


_LATENT = {
    "encoder_intention_mean": "the intention latent's mean (linear)",
    "encoder_intention_log_std": "the intention latent's log standard deviation (linear)",
    "policy_intention": "the intention latent the decoder read (the mean, or a draw)",
}
"""The descriptions of the intention network's latent layers (`vnl.ppo.intention`)."""
_STATE_NAMES = {"xpos": "body_pos", "xquat": "body_quat"}
"""The recording's names of the `mjx.Data` fields it keeps under another name."""


def _observation_variables(env: Any, observation: Any) -> tuple[dict[str, Any], list[str]]:
    """The flat observation (episode, time, feature) and, for a pixel env, each image
    (episode, time, row, column, channel), with the feature labels, of the observations
    (episode, time, ...)."""
    dims_et = model.STEP_DIMS
    data: dict[str, Any] = {}
    if isinstance(observation, dict):  # a pixel env: {"state": ..., "pixels/<camera>": ...}
        for key, image in observation.items():
            if key.startswith("pixels/"):
                data[key.replace("/", "_")] = (dims_et + ("pixel_row", "pixel_column", "channel"), np.asarray(image))
        observation = observation["state"]
    flat = np.asarray(observation)
    layout = [(name, w) for name, w in env.observation_layout() if not name.startswith("pixels/")]
    labels = [f"{name}[{i}]" for name, w in layout for i in range(w)]
    if len(labels) != flat.shape[-1]:
        labels = [str(i) for i in range(flat.shape[-1])]
    data["observation"] = (dims_et + ("observation_feature",), flat)
    return data, labels


def _variables(run: LoadedRun, raw: dict[str, Any], observation: Any) -> tuple[dict[str, Any], list[str], list]:
    """The recording's variables (name -> (dims, array)) of the episode-major arrays `raw`, the
    observation's labels and the layers ({"name", "units"})."""
    m = run.env.mj_model
    dims_et = model.STEP_DIMS
    data, obs_labels = _observation_variables(run.env, observation)
    data.update(
        {
            "action": (dims_et + ("actuator",), raw["action"]),
            "reward": (dims_et, raw["reward"]),
            "done": (dims_et, raw["done"]),
            "active": (dims_et, raw["active"]),
            "qpos": (dims_et + ("qpos_index",), raw["qpos"]),
            "qvel": (dims_et + ("qvel_index",), raw["qvel"]),
            "body_pos": (dims_et + ("body", "xyz"), raw["body_pos"]),
            "body_quat": (dims_et + ("body", "wxyz"), raw["body_quat"]),
            "body_parent": (("body",), np.asarray(m.body_parentid, np.int32)),
        }
    )
    if "latent_action" in raw:
        data["latent_action"] = (dims_et + ("latent_unit",), raw["latent_action"])
    if "reference_qpos" in raw:  # an imitation's reference, beside the body's own pose
        data["reference_qpos"] = (dims_et + ("qpos_index",), raw["reference_qpos"])
        data["reference_body_pos"] = (dims_et + ("body", "xyz"), raw["reference_body_pos"])
    for k, v in raw["metrics"].items():
        data[k.replace("/", "_")] = (dims_et, v)
    layers = []
    for k in sorted(raw):
        if k.startswith(model.LAYER_PREFIXES):
            v = np.asarray(raw[k])
            if v.ndim == 2:  # the value output: one unit
                v = v[..., None]
            data[k] = (dims_et + (f"{k}_unit",), v)
            layers.append({"name": k, "units": int(v.shape[-1])})
    return data, obs_labels, layers


def _dataset(run: LoadedRun, raw: dict[str, Any], observation: Any, seed: int, deterministic: bool) -> Any:
    import mujoco
    import xarray as xr

    env, m = run.env, run.env.mj_model
    episodes, steps = raw["reward"].shape
    data, obs_labels, layers = _variables(run, raw, observation)
    behaviour_vars, behaviour_coords, behaviour_attrs = _behaviour(env, raw)
    data.update({k: (dims, v) for k, (dims, v, _) in behaviour_vars.items()})

    def names(obj: Any, n: int) -> list[str]:
        return [mujoco.mj_id2name(m, obj, i) or f"{i}" for i in range(n)]

    ds = xr.Dataset(
        data,
        coords={
            "episode": np.arange(episodes),
            "time": np.arange(steps) * env.dt,
            "observation_feature": obs_labels,
            "actuator": names(mujoco.mjtObj.mjOBJ_ACTUATOR, m.nu),
            "body": names(mujoco.mjtObj.mjOBJ_BODY, m.nbody),
            "xyz": ["x", "y", "z"],
            "wxyz": ["w", "x", "y", "z"],
            "qpos_index": _dof_labels(m, qpos=True),
            "qvel_index": _dof_labels(m, qpos=False),
            **behaviour_coords,
        },
        attrs={
            "title": f"vnl neural recording of {run.config.env}",
            "env": run.config.env,
            "run_dir": os.path.abspath(run.run_dir),  # found again from any working directory
            "env_set": json.dumps(list(run.env_set)),  # the task variant of `--set env_config...`
            "checkpoint_step": int(run.step),
            "control_dt": float(env.dt),
            "deterministic_policy": int(deterministic),
            "seed": int(seed),
            "activation_function": run.config.network.activation,
            "layers": json.dumps(layers),
            "timing": "time t: observation, activity, action and pose in state s_t; reward of s_t -> s_{t+1}",
            "active": "1 up to and including the step at which the episode ended",
            **behaviour_attrs,
        },
    )
    for k, (_, _, var_attrs) in behaviour_vars.items():
        ds[k].attrs.update(var_attrs)
    for k in raw["metrics"]:
        ds[k.replace("/", "_")].attrs["metric"] = k
    for layer in layers:
        name = layer["name"]
        kind = "output layer (raw)" if name.endswith("_output") else "hidden layer after the nonlinearity"
        kind = _LATENT.get(name, kind)
        ds[name].attrs["description"] = kind
    return ds


def _behaviour(env: Any, raw: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """`vnl.recording.behaviour.variables` of the rollout's episode-major host arrays."""
    per_step = ("qpos", "qvel", "body_pos", "body_quat", "active", "done", "mocap_pos", "metrics")
    arrays = {k: raw[k] for k in per_step if k in raw}
    arrays.update({k: raw[k] for k in ("layout_start", "layout_length") if k in raw})
    return behaviour.variables(env, arrays)


def _dof_labels(m: Any, qpos: bool) -> list[str]:
    """One label per qpos (or qvel) coordinate: '<joint>' or '<joint>[k]' for multi-dof joints."""
    import mujoco

    n = m.nq if qpos else m.nv
    adr = m.jnt_qposadr if qpos else m.jnt_dofadr
    labels = [str(i) for i in range(n)]
    for j in range(m.njnt):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
        end = adr[j + 1] if j + 1 < m.njnt else n
        width = end - adr[j]
        for k in range(width):
            labels[adr[j] + k] = name if width == 1 else f"{name}[{k}]"
    return labels
