"""Test harness setup: headless OpenGL for the renderer, quiet third-party warnings."""

import ctypes
import ctypes.util
import gc
import os
import sys
import tempfile

import pytest

# The tests stand in for the CLI here: pick a headless GL before mujoco is imported.
if "MUJOCO_GL" not in os.environ:
    if ctypes.util.find_library("EGL"):
        os.environ["MUJOCO_GL"] = "egl"
    elif ctypes.util.find_library("OSMesa"):
        os.environ["MUJOCO_GL"] = "osmesa"

# `vnl` commands run by the tests keep compiled programs in a cache of this test session (one per
# xdist worker), not in the user's ~/.cache/vnl/jax.
os.environ["VNL_COMPILE_CACHE"] = tempfile.mkdtemp(prefix="vnl-test-compile-cache-")


@pytest.fixture(scope="module", autouse=True)
def release_compiled_programs():
    """After each test module: JAX's compiled programs dropped and freed memory handed back.

    A worker keeps every program it compiled: over the suite one grew to 7.8 GB resident beside
    the other's 5.2 GB (docs/developers/tests.md), and CI's 24 GiB machine crashed a worker. A
    module's shared compiles live in its own fixtures, so nothing a later module uses is lost."""
    yield
    if "jax" in sys.modules:
        sys.modules["jax"].clear_caches()
    gc.collect()
    libc = ctypes.util.find_library("c")
    if libc and hasattr(ctypes.CDLL(libc), "malloc_trim"):
        ctypes.CDLL(libc).malloc_trim(0)


@pytest.fixture(scope="session", autouse=True)
def xdist_groups_hold(request):
    """Errors every test when `--dist loadgroup` would not keep an `xdist_group` on one worker.

    xdist groups a test by appending "@<group>" to its node id on the worker. pytest 9.2 builds
    node ids from a structured id and ignores that, so groups were spread over both workers and
    their shared compiles and trained runs were done twice (pytest is pinned to 9.1.1 for this).
    Session-scoped and autouse, so it runs before any expensive fixture.
    """
    if not getattr(request.config.option, "loadgroup", False):  # set on xdist workers under loadgroup
        return
    items = request.session.items
    lost = [item.nodeid for item in items if item.get_closest_marker("xdist_group") and "@" not in item.nodeid]
    if lost:
        pytest.fail(
            f"pytest-xdist's loadgroup did not group {len(lost)} tests (e.g. {lost[0]}): this pytest and "
            "pytest-xdist do not work together; install the versions pinned in requirements.lock"
        )


@pytest.fixture(scope="module")
def point_envs():
    """The test-only point-mass envs of tests/tiny_env.py, registered for one test module
    (use with `pytestmark = pytest.mark.usefixtures("point_envs")`)."""
    import tiny_env

    tiny_env.register()
    yield
    tiny_env.unregister()


@pytest.fixture(scope="session")
def rat_recording(tmp_path_factory):
    """An untrained rat in the gaps corridor (MuJoCo C physics, no tilt check): 3 episodes of 80 steps, as a
    dataset, its NetCDF file and its NWB file: (run, dataset, .nc path, .nwb path). Tests that use
    it carry `xdist_group("neuro_record")`, so one worker records it once."""
    from test_viewer import untrained_run  # tests/ is on sys.path; imported here: it imports JAX

    from vnl import record
    from vnl.recording import netcdf, nwb

    # Without the env's tilt check (dm_control's rule): an untrained rat falls over within steps,
    # and episodes of a few steps would make a recording too short to export as NWB expects.
    run = untrained_run(
        tmp_path_factory.mktemp("neuro") / "run", "rodent_run_gaps", ("env_config.healthy_min_upright=null",)
    )
    ds = record.record(run, episodes=3, steps=80, seed=0)
    path = netcdf.write(ds, run.run_dir / "record.nc")
    out = nwb.write(ds, run.run_dir / "record.nwb", config="env: rodent_run_gaps\n", command="test")
    return run, ds, path, out


@pytest.fixture(scope="session")
def lab_session(tmp_path_factory):
    """A synthetic lab session (`vnl.recording.synthetic`): 30 units, 24 with a known linear
    tuning to the snout's position, 8 trials of 20 s, as NWB; (path, truth). About a second."""
    from vnl.recording import synthetic

    path = tmp_path_factory.mktemp("lab") / "lab.nwb"
    return path, synthetic.write_session(path)
