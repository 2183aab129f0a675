"""Every registered env: jit+vmap reset/step, shapes, no NaN; reward terms recomputed; NaN guard."""

import copy
import functools

import jax
import jax.numpy as jp
import mujoco
import numpy as np
import pytest
from dm_control import mjcf
from mujoco import mjx

import vnl
from vnl import physics
from vnl.arenas import bowl, gaps
from vnl.envs import registry
from vnl.errors import VnlError
from vnl.tasks.run import Run

# Each distinct registered env (aliases such as `run` share `rodent_run`'s defaults) is compiled
# once per test module: one jitted rollout of `steps(name, impl)` random-action control steps, vmapped over a
# few envs; the last env of the batch gets zero actions.
# Brax's ant and humanoid (`brax_*_run`, for comparing physics backends) run the same Run task
# code as ant_run/humanoid_run; test_robustness and benchmarks/backend_throughput.py cover them.
# Suites (ant_suite, rodent_suite) are their members' worlds, each rolled out here under its own
# name; test_suite.py covers the suites.
NAMES = [n for n in vnl.names() if n not in registry.ALIASES and not n.startswith("brax_") and not registry.is_suite(n)]
RUN_NAMES = [n for n in NAMES if registry.entry(n).factory is Run]
STEPS = 1000
# The rat on MJX: 200 steps (4 s). Its 1000-step rollouts took 290-340 s each in a full suite on a
# 2-core machine, and CI's suite came close to its limit; at 400 steps 134-240 s (a full suite here,
# 2026-11-28), of which rodent_run's program took 25-30 s to trace and 65-70 s to compile (97 s in
# all at 100 steps, 122 s at 400), and 2-5 s to run; at 200 steps rodent_run's test took 141 s and
# rodent_run_gaps's 170 s (231 at 400). The blow-ups these tests caught came within 132 steps;
# searching for rarer ones is benchmarks' work (docs/experiments/rat-imitate.md).
RAT_MJX_STEPS = 200


def steps(name, impl="jax"):
    """The length of `name`'s random rollout on physics `impl`."""
    return RAT_MJX_STEPS if impl == "jax" and name.startswith("rodent") else STEPS


FIELDS = (
    "time",
    "qpos",
    "qvel",
    "act",
    "qacc_warmstart",
    "mocap_pos",
    "xpos",
    "xmat",
    "xipos",
    "subtree_com",
    "site_xpos",
    "geom_xpos",
    "geom_xmat",
    "ctrl",
    "cvel",
    "qfrc_actuator",
)


def _pick(data):
    """The FIELDS of the physics data (plus `cinert`) as a dict."""
    return {**{f: getattr(data, f) for f in FIELDS}, "cinert": physics.cinert(data)}


def by_env(names, impls=("jax",)):
    """(name, impl) parameters grouped per env and physics for pytest-xdist (`--dist loadgroup`):
    one compile per worker. MuJoCo C physics (impl c) compiles nothing of MuJoCo: cheap to add, and
    in the fast tier; MJX (impl jax) compiles the world's physics, minutes for the rat: slow."""
    return [
        pytest.param(
            n,
            i,
            marks=[pytest.mark.xdist_group(n if i == "jax" else f"{n}-{i}")]
            + ([pytest.mark.slow] if i == "jax" else []),
            id=f"{n}-{i}",
        )
        for n in names
        for i in impls
    ]


BOTH = ("jax", "c")


def batch_size(name):
    return 2 if name.startswith("rodent") else 4


def env(name, impl="jax"):
    return _env(name, impl)  # one cache key for env(n) and env(n, "jax")


@functools.cache
def _env(name, impl):
    return vnl.make(name, impl=impl)


def random_rollout(name, impl="jax"):
    """(initial state, per-step outputs, actions) for STEPS steps; per-step `data` holds FIELDS.
    Cached per (name, impl): `random_rollout(n)` and `random_rollout(n, "jax")` share one compile
    (functools.cache keys them apart, which compiled every MJX rat rollout twice)."""
    return _random_rollout(name, impl)


@functools.cache
def _random_rollout(name, impl):
    e = env(name, impl)
    b = batch_size(name)

    @jax.jit
    def go(key):
        resets, k1 = rollout_keys(name, key)
        s0 = jax.vmap(e.reset)(resets)
        actions = jax.random.uniform(k1, (steps(name, impl), b, e.action_size), minval=-1, maxval=1)
        actions = actions.at[:, -1].set(0.0)

        def body(s, a):
            nxt = jax.vmap(e.step)(s, a)
            out = nxt.replace(data=_pick(nxt.data))
            return nxt, out

        _, traj = jax.lax.scan(body, s0, actions)
        return s0.replace(data=_pick(s0.data)), traj, actions

    return jax.device_get(go(jax.random.PRNGKey(ROLLOUT_SEED)))


ROLLOUT_SEED = 0


def rollout_keys(name, key):
    """(reset keys, shape (batch_size(name), 2); the actions' key) that `random_rollout` draws from
    `key` (`jax.random.PRNGKey(ROLLOUT_SEED)`)."""
    k0, k1 = jax.random.split(key)
    return jax.random.split(k0, batch_size(name)), k1


@pytest.mark.usefixtures("point_envs")
def test_the_tiny_test_env_resets_and_steps_on_c_physics():
    """tests/tiny_env.py's point mass (the env the training tests use): a jitted reset and steps
    pushing towards its target move it there and earn more (less negative) reward."""
    e = registry.make("test_point", impl="c")
    s = jax.jit(e.reset)(jax.random.PRNGKey(0))
    assert s.obs.shape == (e.observation_size,) == (2,)
    step = jax.jit(e.step)
    first = step(s, jp.ones(1))
    for _ in range(20):
        s = step(s, jp.ones(1))
    assert float(s.data.qpos[0]) > float(first.data.qpos[0]) and float(s.reward) > float(first.reward)


SEED_ENVS = ["ant_run", "ant_run_gaps", "ant_escape_bowl", "rodent_run", "rodent_run_gaps", "rodent_escape_bowl"]


@pytest.mark.parametrize("name,impl", by_env(SEED_ENVS + ["humanoid_run"], ("c",)))
def test_the_default_video_camera_frames_the_animal(name, impl):
    """`vnl train`'s final video and `vnl render` without --camera: the animal at the reset state
    spans 30-90% of the image's width or height (the rat's `walker/side` camera showed it at a
    tenth of the height). Measured on MuJoCo's segmentation render: the walker's geoms' pixels."""
    import mujoco

    from vnl.io import video

    e = env(name, impl)
    m = e.mj_model
    s = jax.jit(e.reset)(jax.random.PRNGKey(0))
    d = mujoco.MjData(m)
    d.qpos[:] = np.asarray(s.data.qpos)
    d.mocap_pos[:] = np.asarray(s.data.mocap_pos)
    mujoco.mj_forward(m, d)
    mine = [g for g in range(m.ngeom) if e._is_in_subtree(m, int(m.geom_bodyid[g]), e.root_body_id)]
    try:
        r = mujoco.Renderer(m, 240, 320)
    except Exception as err:  # noqa: BLE001
        pytest.skip(f"no OpenGL: {err}")
    r.enable_segmentation_rendering()
    r.update_scene(d, camera=video.resolve_camera(m, None))
    seg = r.render()
    r.close()
    ys, xs = np.nonzero(np.isin(seg[..., 0], mine) & (seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM))
    assert len(ys), f"{name}: the default camera does not see the animal"
    height, width = (ys.max() - ys.min() + 1) / 240, (xs.max() - xs.min() + 1) / 320
    assert 0.3 <= max(height, width) <= 0.9, (
        f"{name}: the animal spans {height:.2f} of the height, {width:.2f} of the width"
    )


# A world MJX steps as it steps another's is rolled out on MJX once. rodent_two_touch's physics is
# rodent_run's, the rat on a floor (the orb is a mocap body outside the physics:
# test_mjx_rollouts_left_out_step_the_same_world checks it), and its task code is the same on both
# physics (its C rollout runs it). Its MJX rollout took 222 s on CI (2026-11-28), where the suite
# came within 4 minutes of its limit. (rodent_imitate's is not the same: 8 solver iterations.)
# A variant whose world is another's, model for model (rodent_maze_forage_upright: the maze's task
# code with the fall rules, vnl.tasks.falls, which read the root's orientation): its C rollout runs them.
MJX_SAME_AS = {"rodent_two_touch": "rodent_run"}
# (rodent_run_gaps_vision: the corridor's task code without the ground scan.)
MJX_SAME_MODEL = {"rodent_maze_forage_upright": "rodent_maze_forage", "rodent_run_gaps_vision": "rodent_run_gaps"}


@pytest.mark.parametrize(
    "name,impl",
    [p for p in by_env(NAMES, BOTH) if not (p.values[1] == "jax" and p.values[0] in MJX_SAME_AS | MJX_SAME_MODEL)],
)
def test_reset_step_shapes_and_finiteness(name, impl):
    e = env(name, impl)
    b = batch_size(name)
    s0, traj, _ = random_rollout(name, impl)
    assert s0.obs.shape == (b, e.observation_size)
    n = steps(name, impl)
    assert traj.obs.shape == (n, b, e.observation_size)
    assert traj.reward.shape == (n, b) and traj.done.shape == (n, b)
    assert np.isfinite(traj.obs).all() and np.isfinite(traj.reward).all()
    for k, v in traj.metrics.items():
        assert np.isfinite(v).all(), k
    assert traj.obs.dtype == np.float32
    # No blow-ups. (The MJX rat in the gaps corridor blew up here after 132 steps while MJX's
    # broad-phase cull dropped its foot contacts: test_mjx_corridor_finds_every_contact_mujoco_c_finds.)
    assert traj.metrics["physics_nan"].sum() == 0
    # The dynamics move: observations are not constant over time.
    assert np.abs(traj.obs[-1] - traj.obs[0]).max() > 1e-3
    # Reward terms are logged and sum to the reward.
    terms = [k for k in traj.metrics if k.startswith("reward/")]
    assert terms
    np.testing.assert_allclose(sum(traj.metrics[k] for k in terms), traj.reward, rtol=1e-5, atol=1e-5)
    assert sum(w for _, w in e.observation_layout()) == e.observation_size


@pytest.mark.parametrize("name", sorted(MJX_SAME_MODEL))
def test_mjx_rollouts_left_out_compile_the_same_model(name):
    """The variant's compiled MuJoCo model is byte for byte the one whose MJX rollout stands for it."""
    import mujoco

    def saved(m):
        buffer = np.zeros(mujoco.mj_sizeModel(m), np.uint8)
        mujoco.mj_saveModel(m, None, buffer)
        return buffer.tobytes()

    assert saved(env(name, "c").mj_model) == saved(env(MJX_SAME_MODEL[name], "c").mj_model)


@pytest.mark.parametrize("name", sorted(MJX_SAME_AS))
def test_mjx_rollouts_left_out_step_the_same_world(name):
    """What MJX collides and integrates is the same in `name`'s world as in the world whose MJX
    rollout stands for it: the same bodies that are not mocap (mass, inertia, pose), joints (range,
    stiffness, damping), actuators (gains), colliding geoms (type, size, pose, friction, margin,
    solref, condim), the same options; and no geom of a mocap body collides."""
    import mujoco

    a, b = env(name, "c").mj_model, env(MJX_SAME_AS[name], "c").mj_model

    def size(m, g):  # a plane collides as an infinite plane: its size is how it is drawn
        return () if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE else tuple(np.round(m.geom_size[g], 6))

    def world(m):
        bodies = [i for i in range(m.nbody) if m.body_mocapid[i] < 0]
        geoms = [g for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]]
        mocap = [g for g in geoms if m.body_mocapid[m.geom_bodyid[g]] >= 0]
        assert not mocap, f"{name}: mocap bodies' geoms collide: {[m.geom(g).name for g in mocap]}"
        r = lambda v: tuple(np.round(np.asarray(v, float).ravel(), 6))  # noqa: E731
        return (
            [
                (m.body(i).name, r(m.body_mass[i]), r(m.body_inertia[i]), r(m.body_pos[i]), r(m.body_quat[i]))
                for i in bodies
            ],  # fmt: skip
            [
                (m.joint(j).name, r(m.jnt_range[j]), r(m.jnt_stiffness[j]), r(m.dof_damping[m.jnt_dofadr[j]]))
                for j in range(m.njnt)
            ],  # fmt: skip
            [(m.actuator(u).name, r(m.actuator_gainprm[u]), r(m.actuator_biasprm[u])) for u in range(m.nu)],
            [
                (
                    m.geom(g).name,
                    int(m.geom_type[g]),
                    *size(m, g),
                    *np.round(m.geom_pos[g], 6),
                    *np.round(m.geom_friction[g], 6),
                    r(m.geom_margin[g]),
                    r(m.geom_solref[g]),
                    int(m.geom_condim[g]),
                )
                for g in geoms
            ],  # fmt: skip
            (m.opt.timestep, m.opt.iterations, m.opt.ls_iterations, int(m.opt.solver), int(m.opt.cone)),
        )

    for mine, theirs, what in zip(
        world(a), world(b), ("bodies", "joints", "actuators", "geoms", "options"), strict=True
    ):
        assert mine == theirs, f"{name}'s {what} differ from {MJX_SAME_AS[name]}'s: roll it out on MJX again"


@pytest.mark.slow
@pytest.mark.parametrize("name,impl", by_env(RUN_NAMES, BOTH))
def test_reward_terms_match_independent_recomputation(name, impl):
    e = env(name, impl)
    cfg = e.config
    m = e.mj_model
    s0, traj, actions = random_rollout(name, impl)
    root = e.root_body_id
    # The subtree of the root body is every body below it: check subtree_com is the
    # mass-weighted mean of those bodies' centres of mass (the notebooks read the wrong body).
    subtree = [b for b in range(m.nbody) if _is_descendant(m, b, root)]
    mass = m.body_mass[subtree]
    t = 10
    xipos = traj.data["xipos"][t, 0][subtree]
    com = (mass[:, None] * xipos).sum(0) / mass.sum()
    np.testing.assert_allclose(traj.data["subtree_com"][t, 0, root], com, atol=1e-4)

    com_traj = traj.data["subtree_com"]
    prev_com = np.concatenate([s0.data["subtree_com"][None, :, root], com_traj[:-1, :, root]])
    vx = (com_traj[:, :, root, 0] - prev_com[..., 0]) / e.dt
    z = traj.data["xpos"][:, :, root, 2]
    up = traj.data["xmat"][:, :, root, 2, 2]
    healthy = (z >= cfg.healthy_z_range[0]) & (z <= cfg.healthy_z_range[1]) & (up >= cfg.healthy_min_upright)
    a = np.clip(actions, m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1])
    paid = vx if cfg.forward_velocity_cap is None else np.minimum(vx, cfg.forward_velocity_cap)  # humanoid_run's cap
    np.testing.assert_allclose(traj.metrics["reward/forward"], cfg.forward_reward_weight * paid, rtol=1e-4, atol=1e-4)
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


@pytest.mark.slow
@pytest.mark.xdist_group("humanoid_run")
def test_humanoid_observation_is_the_notebooks_layout():
    e = env("humanoid_run")
    s0, traj, _ = random_rollout("humanoid_run")
    d = traj.data
    m = e.mj_model
    nb = m.nbody - 1
    t, b = 5, 1
    expected = np.concatenate(
        [
            d["qpos"][t, b, 2:],
            d["qvel"][t, b],
            d["cinert"][t, b, 1:].ravel(),
            d["cvel"][t, b, 1:].ravel(),
            d["qfrc_actuator"][t, b],
        ]
    )
    np.testing.assert_allclose(traj.obs[t, b], expected, rtol=1e-6)
    assert e.observation_size == (m.nq - 2) + m.nv + nb * 10 + nb * 6 + m.nv == 336
    layout = e.observation_layout()
    assert [n for n, _ in layout][0] == "qpos[2:]"
    assert sum(w for _, w in layout) == e.observation_size


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run")
def test_bodies_resolved_by_name():
    e = env("ant_run")
    assert e.mj_model.body(e.root_body_id).name == "walker/torso"
    h = env("humanoid_run")
    assert h.mj_model.body(h.root_body_id).name == "torso"


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run")
def test_bad_actions_never_reach_physics():
    e = env("ant_run")
    s = jax.jit(e.reset)(jax.random.PRNGKey(1))
    step = jax.jit(e.step)
    for bad in (jp.full((e.action_size,), jp.nan), jp.full((e.action_size,), 1e9), jp.full((e.action_size,), -jp.inf)):
        n = step(s, bad)
        assert np.isfinite(n.obs).all() and np.isfinite(n.reward)
        assert np.abs(np.asarray(n.data.ctrl)).max() <= 1.0
        assert float(n.metrics["physics_nan"]) == 0.0


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run")
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


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run")
def test_ant_contacts_and_rest_height():
    """The ant stands on the floor at rest (no sinking) with the compiled solver settings."""
    e = env("ant_run")
    m = e.mj_model
    d = mujoco.MjData(m)
    for _ in range(int(2.0 / m.opt.timestep)):
        mujoco.mj_step(m, d)
    z = d.xpos[e.root_body_id, 2]
    assert 0.3 < z < 0.45, z  # torso sphere r=0.25 plus legs; fell through would be < 0.25


# --- the rodent and the new arenas ------------------------------------------------------------


def _mj_data(e, traj, t, b):
    """MuJoCo C data at the state after step t of env b (qpos, qvel, act, mocap), forwarded."""
    m = e.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = traj.data["qpos"][t, b]
    d.qvel[:] = traj.data["qvel"][t, b]
    if m.na:
        d.act[:] = traj.data["act"][t, b]
    if m.nmocap:
        d.mocap_pos[:] = traj.data["mocap_pos"][t, b]
    d.ctrl[:] = traj.data["ctrl"][t, b]
    mujoco.mj_forward(m, d)
    mujoco.mj_subtreeVel(m, d)
    return d


SAMPLE_T = (0, 1, 10, 50, 99, 150, 300, RAT_MJX_STEPS - 1, STEPS - 1)


def sample_t(name, impl="jax"):
    """The SAMPLE_T within `name`'s rollout on `impl`."""
    return [t for t in SAMPLE_T if t < steps(name, impl)]


@pytest.mark.slow
@pytest.mark.parametrize("name,impl", by_env(["rodent_run_gaps", "ant_run_gaps"], BOTH))
def test_run_gaps_reward_equals_dm_control_formula(name, impl):
    from dm_control.utils import rewards as dmc_rewards

    e = env(name, impl)
    v = e.config.target_velocity
    _, traj, _ = random_rollout(name, impl)
    for b in range(batch_size(name)):
        for t in sample_t(name, impl):
            d = _mj_data(e, traj, t, b)
            vx = d.subtree_linvel[e.root_body_id, 0]
            expected = dmc_rewards.tolerance(vx, (v, v), margin=v, sigmoid="linear", value_at_margin=0.0)
            # dm_control's termination, an end effector below terminate_at_height, and vnl's additions
            # where the env sets them (the root low, tilted past healthy_min_upright, a foot in a gap).
            c = e.config
            low = d.xpos[e._low_bodies, 2].min() < c.terminate_at_height
            root_low = c.terminate_root_below is not None and d.xpos[e.root_body_id, 2] < c.terminate_root_below
            tilted = c.healthy_min_upright is not None and d.xmat[e.root_body_id][-1] < c.healthy_min_upright
            foot = traj.metrics.get("measure/ended_foot_in_gap", np.zeros_like(traj.reward))[t, b]
            fell = float(low or root_low or tilted or foot)
            assert traj.metrics["fell"][t, b] == fell, (t, b, low, root_low, tilted, foot)
            assert traj.done[t, b] == max(fell, traj.metrics["physics_nan"][t, b])
            # The reward: dm_control's velocity term, plus vnl's healthy bonus while not failed.
            expected += c.healthy_reward * (1.0 - fell)
            assert traj.reward[t, b] == pytest.approx(float(expected), abs=2e-3), (t, b, vx)


@pytest.mark.slow
@pytest.mark.parametrize("name,impl", by_env(["rodent_escape_bowl", "ant_escape_bowl"], BOTH))
def test_escape_reward_equals_dm_control_formula(name, impl):
    from dm_control.utils import rewards as dmc_rewards

    e = env(name, impl)
    m = e.mj_model
    r = e.config.bowl.half_size
    dev = np.cos(np.deg2rad(30))
    _, traj, _ = random_rollout(name, impl)
    rodent = name.startswith("rodent")
    for b in range(batch_size(name)):
        for t in sample_t(name, impl):
            d = _mj_data(e, traj, t, b)
            # dm_control's Escape.get_reward: the rat's head site; other walkers: the root body.
            p = d.site("walker/head").xpos if rodent else d.xpos[e.root_body_id]
            escape = dmc_rewards.tolerance(
                np.linalg.norm(p), (r, float("inf")), margin=r, sigmoid="linear", value_at_margin=0
            )
            zz = [d.xmat[e.root_body_id][-1]] + ([d.body("walker/pelvis").xmat[-1]] if rodent else [])
            upright = np.min(
                dmc_rewards.tolerance(
                    np.array(zz), (dev, float("inf")), sigmoid="linear", margin=1 + dev, value_at_margin=0
                )
            )
            assert traj.reward[t, b] == pytest.approx(float(upright * escape), abs=2e-3), (t, b)
    assert m.hfield_nrow[0] == e.config.bowl.nrow


@pytest.mark.slow
@pytest.mark.xdist_group("rodent_run")
def test_rodent_stands_on_the_floor_with_zero_action():
    """After 2 s of zero action the rat's soles are within a few mm of the floor (no sinking,
    no explosion)."""
    e = env("rodent_run")
    m = e.mj_model
    _, traj, _ = random_rollout("rodent_run")
    t = int(round(2.0 / e.dt)) - 1
    b = batch_size("rodent_run") - 1  # the zero-action env
    bottoms = []
    for g in range(m.ngeom):
        name = m.geom(g).name
        if not (name.startswith(("walker/foot", "walker/toe")) and name.endswith("collision")):
            continue
        radius, half = m.geom_size[g, 0], m.geom_size[g, 1]
        axis_z = traj.data["geom_xmat"][t, b, g].reshape(3, 3)[2, 2]
        bottoms.append(traj.data["geom_xpos"][t, b, g, 2] - half * abs(axis_z) - radius)
    assert len(bottoms) == 8
    assert min(bottoms) == pytest.approx(0.0, abs=0.004), bottoms  # touching, not sunk
    assert traj.data["xpos"][t, b, e.root_body_id, 2] > 0.03  # torso still up
    assert traj.done[: t + 1, b].sum() == 0


@pytest.mark.slow
@pytest.mark.xdist_group("rodent_run_gaps")
def test_gaps_layout_redrawn_per_reset_and_in_the_model():
    from vnl.arenas import gaps

    e = env("rodent_run_gaps")
    s0, traj, _ = random_rollout("rodent_run_gaps")
    mocap = traj.data["mocap_pos"]
    # Different envs (keys) see different platforms around the same spawn point.
    assert np.abs(mocap[0, 0] - mocap[0, 1]).max() > 1e-3
    n = e.corridor.window * e.corridor.pieces
    # Every collidable window box is at the platform height or parked below.
    # Piece k of a platform sits k * PIECE_STEP lower (no coplanar faces, see gaps.build).
    z = mocap[..., :n, 2].reshape(*mocap.shape[:2], e.corridor.window, e.corridor.pieces)
    top = -gaps.THICKNESS - np.arange(e.corridor.pieces) * gaps.PIECE_STEP
    assert (np.isclose(z, top, rtol=0, atol=1e-6) | np.isclose(z, -50.0)).all()
    assert np.isclose(z, top, rtol=0, atol=1e-6).any()


@pytest.mark.slow
@pytest.mark.xdist_group("rodent_run_gaps")
def test_walker_falling_into_a_gap_is_detected():
    """The rat placed over a 0.5 m gap falls in (MuJoCo C) and `failed` says so."""
    from mujoco import mjx

    from vnl.arenas import gaps

    e = env("rodent_run_gaps")
    m = e.mj_model
    p = e.corridor
    n = p.max_platforms
    start = np.full(n, np.inf, np.float32)
    length = np.full(n, 0.6, np.float32)
    start[:5] = [5.0, 5.6, 6.2, 7.3, 7.9]  # 0.6 m platforms, abutting, then a 0.5 m gap (6.8-7.3)
    layout = gaps.Layout(start=jp.asarray(start), length=jp.asarray(length))
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    d.qpos[:3] = (7.05, 0.0, 0.02)
    d.mocap_pos[:] = np.asarray(gaps.place_window(layout, jp.float32(7.05), p))
    mujoco.mj_forward(m, d)
    assert float(e.failed(mjx.put_data(m, d))) == 0.0
    for _ in range(int(1.0 / m.opt.timestep)):
        mujoco.mj_step(m, d)
    assert d.xpos[e.root_body_id, 2] < -0.3
    assert float(e.failed(mjx.put_data(m, d))) == 1.0


def _ant_settled_at(m: mujoco.MjModel, p: gaps.GapsParams, x: float, seconds: float) -> mujoco.MjData:
    """The ant placed at `x` in a corridor with gaps of 0.45 m after 17 and 19.45 m, after
    `seconds` of MuJoCo C with no action."""
    start = np.full(p.max_platforms, np.inf, np.float32)
    length = np.full(p.max_platforms, 2.0, np.float32)
    start[:4], length[0] = [0.0, 15.0, 17.45, 19.9], 15.0
    layout = gaps.Layout(start=jp.asarray(start), length=jp.asarray(length))
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    d.qpos[0] = x
    d.mocap_pos[:] = np.asarray(gaps.place_window(layout, jp.float32(x), p))
    for _ in range(int(seconds / m.opt.timestep)):
        mujoco.mj_step(m, d)
    return d


@pytest.mark.slow
def test_ant_foot_in_a_gap_fails_with_terminate_foot_below():
    """`feet_lowest` is the lowest point of the feet's capsules: an ant settled on a platform (1 s of
    MuJoCo C, no action) rests its feet on the top (z = 0, within the contacts' 5-mm penetration);
    with its front feet over a 0.45-m gap they hang into it, below -0.3 m, a failure with
    `terminate_foot_below=-0.05` and none without it (its feet stay above `terminate_at_height`)."""
    strict = vnl.make("ant_run_gaps", terminate_foot_below=-0.05)
    default = vnl.make("ant_run_gaps", terminate_foot_below=None)  # dm_control's rule alone
    m, p = strict.mj_model, strict.corridor
    seen = {}
    for where, x in (("platform", 16.0), ("gap", 16.5)):  # the front feet reach ~0.65 m ahead
        d = _ant_settled_at(m, p, x, seconds=1.0)
        data = mjx.put_data(m, d)
        seen[where] = float(strict.feet_lowest(data)), float(strict.failed(data)), float(default.failed(data))
    assert -0.005 < seen["platform"][0] <= 0.0 and seen["platform"][1:] == (0.0, 0.0), seen
    assert seen["gap"][0] < -0.3 and seen["gap"][1:] == (1.0, 0.0), seen
    with pytest.raises(VnlError, match="terminate_foot_below"):
        vnl.make("ant_run_gaps", terminate_foot_below=float("inf"))


@pytest.mark.slow
def test_ant_wedged_in_a_gap_fails_with_terminate_root_below():
    """The ant's torso (a sphere of radius 0.25 m) over a 0.45-m gap wedges between the platforms'
    edges with its centre below 0.2 m, where its feet stay above `terminate_at_height`: a failure
    with `terminate_root_below=0.2` (the env's), none without. On a platform it rests at 0.25 m and
    does not fail. (MuJoCo C, 1.5 s; only the torso collides, as when its legs flail in the air.)"""
    results = {}
    for below in (0.2, None):
        e = vnl.make("ant_run_gaps", terminate_root_below=below, terminate_foot_below=None)  # legs pass through
        m, p = copy.deepcopy(e.mj_model), e.corridor
        legs = [
            g for g in range(m.ngeom) if m.geom(g).name.startswith("walker/") and m.geom(g).name != "walker/torso_geom"
        ]
        m.geom_contype[legs] = m.geom_conaffinity[legs] = 0
        for where, x in (("gap", 17.225), ("platform", 16.0)):
            d = _ant_settled_at(m, p, x, seconds=1.5)
            feet = d.xpos[e._low_bodies, 2].min()
            results[below, where] = float(e.failed(mjx.put_data(m, d))), float(d.xpos[e.root_body_id, 2]), feet
    z = {where: torso for (_, where), (_, torso, _) in results.items()}
    assert z["gap"] < 0.2 and 0.24 < z["platform"] < 0.26, results
    assert min(feet for _, _, feet in results.values()) > e.config.terminate_at_height, results
    assert {k: f for k, (f, _, _) in results.items()} == {
        (0.2, "gap"): 1.0,
        (0.2, "platform"): 0.0,
        (None, "gap"): 0.0,
        (None, "platform"): 0.0,
    }, results
    with pytest.raises(VnlError, match="terminate_root_below"):
        vnl.make("ant_run_gaps", terminate_root_below=float("nan"))


@pytest.mark.slow
def test_run_gaps_tilt_check_and_healthy_bonus():
    """`healthy_min_upright` fails a rat tilted past it (60° fails at 45°, 30° does not; neither
    without the check), and `healthy_reward` is paid on every step that does not fail, on top of
    dm_control's velocity term (MuJoCo C)."""
    strict = vnl.make("rodent_run_gaps", impl="c", healthy_min_upright=0.7071, healthy_reward=0.2)
    loose = vnl.make("rodent_run_gaps", impl="c", healthy_min_upright=None)  # dm_control's: no tilt check
    m = strict.mj_model
    state = strict.reset(jax.random.PRNGKey(0))
    failed = {}
    for deg in (30, 60):
        d = mujoco.MjData(m)
        d.qpos[:] = np.asarray(state.data.qpos)
        d.mocap_pos[:] = np.asarray(state.data.mocap_pos)
        half = np.deg2rad(deg) / 2
        d.qpos[3:7] = (np.cos(half), np.sin(half), 0.0, 0.0)  # a roll of `deg` about the body's x
        mujoco.mj_forward(m, d)
        for name, e in (("strict", strict), ("loose", loose)):
            failed[name, deg] = float(e.failed(mjx.put_data(m, d)))
    assert failed == {("strict", 30): 0.0, ("strict", 60): 1.0, ("loose", 30): 0.0, ("loose", 60): 0.0}
    step = jax.jit(strict.step)
    rewards_, velocity, fell = [], [], []
    for t in range(40):
        state = step(state, jp.full((strict.action_size,), 0.3 if t % 10 < 5 else -0.3))
        rewards_.append(float(state.reward))
        velocity.append(float(state.metrics["reward/velocity"]))
        fell.append(float(state.metrics["fell"]))
        if state.done:
            break
    expected = np.asarray(velocity) + 0.2 * (1.0 - np.asarray(fell))
    np.testing.assert_allclose(rewards_, expected, atol=1e-6)
    assert np.asarray(rewards_).min() >= 0.2 - 1e-6 or fell[-1] == 1.0
    for bad in ({"healthy_min_upright": 1.5}, {"healthy_reward": -1.0}):
        with pytest.raises(VnlError, match=next(iter(bad))):
            vnl.make("rodent_run_gaps", impl="c", **bad)
    # One range check for both tasks, each naming how its check is turned off.
    with pytest.raises(VnlError, match=r"healthy_min_upright .*null: no check"):
        vnl.make("rodent_run_gaps", healthy_min_upright=-1.5)
    with pytest.raises(VnlError, match=r"healthy_min_upright .*-1: no check"):
        vnl.make("rodent_run", healthy_min_upright=1.5)


@pytest.mark.slow
@pytest.mark.xdist_group("user_walker")
def test_user_walker_file_errors_name_the_problem(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body name='a'><geom size='0.1'/></worldbody></mujoco>")
    good = tmp_path / "bug.xml"
    good.write_text("<mujoco><worldbody><body name='trunk'><geom size='0.1'/></body></worldbody></mujoco>")
    with pytest.raises(VnlError, match="no such file"):
        vnl.make("run", walker_xml=str(tmp_path / "missing.xml"))
    with pytest.raises(VnlError, match="could not parse"):
        vnl.make("run", walker_xml=str(bad))
    with pytest.raises(VnlError, match="no body named 'torso'.*trunk"):
        vnl.make("run", walker_xml=str(good))


@pytest.mark.slow
@pytest.mark.xdist_group("user_walker")
def test_user_walker_file_runs(tmp_path):
    """A user's MJCF (with its own floor and free joint, both replaced) runs in the run task."""
    xml = tmp_path / "bug.xml"
    xml.write_text(
        """<mujoco model="bug">
          <worldbody>
            <geom name="own_floor" type="plane" size="1 1 0.1"/>
            <body name="trunk" pos="0 0 0.2">
              <freejoint/>
              <geom type="ellipsoid" size="0.1 0.05 0.04"/>
              <body name="leg" pos="0.1 0 0">
                <joint name="hip" type="hinge" axis="0 1 0" range="-1 1"/>
                <geom type="capsule" size="0.02" fromto="0 0 0 0 0 -0.1"/>
              </body>
            </body>
          </worldbody>
          <actuator><motor joint="hip" ctrlrange="-1 1" gear="1"/></actuator>
        </mujoco>"""
    )
    e = vnl.make("run", walker_xml=str(xml), root_body="trunk", episode_length=10, n_substeps=2)
    assert e.walker.name == "bug" and e.action_size == 1
    assert e.mj_model.body(e.root_body_id).name == "walker/trunk"
    s = jax.jit(e.reset)(jax.random.PRNGKey(0))
    s = jax.jit(e.step)(s, jp.ones(1))
    assert np.isfinite(np.asarray(s.obs)).all()
    assert [n for n, _ in e.observation_layout()][:2] == ["joints_pos", "joints_vel"]


@pytest.mark.slow
@pytest.mark.xdist_group("user_walker")
def test_contact_termination_on_a_non_foot_contact():
    """With `contact_termination`, the rat lying on a platform (torso contact) fails; upright on
    its feet it does not. (MuJoCo C state, the env's `failed` evaluated on it.)"""
    from mujoco import mjx

    from vnl.arenas import gaps

    e = vnl.make("rodent_run_gaps", contact_termination=True)
    m = e.mj_model
    layout = gaps.sample_layout(jax.random.PRNGKey(0), e.corridor)
    results = {}
    for pose, quat in (("upright", (1, 0, 0, 0)), ("on_its_back", (0, 1, 0, 0))):
        d = mujoco.MjData(m)
        d.qpos[:] = m.qpos0
        d.qpos[:3] = (5.0, 0.0, e._spawn_z + (0.0 if pose == "upright" else 0.12))
        d.qpos[3:7] = quat
        d.mocap_pos[:] = np.asarray(gaps.place_window(layout, jp.float32(5.0), e.corridor))
        for _ in range(int(0.5 / m.opt.timestep)):
            mujoco.mj_step(m, d)
        results[pose] = float(e.failed(mjx.put_data(m, d)))
    assert results == {"upright": 0.0, "on_its_back": 1.0}


# --- MuJoCo C physics (impl c) against MJX from the same states ---------------------------------
# One control step of C vs MJX from the same mid-episode states of MJX's random-action rollout
# (2-4 envs x 7 times), measured 2026-11-23 (median / max over states): qpos (m or rad), qvel
# difference relative to the state's largest |qvel|, reward difference relative to the rollout's
# largest |reward|:
#   ant_run             0.0009 / 0.014   0.017 / 0.098   0.0014 / 0.018
#   rodent_run          0.0070 / 0.043   0.089 / 1.0     0.0010 / 0.0099
#   rodent_run_gaps     0.0009 / 0.087   0.045 / 1.2     0      / 2e-7
#   rodent_escape_bowl  0.0022 / 0.28    0.11  / 1.0     2e-6   / 2e-4
#   humanoid_run        9e-6   / 0.0098  3e-4  / 0.086   2e-7   / 2e-4
# (rodent_run_gaps's row was measured with MJX's broad-phase cull, which dropped contacts; without
# it, 2026-11-26: 0.00015 / 0.087   0.0044 / 1.24   0 / 2e-6, medians 6-10x closer.)
# The two differ in their contact solvers (MJX's and MuJoCo's Newton with 2-4 iterations, and
# their collision routines); with 50 iterations the rat's differences shrink (qvel median 1.6% ->
# 1.3%, max 20% -> 10% from C's states). A random-action rat kicking against joint limits and the
# floor is the worst case. Tolerances: medians at ~2-3x, maxima at ~2x the measured values.
MEDIAN_TOL = (0.02, 0.25, 0.01)
MAX_TOL = (0.6, 2.5, 0.05)


@pytest.mark.parametrize(
    "name,impl", by_env(["ant_run", "rodent_run", "rodent_run_gaps", "rodent_escape_bowl", "humanoid_run"])
)
@pytest.mark.slow
def test_c_and_mjx_agree_from_the_same_states(name, impl):
    """One control step of MuJoCo C from states of MJX's rollout (mid-episode: feet on the floor,
    on the gaps' moving platforms, on the bowl's heightfield) lands where MJX's next step did,
    within the tolerances above (docs/experiments/physics-on-cpu.md)."""
    ec = env(name, "c")
    s0, traj, actions = random_rollout(name)
    ts = np.asarray([t for t in sample_t(name) if t + 1 < steps(name)])
    at = lambda tree, t: jax.tree.map(lambda x: x[t], tree)  # noqa: E731
    keep = ("time", "qpos", "qvel", "act", "qacc_warmstart", "mocap_pos")
    states = at(traj, ts)  # (T, B, ...)
    data = jax.jit(jax.vmap(jax.vmap(lambda f: ec.forward(ec.make_data(**f)))))(
        {k: jp.asarray(states.data[k]) for k in keep}
    )
    nxt = jax.device_get(jax.jit(jax.vmap(jax.vmap(ec.step)))(states.replace(data=data), actions[ts + 1]))
    ref = at(traj, ts + 1)
    ok = (ref.metrics["physics_nan"] == 0) & (ref.done == 0) & (states.done == 0)
    assert ok.sum() >= 8
    dq = np.abs(nxt.data.qpos - ref.data["qpos"]).max(-1)[ok]
    dv = (np.abs(nxt.data.qvel - ref.data["qvel"]).max(-1) / np.maximum(1, np.abs(ref.data["qvel"]).max(-1)))[ok]
    dr = np.abs(nxt.reward - ref.reward)[ok] / max(1.0, float(np.abs(traj.reward).max()))
    measured = [(float(np.median(x)), float(x.max())) for x in (dq, dv, dr)]
    print(name, "median/max of qpos, qvel (rel), reward (rel) differences:", measured)
    for (median, worst), median_tol, max_tol in zip(measured, MEDIAN_TOL, MAX_TOL, strict=True):
        assert median < median_tol and worst < max_tol, measured


@pytest.mark.slow
@pytest.mark.parametrize("name,impl", by_env(["rodent_run_gaps", "ant_run_gaps"]))
def test_mjx_corridor_finds_every_contact_mujoco_c_finds(name, impl):
    """Every walker geom that MuJoCo C finds penetrating the platforms (by more than 1 mm), MJX
    finds in contact with them too, in every other state of the random rollout (2,000 of the ant's,
    200 of the rat's). (Per geom, not per pair: a platform is 2 overlapping boxes and abuts the
    next, and where a geom touches two, C and MJX's capsule-box routines may report different ones
    of them.) MJX's broad-phase cull (`corridor.max_geom_pairs`, 16 until 2026-11-26) ranks pairs by
    bounding spheres, and a platform's holds the whole walker: it dropped penetrating contacts of the
    rat in 11% of states (benchmarks/mjx_broadphase.py), and the rat blew up."""
    e = env(name, impl)
    m = e.mj_model
    _, traj, _ = random_rollout(name, impl)
    qpos = traj.data["qpos"][::2].reshape(-1, m.nq)
    mocap = traj.data["mocap_pos"][::2].reshape(-1, m.nmocap, 3)

    @jax.jit
    @jax.vmap
    def collide(q, mp):
        d = mjx.make_data(m).replace(qpos=q, mocap_pos=mp)
        d = mjx.collision(e.mjx_model, mjx.kinematics(e.mjx_model, d))
        return d._impl.contact.geom, d._impl.contact.dist

    geoms, dists = jax.device_get(collide(jp.asarray(qpos), jp.asarray(mocap)))
    name_of = lambda g: mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or ""  # noqa: E731
    walker = {g for g in range(m.ngeom) if name_of(g).startswith("walker/")}
    touching = lambda pairs: {int(g) for pair in pairs for g in pair if int(g) in walker}  # noqa: E731
    d = mujoco.MjData(m)
    checked = 0
    for q, mp, g, dist in zip(qpos, mocap, geoms, dists, strict=True):
        d.qpos[:], d.mocap_pos[:] = q, mp
        mujoco.mj_forward(m, d)
        deep = touching((c.geom1, c.geom2) for c in d.contact[: d.ncon] if c.dist < -1e-3)
        found = touching(pair for pair, x in zip(g, dist, strict=True) if x < 0)
        assert deep <= found, [name_of(i) for i in deep - found]
        checked += len(deep)
    assert checked >= 50  # the walker was on the platforms


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run_gaps-c")
def test_the_ant_observes_the_corridors_direction_and_its_offset_from_the_centre_line():
    """`observe_corridor` (ant_run_gaps' default): the last 4 observations are the world x-axis in
    the root's frame and y / half-width; turned 90° left and moved 1.25 m to the left, they read
    (0, -1, 0) and 0.5. The rat's corridor (dm_control's observation) does not have them."""
    env = vnl.make("ant_run_gaps", impl="c", ground_scan=())  # the corridor last, without the ground scan
    assert env.observation_layout()[-1] == ("corridor", 4)
    assert "corridor" not in dict(vnl.make("rodent_run_gaps", impl="c", observe_corridor=False).observation_layout())
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    assert np.allclose(state.obs[-4:-1], [1.0, 0.0, 0.0], atol=0.05) and abs(float(state.obs[-1])) < 0.01
    i = env._free_qpos
    quat = jp.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # yaw +90°
    qpos = state.data.qpos.at[i + 1].set(1.25).at[i + 3 : i + 7].set(quat)
    state = state.replace(data=env.forward(state.data.replace(qpos=qpos, qvel=jp.zeros_like(state.data.qvel))))
    state = jax.jit(env.step)(state, jp.zeros(env.action_size))
    assert np.allclose(state.obs[-4:-1], [0.0, -1.0, 0.0], atol=0.05)
    assert float(state.obs[-1]) == pytest.approx(0.5, abs=0.02)
    assert state.obs.shape == (env.observation_size,)


@pytest.mark.slow
def test_ground_scan_reads_platforms_and_gaps_ahead_from_the_episodes_layout():
    """`ground_scan`: 1 where the corridor floor d metres ahead of the root is a platform, 0 over a
    gap or past the corridor's end; checked against the layout's (start, end) intervals at 601
    distances, after reset and after a step (the root moved)."""
    scan = tuple(float(d) for d in np.arange(0.0, 30.0, 0.05)) + (200.0,)
    env = vnl.make("ant_run_gaps", impl="c", ground_scan=scan)
    assert env.observation_layout()[-2:] == [("corridor", 4), ("ground_ahead", len(scan))]
    first = jax.jit(env.reset)(jax.random.PRNGKey(3))
    intervals = gaps.layout_numpy(first.info["layout"])
    for state in (first, jax.jit(env.step)(first, jp.zeros(env.action_size))):
        x = float(state.data.xpos[env._root, 0]) + np.asarray(scan, np.float32)
        expected = [any(a <= p <= b for a, b in intervals) for p in x]
        got = np.asarray(state.obs[-len(scan) :])
        assert set(np.unique(got)) == {0.0, 1.0} and got[-1] == 0.0
        close = [min(abs(p - e) for a, b in intervals for e in (a, b)) < 1e-4 for p in x]  # float32 edges
        assert all(g == e for g, e, c in zip(got, expected, close, strict=True) if not c)
    with pytest.raises(VnlError, match="ground_scan"):
        vnl.make("ant_run_gaps", ground_scan=(float("nan"),))


@pytest.mark.slow
def test_terrain_scan_reads_the_bowls_height_under_points_around_the_walker():
    """`terrain_scan`: the root's height above the ground at (forward, left) points in its heading
    frame, checked against MuJoCo's own ray cast down onto the arena alone (`mj_ray`) with the walker
    placed at five positions and headings: the bowl's floor, its slopes, its rim and off the
    heightfield (the ground plane). Bilinear against MuJoCo's triangles on the rat's 201-point grid
    (6-cm cells): within 1 cm, median 1 mm; where the ground plane is the ground, within 2 mm."""
    scan = tuple((float(a), float(b)) for a in (-0.2, 0.0, 0.2, 0.4) for b in (-0.2, 0.0, 0.2))
    env = vnl.make("ant_escape_bowl", impl="c", terrain_scan=scan, bowl={"nrow": 201})
    assert env.observation_layout()[-1] == ("terrain", len(scan))
    params = env._config.bowl
    model = mjcf.Physics.from_mjcf_model(bowl.build(params)).model.ptr
    bowl.write_terrain(model, params)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)

    def ground(x: float, y: float) -> float:
        hit = mujoco.mj_ray(
            model, data, np.array([x, y, 3.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, np.zeros(1, np.int32)
        )
        return 3.0 - hit

    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    errors, rim = [], []
    for x, y, yaw in ((0.0, 0.0, 0.0), (2.5, -1.0, 0.7), (-3.3, 2.1, 2.5), (5.9, 0.3, -1.2), (7.0, 7.0, 0.0)):
        pose = jp.array([x, y, 1.0, np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
        placed = env.forward(state.data.replace(qpos=state.data.qpos.at[:7].set(pose)))
        got = np.asarray(env._obs(placed)[-len(scan) :])
        root = np.asarray(placed.xpos[env._root])
        forward, left = np.array([np.cos(yaw), np.sin(yaw)]), np.array([-np.sin(yaw), np.cos(yaw)])
        expected = [root[2] - ground(*(root[:2] + a * forward + b * left)) for a, b in scan]
        error = list(np.abs(got - expected))
        errors += error
        rim += error if x > 5.5 else []
    assert max(errors) < 0.01 and np.median(errors) < 0.001
    assert max(rim) < 0.002  # at and past the rim the ground plane, 1 cm above the heightfield's base
    with pytest.raises(VnlError, match="terrain_scan"):
        vnl.make("ant_escape_bowl", terrain_scan=((0.1, float("nan")),))


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run-c")
def test_forward_velocity_cap_clips_the_forward_reward_only():
    """With `forward_velocity_cap` c the forward term is w·min(v_x, c): steps faster than c earn
    w·c, slower ones (and backward) their own v_x; the x_velocity metric stays uncapped."""
    cap = 0.05
    e = vnl.make("ant_run", impl="c", forward_velocity_cap=cap)
    w = e.config.forward_reward_weight

    @jax.jit
    def rollout(key):
        s = jax.vmap(e.reset)(jax.random.split(key, 4))
        actions = jax.random.uniform(key, (60, 4, e.action_size), minval=-1.0, maxval=1.0)
        return jax.lax.scan(lambda s, a: (jax.vmap(e.step)(s, a),) * 2, s, actions)[1]

    traj = rollout(jax.random.PRNGKey(3))
    vx = np.asarray(traj.metrics["x_velocity"])
    alive = np.asarray(traj.metrics["physics_nan"]) == 0
    assert (vx[alive] > cap).any() and (vx[alive] < cap).any()  # both sides of the cap are exercised
    np.testing.assert_allclose(traj.metrics["reward/forward"], w * np.minimum(vx, cap), rtol=1e-5, atol=1e-6)
    with pytest.raises(vnl.VnlError, match="forward_velocity_cap"):
        vnl.make("ant_run", impl="c", forward_velocity_cap=-1.0)


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run-c")
def test_the_clock_is_the_phase_of_the_episode_s_time_and_restarts_with_each_episode():
    """`clock_period` T appends (sin, cos)(2π t / T), t the episode's time: (0, 1) at reset, the
    phase of k control steps after k steps, (0, 1) again after an episode ends (auto-reset, as in
    training). The other walker tasks append it too; off by default."""
    from vnl.envs.wrappers import wrap_for_training

    period = 0.35
    env = vnl.make("ant_run", impl="c", clock_period=period)
    assert env.observation_layout()[-1] == ("clock", 2)
    plain = vnl.make("ant_run", impl="c")
    assert "clock" not in dict(plain.observation_layout())
    assert env.observation_size == plain.observation_size + 2
    episode = 5
    train_env = wrap_for_training(env, episode_length=episode)
    state = jax.jit(train_env.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    step = jax.jit(train_env.step)
    action = jp.zeros((2, env.action_size))
    np.testing.assert_allclose(state.obs[:, -2:], [[0.0, 1.0]] * 2, atol=1e-6)
    for k in range(1, episode + 2):
        state = step(state, action)
        t = (k % episode) * env.dt  # the episode's 5th step ends it: the next state is the reset's
        expected = [np.sin(2 * np.pi * t / period), np.cos(2 * np.pi * t / period)]
        np.testing.assert_allclose(state.obs[:, -2:], [expected] * 2, atol=1e-5)
    for name in ("ant_run_gaps", "ant_escape_bowl"):
        other = vnl.make(name, impl="c", clock_period=period)
        first = jax.jit(other.reset)(jax.random.PRNGKey(0))
        assert other.observation_layout()[-1] == ("clock", 2)
        assert sum(w for _, w in other.observation_layout()) == other.observation_size == first.obs.shape[0]
        np.testing.assert_allclose(first.obs[-2:], [0.0, 1.0], atol=1e-6)
    with pytest.raises(VnlError, match="clock_period must be at least two control steps"):
        vnl.make("ant_run", clock_period=env.dt)


@pytest.mark.slow
@pytest.mark.xdist_group("rodent_run-c")
def test_the_rat_observes_its_heading_and_the_ant_can():
    """`observe_heading` (rodent_run's default): `heading` is the world x-axis (the rewarded
    direction) in the root's frame: (1, 0, 0) at reset; after a step from a pose turned 90° left
    it points (0, -1) in the horizontal, turned round (-1, 0). Off by default elsewhere; with the
    state observation too (the ant)."""
    env = vnl.make("rodent_run", impl="c")
    layout = env.observation_layout()
    assert layout[-1] == ("heading", 3) and sum(w for _, w in layout) == env.observation_size
    start = sum(w for _, w in layout[:-1])
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    assert np.allclose(state.obs[start:], [1.0, 0.0, 0.0], atol=0.05)
    i, step = env._free_qpos, jax.jit(env.step)
    for yaw, expected in ((np.pi / 2, [0.0, -1.0, 0.0]), (np.pi, [-1.0, 0.0, 0.0])):
        quat = jp.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
        turned = state.data.replace(qpos=state.data.qpos.at[i + 3 : i + 7].set(quat))
        moved = step(state.replace(data=env.forward(turned)), jp.zeros(env.action_size))
        heading = np.asarray(moved.obs[start:])  # a unit vector; the step's zero action tilts the rat a little
        assert np.linalg.norm(heading) == pytest.approx(1.0, abs=1e-4) and abs(heading[2]) < 0.15, heading
        assert np.allclose(heading[:2] / np.linalg.norm(heading[:2]), expected[:2], atol=0.02), heading
    blind = vnl.make("rodent_run", impl="c", observe_heading=False)
    assert "heading" not in dict(blind.observation_layout())
    assert blind.observation_size == env.observation_size - 3
    ant = vnl.make("ant_run", impl="c", observe_heading=True, clock_period=0.5)
    assert ant.observation_layout()[-2:] == [("heading", 3), ("clock", 2)]
    first = jax.jit(ant.reset)(jax.random.PRNGKey(1))
    assert first.obs.shape == (ant.observation_size,) and np.allclose(first.obs[-5:-2], [1, 0, 0], atol=0.05)
    # The corridor and the bowl put it right after the proprioception (a rodent_run parent's layout
    # stays a prefix, so `--init-from` a running rat works); off by default there.
    for name in ("ant_run_gaps", "ant_escape_bowl"):
        plain, other = vnl.make(name, impl="c"), vnl.make(name, impl="c", observe_heading=True)
        at = len(other.proprioception_layout())
        assert other.observation_layout()[at] == ("heading", 3) and "heading" not in dict(plain.observation_layout())
        assert other.observation_layout()[:at] + other.observation_layout()[at + 1 :] == plain.observation_layout()
        s0 = jax.jit(other.reset)(jax.random.PRNGKey(2))
        start = sum(w for _, w in other.observation_layout()[:at])
        assert s0.obs.shape == (other.observation_size,)
        np.testing.assert_allclose(s0.obs[start : start + 3], s0.data.xmat[other._root][0], atol=1e-6)


@pytest.mark.slow
@pytest.mark.xdist_group("rodent_run-c")
def test_foot_slip_cost_charges_a_sliding_stance_foot_and_nothing_else():
    """`foot_slip_cost_weight`: a settled rat slid 1 cm sideways over one 20-ms control step moves
    each of its feet's geoms on the floor at 0.5 m/s, and pays weight x 0.5 x their number; lifted
    2 cm as well, no geom is in stance and it pays nothing. The step logs the term; off by default."""
    w = 2.0
    e = vnl.make("rodent_run", impl="c", foot_slip_cost_weight=w)
    s = jax.jit(e.reset)(jax.random.PRNGKey(0))
    step = jax.jit(e.step)
    for _ in range(25):  # settle on the floor at zero action
        s = step(s, jp.zeros(e.action_size))
    data0 = s.data
    moved = lambda dx, dz: e.forward(e.make_data(qpos=data0.qpos.at[0].add(dx).at[2].add(dz)))  # noqa: E731
    stance = int((np.asarray(e._slip_feet.lowest(data0)) < e.config.foot_contact_height).sum())
    assert stance >= 4  # feet and hands on the floor
    np.testing.assert_allclose(float(e.foot_slip(data0, moved(0.0, 0.0))), 0.0, atol=1e-6)
    np.testing.assert_allclose(float(e.foot_slip(data0, moved(0.01, 0.0))), 0.5 * stance, rtol=1e-3)
    assert float(e.foot_slip(data0, moved(0.01, 0.02))) == 0.0
    nxt = step(s, jp.zeros(e.action_size))
    np.testing.assert_allclose(float(nxt.metrics["reward/foot_slip"]), -w * float(nxt.metrics["foot_slip"]), rtol=1e-6)
    terms = sum(float(v) for k, v in nxt.metrics.items() if k.startswith("reward/"))
    np.testing.assert_allclose(terms, float(nxt.reward), rtol=1e-5, atol=1e-6)
    assert "reward/foot_slip" not in env("rodent_run", "c").reset(jax.random.PRNGKey(0)).metrics
    with pytest.raises(VnlError, match="foot_slip_cost_weight"):
        vnl.make("rodent_run", impl="c", foot_slip_cost_weight=-1.0)


@pytest.mark.slow
def test_bowl_slope_profile_smooth_peaks_at_the_formula_and_bumps_steepen_it():
    smooth = bowl.slope_profile(bowl.BowlParams(smoothness=1.0))
    expected = np.degrees(np.arctan(np.pi * 0.5 / 6.0))  # 14.7°: dh/dr of 0.5·(1 - cos(2πr/6))/2
    assert max(r.p90_deg for r in smooth) == pytest.approx(expected, abs=0.3)
    steepest = max(smooth, key=lambda r: r.median_deg)
    assert steepest.inner in (1.0, 1.5, 4.0, 4.5)  # around a quarter and three quarters of the radius
    assert all(r.steeper_than_15 == 0 for r in smooth)
    assert smooth[0].median_deg < 1.0  # the flat floor inside the clipped radius (0.6 m)
    bumpy = bowl.slope_profile(bowl.BowlParams())  # dm_control's: smoothness 0.5
    ridge = [r for r in bumpy if 2.0 <= r.inner < 4.0]
    assert min(r.median_deg for r in ridge) > 20.0  # ~27-30° on the ridge
    assert [r.outer for r in bumpy][-1] == 6.0 and len(bumpy) == 12
    with pytest.raises(VnlError, match="ring"):
        bowl.slope_profile(bowl.BowlParams(), ring=0.0)


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run-c")
def test_incline_tilts_gravity_so_the_floor_rises_along_x():
    flat, tilted = env("ant_run", "c"), vnl.make("ant_run", impl="c", incline=20.0)  # flat: the shared one
    g = 9.81
    assert np.asarray(flat._mj_model.opt.gravity) == pytest.approx([0, 0, -g])
    t = np.radians(20.0)
    assert np.asarray(tilted._mj_model.opt.gravity) == pytest.approx([-g * np.sin(t), 0, -g * np.cos(t)], rel=1e-6)
    for e, ax in ((flat, 0.0), (tilted, -g * np.sin(t))):
        state = jax.jit(e.reset)(jax.random.PRNGKey(0))
        qpos = state.data.qpos.at[2].set(3.0)  # in the air: nothing but gravity acts on the root
        data = e.forward(state.data.replace(qpos=qpos, qvel=jp.zeros_like(state.data.qvel)))
        state = jax.jit(e.step)(state.replace(data=data), jp.zeros(e.action_size))
        assert float(state.data.qvel[0]) == pytest.approx(ax * e.dt, abs=1e-3)  # falling down the slope
    with pytest.raises(vnl.VnlError, match="incline"):
        vnl.make("ant_run", incline=50.0)
    mjx_tilted = vnl.make("ant_run", impl="jax", incline=20.0)  # MJX's model is put after the tilt
    assert np.asarray(mjx_tilted._mjx_model.opt.gravity) == pytest.approx([-g * np.sin(t), 0, -g * np.cos(t)], rel=1e-6)
