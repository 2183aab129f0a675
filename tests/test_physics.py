"""MuJoCo C physics (`impl: c`): the FFI bridge, equality with MuJoCo's own stepping, parity with
MJX, the NaN guard, threads, per-env model fields and the compilation cache."""

import copy
import functools
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jp
import mujoco
import numpy as np
import pytest

import vnl
from vnl import physics
from vnl.errors import VnlError
from vnl.physics import c_physics, ffi

ROOT = Path(__file__).resolve().parents[1]
C_ENVS = ["ant_run", "rodent_run", "rodent_run_gaps", "rodent_escape_bowl", "humanoid_run", "find_target"]


def by_env(names, group=""):
    return [pytest.param(n, marks=pytest.mark.xdist_group(n + group)) for n in names]


# --- the FFI bridge ---------------------------------------------------------------------------


def test_host_call_under_jit_and_vmap_sees_whole_batches():
    calls = []

    def fn(inputs, outputs):
        a, b = inputs
        calls.append(a.shape)
        outputs[0][...] = 2 * a + b[..., :1]
        outputs[1][...] = a.sum(-1)

    key = ffi.register(0x5EED, fn)
    spec = [jax.ShapeDtypeStruct((3,), jp.float32), jax.ShapeDtypeStruct((), jp.float32)]
    f = jax.jit(lambda a, b: ffi.call(key, spec, a, b))
    a, b = np.arange(3, dtype=np.float32), np.ones(2, np.float32)
    out = f(a, b)
    np.testing.assert_array_equal(out[0], 2 * a + 1)
    assert float(out[1]) == 3.0
    A = np.arange(12, dtype=np.float32).reshape(4, 3)
    out = jax.jit(jax.vmap(f, in_axes=(0, None)))(A, b)  # b is broadcast to the batch
    np.testing.assert_array_equal(out[0], 2 * A + 1)
    np.testing.assert_array_equal(out[1], A.sum(-1))
    AA = np.arange(24, dtype=np.float32).reshape(2, 4, 3)
    out = jax.jit(jax.vmap(jax.vmap(f, in_axes=(0, None)), in_axes=(0, None)))(AA, b)
    np.testing.assert_array_equal(out[0], 2 * AA + 1)
    assert calls[-2:] == [(4, 3), (2, 4, 3)]  # one call per batch, not per element


def test_host_call_error_is_raised_with_its_message():
    def fn(inputs, outputs):
        raise ValueError("the host function failed")

    key = ffi.register(0xBAD, fn)
    f = jax.jit(lambda a: ffi.call(key, [jax.ShapeDtypeStruct((2,), jp.float32)], a)[0])
    with pytest.raises(Exception, match="the host function failed"):
        f(jp.zeros(2)).block_until_ready()


# --- MuJoCo C in the env equals MuJoCo's own stepping ------------------------------------------


@functools.cache
def c_env(name, **kw):
    return vnl.make(name, impl="c", **kw)


@functools.cache
def mid_episode(name, impl="c", batch=3, steps=20):
    """States of `batch` envs after `steps` random-action control steps, and an action for each."""
    e = vnl.make(name, impl=impl) if impl != "c" else c_env(name)

    @jax.jit
    def go(key):
        k0, k1, k2 = jax.random.split(key, 3)
        s = jax.vmap(e.reset)(jax.random.split(k0, batch))
        actions = jax.random.uniform(k1, (steps, batch, e.action_size), minval=-1, maxval=1)
        s, _ = jax.lax.scan(lambda s, a: (jax.vmap(e.step)(s, a), None), s, actions)
        return s, jax.random.uniform(k2, (batch, e.action_size), minval=-1, maxval=1)

    return jax.device_get(go(jax.random.PRNGKey(3)))


def _mj_data(m, data, b):
    """An MjData holding env b's state (float32 values, exactly) from a batched CData/mjx.Data."""
    d = mujoco.MjData(m)
    d.time = float(data.time[b])
    for name in c_physics.STATE[1:]:
        getattr(d, name)[...] = np.asarray(getattr(data, name)[b], np.float64).reshape(getattr(d, name).shape)
    return d


@pytest.mark.slow
@pytest.mark.parametrize("name", by_env(C_ENVS, "-c"))
def test_c_step_equals_mujoco_stepping_bit_for_bit(name):
    """One env step = `n_substeps` × mj_step + mj_step1 (positions and velocities of the new
    state) on the same state in MuJoCo itself, equal to the last bit of float32."""
    e = c_env(name)
    s, action = mid_episode(name)
    s1 = jax.device_get(jax.jit(jax.vmap(e.step))(s, action))
    m = e.mj_model
    for b in range(action.shape[0]):
        # The task may move mocap bodies before the physics step (the gaps' platforms): take
        # them, and the sanitized controls, from the stepped state.
        d = _mj_data(m, s.data, b)
        d.mocap_pos[:] = s1.data.mocap_pos[b]
        d.ctrl[:] = s1.data.ctrl[b]
        for _ in range(e.n_substeps):
            mujoco.mj_step(m, d)
        mujoco.mj_step1(m, d)
        assert s1.metrics["physics_nan"][b] == 0
        for field in ("time", "qpos", "qvel", "act", "qacc_warmstart", "xpos", "xquat", "subtree_com", "cvel"):
            ref = np.asarray(getattr(d, field), np.float32).reshape(np.shape(getattr(s1.data, field)[b]))
            np.testing.assert_array_equal(getattr(s1.data, field)[b], ref, err_msg=f"{name} env {b} {field}")
        for field in ("xmat", "geom_xmat", "site_xmat", "cam_xmat", "ten_velocity", "qfrc_actuator", "cinert"):
            ref = np.asarray(getattr(d, field), np.float32).reshape(np.shape(getattr(s1.data, field)[b]))
            np.testing.assert_array_equal(getattr(s1.data, field)[b], ref, err_msg=f"{name} env {b} {field}")


@pytest.mark.xdist_group("rodent_run-c")
def test_c_forward_equals_mj_forward():
    e = c_env("rodent_run")
    s = jax.device_get(jax.jit(e.reset)(jax.random.PRNGKey(5)))
    d = mujoco.MjData(e.mj_model)
    d.qpos[:], d.qvel[:] = np.asarray(s.data.qpos, np.float64), np.asarray(s.data.qvel, np.float64)
    mujoco.mj_forward(e.mj_model, d)
    for field in ("xpos", "subtree_com", "cvel", "qacc", "qfrc_actuator", "ten_length", "site_xpos"):
        ref = np.asarray(getattr(d, field), np.float32).reshape(np.shape(getattr(s.data, field)))
        np.testing.assert_array_equal(getattr(s.data, field), ref, err_msg=field)


# --- parity with MJX ---------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ant_run", "rodent_run"])
def test_c_and_mjx_agree_without_contacts(name):
    # (From mid-episode states with contacts: tests/test_envs.py, which has MJX's rollouts.)
    """In the air (no contacts), MuJoCo C and MJX compute the same step to float32 precision:
    every state and derived quantity the tasks read is wired through."""
    ej, ec = vnl.make(name), c_env(name)
    m = ec.mj_model
    rng = np.random.default_rng(0)
    qpos = np.asarray(m.qpos0, np.float32).copy()
    qpos[2] += 5.0  # the root 5 m up
    qvel = rng.uniform(-1, 1, m.nv).astype(np.float32)
    ctrl = rng.uniform(-1, 1, m.nu).astype(np.float32)

    def one(env):
        d = env.forward(env.make_data(qpos=jp.asarray(qpos), qvel=jp.asarray(qvel)))
        return env.physics_step(d, jp.asarray(ctrl))

    (dj, bj), (dc, bc) = jax.jit(lambda: one(ej))(), jax.jit(lambda: one(ec))()
    assert float(bj) == float(bc) == 0
    for field, atol in [("qpos", 1e-4), ("qvel", 3e-3), ("act", 1e-5), ("xpos", 1e-4), ("subtree_com", 1e-4)]:
        np.testing.assert_allclose(getattr(dc, field), getattr(dj, field), atol=atol, err_msg=field)
    for field, atol in [("cvel", 3e-3), ("ten_length", 1e-4), ("cam_xpos", 1e-4), ("site_xpos", 1e-4)]:
        np.testing.assert_allclose(getattr(dc, field), getattr(dj, field), atol=atol, err_msg=field)
    np.testing.assert_allclose(physics.ten_velocity(dc), physics.ten_velocity(dj), atol=3e-3)
    np.testing.assert_allclose(physics.cinert(dc), physics.cinert(dj), atol=1e-4)


# --- the NaN guard, threads, per-env fields ------------------------------------------------------


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run-c")
def test_a_blow_up_ends_only_that_envs_episode():
    """An env whose velocities blow up (MuJoCo's bad-qvel check) keeps its last state and ends its
    episode with zero reward; the other envs step exactly as in a batch without it. NaN and 1e9
    actions are cleaned before they reach the physics."""
    e = c_env("ant_run")
    s, action = mid_episode("ant_run", batch=4)
    step = jax.jit(jax.vmap(e.step))
    good = jax.device_get(step(s, action))
    qvel = np.array(s.data.qvel)
    qvel[2, 0] = 1e20
    bad_action = np.array(action)
    bad_action[1, 0], bad_action[3, 1] = np.nan, 1e9
    bad_data = s.data.replace(qvel=qvel)
    out = jax.device_get(step(s.replace(data=bad_data), bad_action))
    np.testing.assert_array_equal(out.metrics["physics_nan"], [0, 0, 1, 0])
    assert out.done[2] == 1 and out.reward[2] == 0
    np.testing.assert_array_equal(out.data.qpos[2], s.data.qpos[2])  # kept its last state
    assert np.isfinite(out.obs).all()
    np.testing.assert_array_equal(out.data.qpos[0], good.data.qpos[0])  # untouched by env 2
    assert out.data.ctrl[1, 0] == 0 and out.data.ctrl[3, 1] == e.mj_model.actuator_ctrlrange[1, 1]


@pytest.mark.slow
@pytest.mark.xdist_group("ant_run-c")
def test_every_blow_up_is_reported_not_only_a_simulations_first():
    """The same blowing-up state stepped again blows up again: MuJoCo's reset after a bad qacc sets
    its warning count back to 1, which a count compared with the previous call's took for no new
    warning (the env then went on from the model's default pose)."""
    e = c_env("ant_run")
    s, action = mid_episode("ant_run", batch=2)
    bad = s.replace(data=s.data.replace(qfrc_applied=np.full_like(s.data.qfrc_applied, np.inf)))
    step = jax.jit(jax.vmap(e.step))
    for _ in range(3):
        out = jax.device_get(step(bad, action))
        np.testing.assert_array_equal(out.metrics["physics_nan"], [1, 1])
        np.testing.assert_array_equal(out.data.qpos, s.data.qpos)  # kept its last state


@pytest.mark.xdist_group("ant_run-c")
def test_results_do_not_depend_on_the_thread_count():
    """Two envs of one model, 1 and 2 threads, alive at once: each call runs on its own env's
    batch of simulations (its thread count), and the results are bit-identical."""
    s, action = mid_episode("ant_run", batch=4)
    envs = [vnl.make("ant_run", impl="c", threads=threads) for threads in (1, 2)]
    steps = [jax.jit(jax.vmap(e.step)).lower(s, action).compile() for e in envs]  # both registered
    outs = []
    for i, (e, step) in enumerate(zip(envs, steps, strict=True)):
        assert e.physics.threads == i + 1 and e.physics.describe().startswith("MuJoCo C")
        outs.append(jax.device_get(step(s, action)))
        assert [4 in other.physics._batches for other in envs] == [True, i == 1]  # this env's Batch ran
    for a, b in zip(jax.tree.leaves(outs[0]), jax.tree.leaves(outs[1]), strict=True):
        np.testing.assert_array_equal(a, b)


def test_bad_impl_and_threads_are_one_line_errors():
    with pytest.raises(VnlError, match="threads must be a whole number >= 1"):
        vnl.make("ant_run", impl="c", threads=0)
    with pytest.raises(VnlError, match="impl"):
        vnl.make("ant_run", impl="fortran")
    with pytest.raises(VnlError, match="contact_termination.*impl: jax"):
        vnl.make("rodent_run_gaps", impl="c", contact_termination=True)
    assert physics.resolve_threads(None) == physics.available_cores() >= 1


@pytest.mark.slow
def test_per_env_masses_and_gains_reach_mujoco():
    """With randomized masses (MuJoCo's derived constants recomputed) and gains, each env steps as
    MuJoCo does with that env's model."""
    from vnl.envs import randomize
    from vnl.envs.wrappers import wrap_for_training

    env = vnl.make("ant_run", impl="c")
    n = 3
    cfg = randomize.RandomizeConfig(body_mass=(0.5, 2.0), actuator_gain=(0.5, 1.5))
    fn = functools.partial(randomize.randomizer(cfg), rng=jax.random.split(jax.random.PRNGKey(1), n))
    w = wrap_for_training(env, episode_length=100, randomization_fn=fn)
    assert set(env.physics.per_env_fields) == {"body_mass", "body_inertia", "actuator_gainprm", "actuator_biasprm"}
    s0 = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(2), n))
    action = jp.full((n, env.action_size), 0.5)
    s1 = jax.device_get(jax.jit(w.step)(s0, action))
    models = w.env.env.model
    for i in range(n):
        m = copy.copy(env.mj_model)
        m.body_mass[:] = np.asarray(models.body_mass[i], np.float32)
        m.body_inertia[:] = np.asarray(models.body_inertia[i], np.float32)
        m.actuator_gainprm[:] = np.asarray(models.actuator_gainprm[i], np.float32)
        m.actuator_biasprm[:] = np.asarray(models.actuator_biasprm[i], np.float32)
        mujoco.mj_setConst(m, mujoco.MjData(m))
        d = _mj_data(m, s0.data, i)
        d.ctrl[:] = 0.5
        for _ in range(env.n_substeps):
            mujoco.mj_step(m, d)
        mujoco.mj_step1(m, d)
        np.testing.assert_array_equal(s1.data.qpos[i], d.qpos.astype(np.float32))
        np.testing.assert_array_equal(s1.data.subtree_com[i], d.subtree_com.astype(np.float32))
    assert np.ptp(s1.data.qpos[:, 2]) > 1e-4  # the envs differ


# --- vision, presets, the compilation cache --------------------------------------------------------


@pytest.mark.slow
def test_in_graph_camera_sees_c_physics_states():
    env = vnl.make("find_target", impl="c", vision={"width": 16, "height": 16})
    s0 = jax.jit(env.reset)(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    s = s0
    for _ in range(10):
        s = step(s, jp.array([1.0, 0.0]))
    key = env.pixels_key
    assert float(s.data.qpos[0]) > float(s0.data.qpos[0]) + 0.05  # the ball moved
    assert np.abs(np.asarray(s.obs[key], int) - np.asarray(s0.obs[key], int)).sum() > 0
    np.testing.assert_array_equal(s.obs[key], env.pixels(s.data))


def test_cpu_presets_choose_c_physics():
    from vnl.train import config as train_config

    for name in ("rodent_run", "rodent_run_gaps", "rodent_escape_bowl", "ant_run", "ant_run_gaps", "ant_escape_bowl"):
        cfg = train_config.build(name, "cpu")
        assert cfg.resolved_env_config().impl == "c"
        assert train_config.build(name, "gpu").resolved_env_config().impl == "jax"
        assert train_config.build(name, "cpu", assignments=["env_config.impl=jax"]).resolved_env_config().impl == "jax"
    assert train_config.build("humanoid_run", "cpu").resolved_env_config().impl == "c"
    assert train_config.build("ant_run", "tiny").resolved_env_config().impl == "jax"  # tests' smoke preset


CACHE_SCRIPT = textwrap.dedent(
    """
    import json, time, jax
    hits = []
    jax.monitoring.register_event_listener(lambda e, **kw: hits.append(e) if e.endswith("cache_hits") else None)
    import vnl
    from vnl import compile_cache
    compile_cache.enable({cache!r})
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)  # this program compiles in < 0.5 s here
    env = vnl.make("rodent_run", impl="c")
    def rollout(key):
        s = jax.vmap(env.reset)(jax.random.split(key, 4))
        a = jax.numpy.zeros((30, 4, env.action_size))
        return jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a), s.reward), s, a)[1]
    t = time.time()
    r = jax.jit(rollout)(jax.random.PRNGKey(0)).block_until_ready()
    print("RESULT" + json.dumps({{"hits": len(hits), "seconds": time.time() - t, "sum": float(r.sum())}}))
    """
)


@pytest.mark.slow
@pytest.mark.xdist_group("rodent_run-c")
def test_second_process_loads_the_c_physics_program_from_the_cache(tmp_path):
    script = CACHE_SCRIPT.format(cache=str(tmp_path / "cache"))
    runs = []
    for _ in range(2):
        p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=600)
        assert p.returncode == 0, p.stderr[-3000:]
        runs.append(json.loads(p.stdout.split("RESULT")[-1]))
    assert runs[0]["hits"] == 0 and runs[1]["hits"] >= 1
    assert runs[0]["sum"] == runs[1]["sum"]  # the cached program computes the same rollout
    assert any((tmp_path / "cache").glob("jit_rollout-*"))


QUIET_SCRIPT = textwrap.dedent(
    """
    import sys
    if sys.argv[2] == "cli":
        from vnl.cli.process import configure_process
        configure_process(mujoco_needed=False)
    import jax, jax.numpy as jp
    from vnl import compile_cache
    compile_cache.enable(sys.argv[1])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    hits = []
    jax.monitoring.register_event_listener(lambda e, **kw: hits.append(e) if e.endswith("cache_hits") else None)
    def f(x):
        for i in range(50):
            x = jp.sin(x) @ x + i
        return x
    print("RESULT", float(jax.jit(f)(jp.eye(8) / 8).sum()), len(hits))
    """
)


@pytest.mark.slow
def test_the_cli_keeps_xla_s_cache_load_warnings_off_the_console(tmp_path):
    """jaxlib 0.8's XLA:CPU logs multi-kilobyte ERROR lines (a false SIGILL warning) whenever it
    loads a program from the persistent cache; the CLI's process setup keeps them off the console,
    and the program still loads from the cache and computes the same."""
    env = {k: v for k, v in os.environ.items() if k != "TF_CPP_MIN_LOG_LEVEL"}

    def run(mode: str) -> tuple[str, list[str]]:
        cmd = [sys.executable, "-c", QUIET_SCRIPT, str(tmp_path / "cache"), mode]
        p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)
        assert p.returncode == 0, p.stderr[-3000:]
        return p.stderr, p.stdout.split("RESULT")[-1].split()

    _, first = run("plain")  # writes the cache
    plain, second = run("plain")
    quiet, third = run("cli")
    assert first[0] == second[0] == third[0] and first[1] == "0" and int(second[1]) >= 1 and int(third[1]) >= 1
    if "cpu_aot_loader" not in plain:
        pytest.skip("this jaxlib does not log the cache-load warning")
    assert "cpu_aot_loader" not in quiet and "SIGILL" not in quiet, quiet[:2000]


# --- training with C physics on two devices --------------------------------------------

TINY_C = ["--preset", "tiny", "--no-video", "--no-compile-cache", "--set", "env_config.impl=c"]


def _vnl(*args, env=None, timeout=900):
    return subprocess.run(
        [sys.executable, "-m", "vnl", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=timeout,
    )


# Exact resume with C physics (and a changed thread count): tests/test_research.py, on ant_run.


@pytest.mark.slow
def test_trains_with_c_physics_on_two_devices(tmp_path):
    env = {**__import__("os").environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    p = _vnl("train", "ant_run", *TINY_C, "--out", tmp_path / "run", env=env)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    assert "on 2 cpu device(s)" in p.stdout and "physics MuJoCo C" in p.stdout
    from vnl.io import checkpoint

    _, params = checkpoint.load(tmp_path / "run")
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(params))


def test_mjx_private_fields_that_vnl_reads_are_still_there():
    """`vnl/physics/mjx_physics.py` is vnl's only reader of MJX's implementation data
    (`data._impl.ten_J`, `.ten_velocity`, `.cinert`: MJX 3.17 has no public field for them). This
    fails loudly if MJX moves or changes them: the values must equal MuJoCo C's."""
    from mujoco import mjx

    from vnl.physics import mjx_physics

    xml = """<mujoco><worldbody><body><joint name="a" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 .3 0 0" size=".05"/>
      <body pos=".3 0 0"><joint name="b" type="hinge" axis="0 1 0"/><geom type="sphere" size=".05"/></body>
      </body></worldbody><tendon><fixed name="t"><joint joint="a" coef="1"/><joint joint="b" coef="-0.5"/></fixed>
      </tendon></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:] = [0.3, -0.7]
    d.qvel[:] = [1.5, 2.0]
    mujoco.mj_forward(m, d)
    mx = mjx.put_model(m)
    dx = jax.jit(lambda q, v: mjx_physics.sync(mx, mjx.make_data(mx).replace(qpos=q, qvel=v)))(d.qpos, d.qvel)
    np.testing.assert_allclose(mjx_physics.ten_velocity(dx), d.ten_velocity, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(mjx_physics.cinert(dx), d.cinert, rtol=1e-5, atol=1e-6)
    assert float(d.ten_velocity[0]) != 0.0  # the check compares something
