"""A run's policy entropy as SAC's temperature loss measures it (`vnl.ppo.sac.make_alpha_loss`):
the mean -log-probability of an action sampled from the policy (tanh included), in nats, on the
observations of the run's own recorded episodes (`vnl.record.record`, the deterministic policy);
what to pass as `sac.target_entropy` when a SAC run warm-starts from it (docs/how-to/sac.md).

    .venv/bin/python benchmarks/policy_entropy.py RUN_DIR [--step S] [--episodes 4] [--steps 200]
"""

from __future__ import annotations

import argparse
import types

import jax
import jax.numpy as jp


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--step", type=int, help="a checkpoint step (default: the last)")
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--steps", type=int, default=200, help="control steps per episode at most")
    args = parser.parse_args()

    from vnl import record
    from vnl.policy import load_run
    from vnl.ppo.networks import make_network
    from vnl.ppo.sac import make_alpha_loss

    run = load_run(args.run, step=args.step)
    if run.config.network.core or run.config.network.architecture != "brax":
        raise SystemExit("policy_entropy.py reads feed-forward policies (network.architecture brax, no core)")
    ds = record.record(run, episodes=args.episodes, steps=args.steps)
    obs = jp.asarray(ds["observation"].values.reshape(-1, ds["observation"].shape[-1]))
    network = make_network(run.config, run.env)
    normalizer, policy, _ = run.params
    # SAC's own temperature loss measures it (its second output); the target does not enter the entropy.
    batch = types.SimpleNamespace(observation=obs)
    _, entropy = make_alpha_loss(network, 0.0)(jp.zeros(()), policy, normalizer, batch, jax.random.PRNGKey(0))
    entropy = float(entropy)
    print(
        f"{run.run_dir} step {run.step:,}: entropy {entropy:.1f} nats over {obs.shape[0]:,} observations "
        f"({run.env.action_size} actions; Brax's SAC target: {-0.5 * run.env.action_size:.1f})"
    )


if __name__ == "__main__":
    main()
