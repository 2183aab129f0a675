"""Warm starts: a new run that begins with another run's networks (`vnl train ENV --init-from RUN_DIR`).

The new run takes the parent checkpoint's policy and value parameters and its observation
normalizer (and with `init.keep_optimizer` its Adam state); everything else starts fresh — its
own env (any env config, or another env with the same observation and action layout), seed, env
states and step count, which starts at 0. Its config.yaml records the parent (`init.run`), the
checkpoint step used (`init.step`) and the hash of the parent's config (`init.config_hash`), so
`vnl plot --lineage` can draw the parent's curve followed by the child's.

The networks must be the same: unless the user sets `network.*`, the child takes the parent's
network section (`parent_defaults`); any difference in sizes is one `VnlError` naming them,
before anything compiles.

A new sensor: the child's observation may add entries to the parent's (e.g. `ground_scan` in
the corridor after learning to run on the floor) when every entry of the parent's layout (name
and width, `Env.observation_layout`) is in the child's, in the same order. The first layers of the
policy and value networks get zero weights from the new inputs, and the normalizer treats them
as mean 0, standard deviation 1 with the parent's sample count (so their statistics barely move:
suited to inputs of order 1), so the child begins computing exactly the parent's functions and
learns what the new inputs are worth. Not with `--vision` or `--keep-optimizer`.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

import numpy as np

from vnl import typed_config as config_lib
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.train.config import TrainConfig, read_config
from vnl.train.worlds import trained_config

PARAMS = ".training.params."
NORMALIZER = ".training.normalizer_params."
OPTIMIZER = ".training.optimizer_state"


@dataclasses.dataclass
class Parent:
    """The checkpoint a warm start begins from.

    Attributes:
      run_dir: the parent run directory (absolute).
      step: the checkpoint's step.
      config: the parent's TrainConfig.
      arrays: the checkpoint's training state, `.training.*` arrays only (named as in
        `PPOLoop.to_arrays`).
      input_rows: set by `check_layout` when the child's observation adds entries: for each of
        the child's inputs, shape (child width,), the parent's input index or -1 for a new one.
      new_inputs: the added entries, as "name (width)".
      layout: the (name, width) blocks of the observation the parent's networks read, as its
        checkpoint recorded them (None for checkpoints written before vnl recorded them).
    """

    run_dir: Path
    step: int
    config: TrainConfig
    arrays: dict[str, np.ndarray]
    input_rows: np.ndarray | None = None  # a grown observation: each input's parent index, -1 if new
    new_inputs: tuple[str, ...] = ()
    layout: list[tuple[str, int]] | None = None

    def observation_layout(self) -> list[tuple[str, int]]:
        """The parent's observation blocks: as recorded, else from its env (built for this)."""
        if self.layout is not None:
            return self.layout
        return trained_config(self.config, self.run_dir, self.step).make_env().observation_layout()

    @property
    def config_hash(self) -> str:
        return config_hash(self.config)

    def sizes(self) -> tuple[int, int]:
        """(observation width, action size) the parent's networks take and give: the
        normalizer's width (of `state` for vision runs) and half the policy's output (Brax's
        `tanh_normal` policy outputs a location and a scale per action; a `normal` one, the
        location alone, from `Dense_0`)."""
        mean = [v for k, v in self.arrays.items() if k.startswith(NORMALIZER + "mean")]
        width = int(mean[0].shape[-1]) if len(mean) == 1 else -1
        location = self.arrays.get(".training.params.policy['params']['Dense_0']['bias']")
        if location is not None:  # network.distribution_type normal: a location per action
            return width, int(location.shape[-1])
        head = self.arrays.get(".training.params.policy['params']['output']['bias']")
        if head is None:  # the intention network's head (vnl.ppo.intention)
            head = self.arrays.get(".training.params.policy['params']['policy_head']['bias']")
        if head is not None:  # a recurrent core's head: a location (and with tanh_normal a scale) per action
            scale_param = any("['std_" in k for k in self.arrays if k.startswith(".training.params.policy"))
            return width, int(head.shape[-1]) // (1 if scale_param else 2)
        outputs = [
            (int(m.group(1)), v)
            for k, v in self.arrays.items()
            if (m := re.fullmatch(r"\.training\.params\.policy\['params'\]\['hidden_(\d+)'\]\['bias'\]", k))
        ]
        actions = int(max(outputs, key=lambda kv: kv[0])[1].shape[-1]) // 2 if outputs else -1
        return width, actions


def config_hash(config: TrainConfig) -> str:
    """A short hash of a run's config without its `log` section (what a resume may change)."""
    return config.content_hash()


def parent_defaults(run_dir: str | Path) -> dict[str, Any]:
    """The config values a child inherits unless it sets them: the parent's network and whether
    it normalizes observations (`vnl.train.config.build` takes them as file values below the
    user's own)."""
    parent = read_config(run_dir)
    return {
        "network": config_lib.to_dict(parent.network),
        "ppo": {"normalize_observations": parent.ppo.normalize_observations},
    }


def load_parent(config: TrainConfig) -> Parent:
    """Reads the checkpoint `config.init` names; `VnlError` when the run or step is missing or
    unreadable, when the parent's config is not the one `init.config_hash` recorded (a config
    copied from a warm-started run), or when the parent's networks differ from `config`'s."""
    init = config.init
    if init.run is None:
        raise VnlError("no parent run: set init.run (--init-from RUN_DIR)")
    run_dir = Path(init.run).absolute()
    parent_config = read_config(run_dir)
    if init.config_hash is not None and init.config_hash != config_hash(parent_config):
        raise VnlError(
            f"init.config_hash is {init.config_hash}, but the config of {run_dir} now hashes to "
            f"{config_hash(parent_config)}: it is not the parent this config was made with (changed since, or "
            "another run of that name); drop init.config_hash to start from it as it is"
        )
    step, arrays, meta = checkpoint.load_train_state(run_dir, init.step)
    arrays = {k: v for k, v in arrays.items() if k.startswith(".training.")}
    recorded_layout = meta.get("observation_layout")
    layout = [(str(n), int(w)) for n, w in recorded_layout] if isinstance(recorded_layout, list) else None
    parent = Parent(run_dir, step, parent_config, arrays, layout=layout)
    _check_networks(parent, config)
    return parent


def _check_networks(parent: Parent, config: TrainConfig) -> None:
    a, b = parent.config, config
    fields = ("policy_hidden_layer_sizes", "value_hidden_layer_sizes", "activation", "distribution_type", "core")
    fields += ("architecture",)
    if b.network.core is not None:
        fields += ("core_size",)
    if b.network.architecture == "merel":
        fields += ("encoder_hidden_layer_sizes", "policy_core_sizes")
        if b.vision.enabled:
            fields += ("resnet_channels", "resnet_blocks", "resnet_features")
    if b.network.architecture == "intention":
        fields += ("encoder_hidden_layer_sizes", "intention_size")
    if b.network.distribution_type == "normal":
        fields += ("noise_std_type",)
    if b.vision.enabled:
        fields += ("cnn_channels", "cnn_kernel_sizes", "cnn_strides", "cnn_max_pool", "cnn_pool")
    differ = [f for f in fields if getattr(a.network, f) != getattr(b.network, f)]
    if differ:
        net_a, net_b = a.network, b.network
        detail = "; ".join(f"network.{f} {_show(getattr(net_a, f))} vs {_show(getattr(net_b, f))}" for f in differ)
        raise VnlError(
            f"cannot start from {parent.run_dir} (step {parent.step:,}): its networks differ from this run's "
            f"({detail}); drop the network overrides (a warm start takes the parent's networks)"
        )
    if a.ppo.normalize_observations != b.ppo.normalize_observations:
        raise VnlError(
            f"cannot start from {parent.run_dir}: ppo.normalize_observations is {a.ppo.normalize_observations} "
            f"there and {b.ppo.normalize_observations} here"
        )
    if a.vision.enabled != b.vision.enabled:
        raise VnlError(
            f"cannot start from {parent.run_dir}: it was trained {'with' if a.vision.enabled else 'without'} "
            f"--vision and this run is {'with' if b.vision.enabled else 'without'} it"
        )


def _show(value: Any) -> str:
    return str(list(value)) if isinstance(value, tuple) else str(value)


def check_layout(parent: Parent, env: Any, env_name: str) -> Parent:
    """`parent`, with `input_rows` set when `env`'s observation adds entries to the parent's;
    `VnlError` naming the sizes when the layouts differ otherwise (checked from shapes and
    layouts; nothing is compiled)."""
    width, actions = parent.sizes()
    size = env.observation_size
    own = int(size["state"][-1]) if isinstance(size, dict) else int(size)
    if (width, actions) == (own, env.action_size):
        return parent
    mismatch = VnlError(
        f"cannot start from {parent.run_dir} (step {parent.step:,}, env {parent.config.env}): its networks take "
        f"observations of width {width} and give {actions} actions, but {env_name} has observations of width "
        f"{own} and {env.action_size} actions; --init-from needs the same observation and action layout "
        f"(or the parent's observation with entries added)"
    )
    if actions != env.action_size or own < width or isinstance(size, dict):
        raise mismatch
    if parent.config.network.architecture == "intention":
        raise VnlError(
            f"cannot start from {parent.run_dir}: its intention network's encoder and decoder read fixed columns of "
            f"its observation (width {width}), and {env_name}'s has width {own}; --init-from needs the same observation"
        )
    rows, new = grown_inputs(parent.observation_layout(), env.observation_layout())
    if rows is None or int((rows >= 0).sum()) != width:
        raise mismatch
    return dataclasses.replace(parent, input_rows=rows, new_inputs=tuple(new))


def grown_inputs(theirs: list[tuple[str, int]], ours: list[tuple[str, int]]) -> tuple[np.ndarray | None, list[str]]:
    """Maps our observation's inputs to theirs when ours adds entries to theirs: (for each of our
    inputs, shape (our width,), its index in theirs or -1 for an added one; the added entries as
    "name (width)"), or (None, []) when theirs is not ours with entries added."""
    rows: list[int] = []
    new: list[str] = []
    k, offset = 0, 0
    for name, n in ours:
        if k < len(theirs) and theirs[k] == (name, n):
            rows += range(offset, offset + n)
            offset, k = offset + n, k + 1
        else:
            rows += [-1] * n
            new.append(f"{name} ({n})")
    if k < len(theirs):
        return None, []
    return np.asarray(rows, dtype=np.int64), new


def recorded(config: TrainConfig, parent: Parent) -> TrainConfig:
    """`config` with the parent recorded: its absolute path, the step used and its config hash."""
    init = dataclasses.replace(config.init, run=str(parent.run_dir), step=parent.step, config_hash=parent.config_hash)
    return dataclasses.replace(config, init=init)


def apply(loop: Any, state: Any, parent: Parent, keep_optimizer: bool) -> Any:
    """`state` (a fresh `LoopState` of `loop`) with the parent's params and normalizer (and Adam
    state with `keep_optimizer`); the env step count stays 0. With a grown observation
    (`parent.input_rows`), the first layers' and the normalizer's arrays are widened (`_widen`).

    Raises `VnlError` naming the arrays whose shapes differ (the layouts were checked before, so
    this catches anything else, e.g. a different optimizer chain with `keep_optimizer`).
    """
    import jax

    if keep_optimizer and parent.input_rows is not None:
        raise VnlError(
            f"cannot keep the optimizer of {parent.run_dir}: this run's observation adds "
            f"{', '.join(parent.new_inputs)}, and the parent's Adam moments have no entries for them; "
            "drop --keep-optimizer"
        )
    training = loop.training(state)
    paths, treedef = jax.tree_util.tree_flatten_with_path(training)
    prefixes = taken(loop.config, parent.config, keep_optimizer)
    leaves, bad = [], []
    for path, leaf in paths:
        name = ".training" + jax.tree_util.keystr(path)
        if not name.startswith(prefixes):
            leaves.append(leaf)
            continue
        theirs = parent.arrays.get(name)
        if theirs is not None and parent.input_rows is not None:
            theirs = _widen(name, theirs, parent)
        if theirs is None or theirs.shape != np.shape(leaf) or theirs.dtype != np.asarray(leaf).dtype:
            bad.append(f"{name[len('.training.') :]} {None if theirs is None else theirs.shape} vs {np.shape(leaf)}")
            leaves.append(leaf)
        else:
            leaves.append(theirs)
    if bad:
        raise VnlError(
            f"cannot start from {parent.run_dir} (step {parent.step:,}): the saved training state does not fit "
            f"this run ({'; '.join(bad[:3])}{' ...' if len(bad) > 3 else ''})"
        )
    return loop.with_training(state, jax.tree_util.tree_unflatten(treedef, leaves))


def taken(child: TrainConfig, parent: TrainConfig, keep_optimizer: bool) -> tuple[str, ...]:
    """The training-state arrays (path prefixes) a child takes from its parent. A SAC child
    (`algorithm: sac`) takes a PPO parent's policy and normalizer (a PPO value network is not a Q
    network: its Q networks start fresh), a SAC parent's Q and target Q networks too."""
    if child.algorithm != "sac":
        return (PARAMS, NORMALIZER) + ((OPTIMIZER,) if keep_optimizer else ())
    if parent.algorithm == "sac":
        return (PARAMS, NORMALIZER, ".training.target_q")
    return (PARAMS + "policy", NORMALIZER)


# A `normal` policy's MLP sits under MLP_0 (Brax's PolicyModuleWithStd), a recurrent network's
# under encoder (vnl.ppo.recurrent).
FIRST_KERNEL = re.compile(
    r"\.training\.params\.(policy|value)\['params'\](\['MLP_0'\]|\['encoder'\])?\['hidden_0'\]\['kernel'\]"
)


def _widen(name: str, theirs: np.ndarray, parent: Parent) -> np.ndarray:
    """The parent's array for the child's wider observation: the first layers' kernels, shape
    (parent width, units) -> (child width, units), get zero rows for the new inputs; the
    normalizer's per-input arrays, shape (parent width,) -> (child width,), mean 0, std 1 and a
    summed variance of `count` (a variance of 1) there. Other arrays are returned as they are."""
    rows = parent.input_rows
    assert rows is not None
    old = rows >= 0
    field = name[len(NORMALIZER) :] if name.startswith(NORMALIZER) else None
    if FIRST_KERNEL.fullmatch(name):
        grown = np.zeros((len(rows),) + theirs.shape[1:], theirs.dtype)
    elif field in ("mean", "std", "summed_variance"):
        count = float(parent.arrays[NORMALIZER + "count.hi"]) * 2.0**32 + float(parent.arrays[NORMALIZER + "count.lo"])
        fill = {"mean": 0.0, "std": 1.0, "summed_variance": count}[field]
        grown = np.full((len(rows),) + theirs.shape[1:], fill, theirs.dtype)
    else:
        return theirs
    grown[old] = theirs[rows[old]]
    return grown


def check_lineage(run_dirs: list[str | Path]) -> None:
    """Warns for each parent in the lineage of `run_dirs` (`vnl.io.plot.lineage`, what `vnl plot
    --lineage` draws) whose config is not the one its child started from (its hash differs from
    the child's `init.config_hash`): it was changed since, or the run found by its name next to
    the child is another one. Parents whose config this vnl cannot read are not compared."""
    import warnings

    from vnl.io import plot

    for run_dir in run_dirs:
        chain = plot.lineage(run_dir)
        for (parent, _), (child, _) in zip(chain, chain[1:], strict=False):
            init = config_lib.load_yaml(str(child / "config.yaml"), "config.yaml of the run").get("init") or {}
            recorded = init.get("config_hash")
            try:
                actual = config_hash(read_config(parent))
            except VnlError:
                continue
            if recorded and actual != recorded:
                warnings.warn(
                    f"{parent} is drawn as the parent of {child}, but its config (hash {actual}) is not the one "
                    f"{child.name} started from (hash {recorded}): it was changed since, or it is another run of "
                    "that name",
                    stacklevel=2,
                )


def planned(config: TrainConfig) -> TrainConfig:
    """`config` with the parent recorded as `recorded` will record it, read from the parent's
    config.yaml and checkpoint names alone (no arrays loaded): its absolute path, the step
    (`init.step`, else the newest checkpoint) and its config hash. For `--print-config`."""
    init = config.init
    if init.run is None:
        return config
    run_dir = Path(init.run).absolute()
    parent_config = read_config(run_dir)
    available = checkpoint.steps(run_dir)
    step = init.step if init.step is not None else (available[-1] if available else None)
    if step is None:
        raise VnlError(f"no checkpoint in {checkpoint.checkpoint_dir(run_dir)} to start from")
    init = dataclasses.replace(init, run=str(run_dir), step=step, config_hash=config_hash(parent_config))
    return dataclasses.replace(config, init=init)
