"""Freezes Brax's `ppo.train` on the test point env as the reference of
tests/test_research.py::test_loop_matches_brax_ppo_train.

brax 0.14.2's `ppo.train` calls `jax.device_put_replicated` (removed in jax 0.10), so it only runs
on the old stack (jax 0.8.2, Python 3.11) and with the tree it was made from (commit 2f09e3d, where
`vnl.train.ppo.brax_kwargs` built ppo.train's arguments). It was run once, from that tree's root:

    .venv/bin/python tests/data/make_brax_ppo_reference.py

and is kept as the record of how the reference was made; it does not run on today's tree.

It writes, for desired_kl None and 0.01, tests/data/brax_ppo_reference_<none|kl0.01>.npz:
`leaf_<i>` the final params' leaves in `jax.tree.leaves` order of (normalizer, policy, value),
`steps` and `eval_episode_reward` of each evaluation, and for the KL case `learning_rate` (the
final `training/learning_rate`); and brax_ppo_reference_versions.json with the package versions.
The settings are the test's (`cfg`, SETTINGS, K).
"""

import importlib.metadata
import json
import sys
from pathlib import Path

import jax
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # tests/: tiny_env and test_research

import test_research  # noqa: E402  (the test's settings: cfg, K)
import tiny_env  # noqa: E402
from brax.training.agents.ppo import train as brax_ppo  # noqa: E402

from vnl.envs import registry  # noqa: E402
from vnl.train import ppo  # noqa: E402

CASES = {"none": None, "kl0.01": 0.01}


def name(tag: str) -> Path:
    return HERE / f"brax_ppo_reference_{tag}.npz"


def main() -> None:
    tiny_env.register()
    for tag, desired_kl in CASES.items():
        config = test_research.cfg(desired_kl=desired_kl)
        env = registry.entry("test_point").factory(config.resolved_env_config())
        records = []
        _, params, _ = brax_ppo.train(
            environment=env,
            progress_fn=lambda s, m: records.append((s, m)),  # noqa: B023
            **ppo.brax_kwargs(config),
        )
        arrays = {f"leaf_{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(params))}
        arrays["steps"] = np.asarray([s for s, _ in records], np.int64)
        arrays["eval_episode_reward"] = np.asarray([m["eval/episode_reward"] for _, m in records], np.float32)
        if desired_kl is not None:
            arrays["learning_rate"] = np.asarray(records[-1][1]["training/learning_rate"], np.float32)
        np.savez_compressed(name(tag), **arrays)
        print(f"{name(tag).name}: steps {arrays['steps'].tolist()}, {len(jax.tree.leaves(params))} leaves")
    packages = ["jax", "jaxlib", "brax", "flax", "optax", "mujoco", "mujoco-mjx"]
    versions = {p: importlib.metadata.version(p) for p in packages}
    versions["python"] = sys.version.split()[0]
    versions["backend"] = jax.default_backend()
    (HERE / "brax_ppo_reference_versions.json").write_text(json.dumps(versions, indent=1) + "\n")
    tiny_env.unregister()


if __name__ == "__main__":
    main()
