"""Memory of one vision PPO training step, from XLA's compiled memory analysis (nothing is run).

The notebooks flattened their camera image into a 230,427-wide float32 observation; their XLA
dump showed f32[32,64,5,230427] buffers (8.79 GiB: 32 minibatches x batch 64 x unroll 5), which
ran the GPU out of memory. This compiles vnl's training epoch (one training step) at those batch
settings for

  - `pixels`: the env with `vision` on, 64x64 RGB uint8 `pixels/<camera>` next to `state`,
    Brax's vision networks (NatureCNN by default);
  - `flat`: the same env, blind, with its observation padded to 230,427 float32 values (the
    notebooks' layout) and Brax's MLP networks;

and prints XLA's argument / output / temporary sizes, and the rollout's observation buffer
(batch x minibatches x unroll observations). The environments are never stepped: shapes come
from `jax.eval_shape`, so this runs in a few minutes on a CPU and the numbers are the compiler's,
for this backend (a GPU compile differs in detail).

    .venv/bin/python benchmarks/vision_memory.py [--env ant_run_gaps] [--num-envs 2048]
"""

from __future__ import annotations

import argparse
import platform
import time

import jax
import jax.numpy as jp
import numpy as np

from vnl.ppo.loop import PPOLoop
from vnl.tasks.contract import Env, State
from vnl.train import config as train_config

GIB = 2**30


class FlatPadded(Env):
    """`env` with its flat observation zero-padded to `width` float32 values."""

    def __init__(self, env: Env, width: int) -> None:
        self.inner, self.width = env, width
        self._config, self._mj_model, self._mjx_model = env.config, env.mj_model, env.mjx_model
        self._n_substeps = env.n_substeps

    def _pad(self, state: State) -> State:
        return state.replace(obs=jp.pad(state.obs, (0, self.width - state.obs.shape[-1])))

    def reset(self, rng: jax.Array) -> State:
        return self._pad(self.inner.reset(rng))

    def step(self, state: State, action: jax.Array) -> State:
        return self._pad(self.inner.step(state.replace(obs=state.obs[: self.inner.observation_size]), action))


def analyse(env: Env, config: train_config.TrainConfig) -> dict[str, float]:
    """Compiled memory of one training step of `env` under `config`, in bytes."""
    loop = PPOLoop(env, config, training_steps_per_epoch=1)
    n = loop.n_devices
    key = jax.ShapeDtypeStruct((n, 2), jp.uint32)
    keys = jax.ShapeDtypeStruct((n, loop.local_envs // n, 2), jp.uint32)
    env_state = jax.eval_shape(jax.vmap(loop.env.reset), keys)
    training = jax.eval_shape(loop.init_training, jax.random.PRNGKey(0))
    training = jax.tree.map(lambda x: jax.ShapeDtypeStruct((n, *x.shape), x.dtype), training)
    t = time.perf_counter()
    compiled = loop._epoch.lower(training, env_state, key).compile()
    stats = compiled.memory_analysis()
    obs = jax.tree.leaves(jax.eval_shape(env.reset, jax.ShapeDtypeStruct((2,), jp.uint32)).obs)
    per_obs = sum(int(np.prod(x.shape)) * x.dtype.itemsize for x in obs)
    p = config.ppo
    return {
        "obs_bytes": per_obs,
        "rollout_obs": per_obs * p.batch_size * p.num_minibatches * p.unroll_length,
        "argument": stats.argument_size_in_bytes,
        "output": stats.output_size_in_bytes,
        "temp": stats.temp_size_in_bytes,
        "compile_s": time.perf_counter() - t,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="ant_run_gaps")
    parser.add_argument("--num-envs", type=int, default=2048)
    parser.add_argument("--flat-width", type=int, default=230_427)
    args = parser.parse_args()
    ppo = {
        "num_envs": args.num_envs,
        "batch_size": 64,
        "num_minibatches": 32,
        "unroll_length": 5,
        "num_updates_per_batch": 8,
    }
    rows = []
    pixels = train_config.build(args.env, "gpu", file_values={"ppo": ppo, "vision": {"enabled": True}})
    rows.append(("pixels 64x64x3 uint8 + state", analyse(pixels.make_env(), pixels)))
    blind = train_config.build(args.env, "gpu", file_values={"ppo": ppo})
    rows.append((f"flat {args.flat_width:,} float32", analyse(FlatPadded(blind.make_env(), args.flat_width), blind)))

    print(f"\n{args.env}, one training step: {args.num_envs} envs, batch 64 x 32 minibatches x unroll 5, 8 updates")
    print(f"{jax.default_backend()} ({platform.processor() or platform.machine()}), jax {jax.__version__}\n")
    print(
        "| observation | bytes/obs | rollout observations (GiB) | XLA arguments (GiB) | XLA temporaries (GiB) "
        "| arguments + temporaries vs flat |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    flat = rows[-1][1]["argument"] + rows[-1][1]["temp"]
    for name, r in rows:
        total = r["argument"] + r["temp"]
        print(
            f"| {name} | {r['obs_bytes']:,} | {r['rollout_obs'] / GIB:.3f} | {r['argument'] / GIB:.3f} "
            f"| {r['temp'] / GIB:.3f} | {total / flat:.3f} |"
        )


if __name__ == "__main__":
    main()
