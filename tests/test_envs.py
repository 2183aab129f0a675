"""Every registered env: jit+vmap reset/step, shapes, no NaN; reward terms recomputed; NaN guard."""

import functools

import jax
import jax.numpy as jp
import mujoco
import numpy as np
import pytest

import vnl

BATCH = 4
STEPS = 200


@functools.cache
def env(name):
    return vnl.make(name)


@functools.cache
def random_rollout(name):
    """(initial state, states after each step, actions) for STEPS random-action steps."""
    e = env(name)

    @jax.jit
    def go(key):
        k0, k1 = jax.random.split(key)
        s0 = jax.vmap(e.reset)(jax.random.split(k0, BATCH))
        actions = jax.random.uniform(k1, (STEPS, BATCH, e.action_size), minval=-1, maxval=1)

        def body(s, a):
            nxt = jax.vmap(e.step)(s, a)
            return nxt, nxt

        _, traj = jax.lax.scan(body, s0, actions)
        return s0, traj, actions

    return jax.device_get(go(jax.random.PRNGKey(0)))


@pytest.mark.parametrize("name", vnl.names())
def test_reset_step_shapes_and_finiteness(name):
    e = env(name)
    s0, traj, _ = random_rollout(name)
    assert s0.obs.shape == (BATCH, e.observation_size)
    assert traj.obs.shape == (STEPS, BATCH, e.observation_size)
    assert traj.reward.shape == (STEPS, BATCH) and traj.done.shape == (STEPS, BATCH)
    assert np.isfinite(traj.obs).all() and np.isfinite(traj.reward).all()
    for k, v in traj.metrics.items():
        assert np.isfinite(v).all(), k
    assert traj.obs.dtype == np.float32
    # The dynamics move: observations are not constant over time.
    assert np.abs(traj.obs[-1] - traj.obs[0]).max() > 1e-3


@pytest.mark.parametrize("name", vnl.names())
def test_reward_terms_match_independent_recomputation(name):
    e = env(name)
    cfg = e.config
    m = e.mj_model
    s0, traj, actions = random_rollout(name)
    root = e.root_body_id
    # The subtree of the root body is every body below it: check subtree_com is the
    # mass-weighted mean of those bodies' centres of mass (the notebooks read the wrong body).
    subtree = [b for b in range(m.nbody) if _is_descendant(m, b, root)]
    mass = m.body_mass[subtree]
    t = 10
    xipos = traj.data.xipos[t, 0][subtree]
    com = (mass[:, None] * xipos).sum(0) / mass.sum()
    np.testing.assert_allclose(traj.data.subtree_com[t, 0, root], com, atol=1e-4)

    prev_com = np.concatenate([s0.data.subtree_com[None, :, root], traj.data.subtree_com[:-1, :, root]])
    vx = (traj.data.subtree_com[:, :, root, 0] - prev_com[..., 0]) / e.dt
    z = traj.data.xpos[:, :, root, 2]
    up = traj.data.xmat[:, :, root, 2, 2]
    healthy = (z >= cfg.healthy_z_range[0]) & (z <= cfg.healthy_z_range[1]) & (up >= cfg.healthy_min_upright)
    a = np.clip(actions, m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1])
    np.testing.assert_allclose(traj.metrics["reward/forward"], cfg.forward_reward_weight * vx, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(traj.metrics["reward/healthy"], cfg.healthy_reward * healthy)
    np.testing.assert_allclose(traj.metrics["reward/ctrl_cost"], -cfg.ctrl_cost_weight * (a**2).sum(-1), rtol=1e-5)
    total = sum(traj.metrics[f"reward/{k}"] for k in ("forward", "healthy", "ctrl_cost"))
    np.testing.assert_allclose(traj.reward, total, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(traj.done, 1.0 - healthy)  # terminate_when_unhealthy


def _is_descendant(m, body, root):
    while body != 0:
        if body == root:
            return True
        body = m.body_parentid[body]
    return root == 0


def test_humanoid_observation_is_the_notebooks_layout():
    e = env("humanoid_run")
    s0, traj, _ = random_rollout("humanoid_run")
    d = traj.data
    m = e.mj_model
    nb = m.nbody - 1
    t, b = 5, 1
    expected = np.concatenate(
        [
            d.qpos[t, b, 2:],
            d.qvel[t, b],
            d._impl.cinert[t, b, 1:].ravel(),
            d.cvel[t, b, 1:].ravel(),
            d.qfrc_actuator[t, b],
        ]
    )
    np.testing.assert_allclose(traj.obs[t, b], expected, rtol=1e-6)
    assert e.observation_size == (m.nq - 2) + m.nv + nb * 10 + nb * 6 + m.nv == 336
    layout = e.observation_layout()
    assert [n for n, _ in layout][0] == "qpos[2:]"
    assert sum(w for _, w in layout) == e.observation_size


def test_bodies_resolved_by_name():
    e = env("ant_run")
    assert e.mj_model.body(e.root_body_id).name == "walker/torso"
    h = env("humanoid_run")
    assert h.mj_model.body(h.root_body_id).name == "torso"


def test_bad_actions_never_reach_physics():
    e = env("ant_run")
    s = jax.jit(e.reset)(jax.random.PRNGKey(1))
    step = jax.jit(e.step)
    for bad in (jp.full((e.action_size,), jp.nan), jp.full((e.action_size,), 1e9), jp.full((e.action_size,), -jp.inf)):
        n = step(s, bad)
        assert np.isfinite(n.obs).all() and np.isfinite(n.reward)
        assert np.abs(np.asarray(n.data.ctrl)).max() <= 1.0
        assert float(n.metrics["physics_nan"]) == 0.0


def test_physics_blow_up_ends_episode_without_nan():
    e = env("ant_run")
    s = jax.jit(e.reset)(jax.random.PRNGKey(3))
    # A finite but absurd velocity overflows float32 within the step: the guard must catch it.
    huge = s.replace(data=s.data.replace(qvel=s.data.qvel.at[:].set(1e30)))
    n = jax.jit(e.step)(huge, jp.zeros(e.action_size))
    assert float(n.metrics["physics_nan"]) == 1.0
    assert float(n.done) == 1.0
    assert float(n.reward) == 0.0
    assert np.isfinite(np.asarray(n.obs)).all()
    assert np.isfinite(np.asarray(n.data.qpos)).all()


def test_ant_contacts_and_rest_height():
    """The ant stands on the floor at rest (no sinking) with the compiled solver settings."""
    e = env("ant_run")
    m = e.mj_model
    d = mujoco.MjData(m)
    for _ in range(int(2.0 / m.opt.timestep)):
        mujoco.mj_step(m, d)
    z = d.xpos[e.root_body_id, 2]
    assert 0.3 < z < 0.45, z  # torso sphere r=0.25 plus legs; fell through would be < 0.25
