"""Compact checkpoints (issue 57): a checkpoint keeps of each physics state what the next step
reads, and `--resume` through it is still bit-exact; a full checkpoint of an earlier vnl resumes
too; `rundir.checkpoint_bytes` counts what is written; each task declares every derived field its
step reads of a previous state (`Env.previous_state_reads`)."""

import io
import shutil
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from vnl import physics
from vnl.envs import registry
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.physics import c_physics, mjx_physics
from vnl.train import config as train_config
from vnl.train import rundir, trainer

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("point_envs")]

ROOT = Path(__file__).resolve().parents[1]
K = 1024  # tiny preset: 2 training steps of 512 env steps
DATA = (".env.data.", ".env.info['first_data'].")  # the training envs' physics states: current, first


KEPT = {"jax": set(mjx_physics.ALWAYS_KEPT), "c": set(c_physics.STATE)}  # the point mass reads nothing else


def config(impl="jax", **ppo):
    values = {
        "ppo": {"num_timesteps": 2 * K, "num_evals": 3, "episode_length": None, **ppo},
        "env_config": {"impl": impl, "episode_length": 12},  # episodes end, so first states are used
        "log": {"video": False, "progress": False},
    }
    return train_config.build("test_point", "tiny", file_values=values)


def quiet(_):
    pass


def physics_fields(arrays):
    """The names of the physics fields (as `data.<name>`) in a checkpoint's arrays."""
    leaves = [k.removeprefix(p) for k in arrays for p in DATA if k.startswith(p)]
    return {leaf.removeprefix("_impl.").split(".")[0] for leaf in leaves}


def untimed(run):
    timing = ("time", "sps", "steps_per_sec")
    records = metrics_io.read(run / "metrics.jsonl")
    return [{k: v for k, v in r.items() if not any(t in k for t in timing)} for r in records]


def assert_same_run(run, reference):
    assert checkpoint.steps(run) == checkpoint.steps(reference) == [0, K, 2 * K]
    _, a, _ = checkpoint.load_train_state(reference)
    _, b, _ = checkpoint.load_train_state(run)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert untimed(run) == untimed(reference)


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    """impl -> 2K steps of the point mass on that physics, uninterrupted (trained when first asked)."""
    runs = {}

    def get(impl):
        if impl not in runs:
            runs[impl] = tmp_path_factory.mktemp(impl) / "reference"
            trainer.train(config(impl), runs[impl], say=quiet)
        return runs[impl]

    return get


@pytest.fixture(scope="module")
def reference(references):
    return references("jax")


@pytest.mark.parametrize("impl", ["jax", "c"])
def test_a_resume_through_a_compact_checkpoint_is_bit_exact(references, impl, tmp_path):
    """K steps + `--resume` + K steps equals 2K steps, bit for bit, on MJX and on MuJoCo C, and
    every checkpoint holds of the physics states only the integration state (and, on MJX,
    `qfrc_constraint`): the point mass's step reads nothing else of a previous state."""
    run = tmp_path / "run"
    trainer.train(config(impl, num_timesteps=K, num_evals=2), run, say=quiet)
    step, arrays, meta = checkpoint.load_train_state(run)
    assert step == K and meta["format"] == checkpoint.META_FORMAT == 2
    assert physics_fields(arrays) == KEPT[impl]
    assert not any(name in physics_fields(arrays) for name in ("efc_J", "M", "xpos", "qacc", "cinert"))
    trainer.resume(run, flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    assert_same_run(run, references(impl))


@pytest.fixture(scope="module")
def full_checkpoint(tmp_path_factory):
    """K steps of the same run, its checkpoints written as vnl wrote them before format 2: the
    whole physics state (format 1)."""
    run = tmp_path_factory.mktemp("full") / "run"
    with pytest.MonkeyPatch.context() as m:
        m.setattr(physics, "derived_paths", lambda tree, reads: [])
        m.setattr(checkpoint, "META_FORMAT", 1)
        trainer.train(config(num_timesteps=K, num_evals=2), run, say=quiet)
    return run


def test_a_full_checkpoint_of_an_earlier_vnl_resumes_exactly_and_is_followed_by_compact_ones(
    reference, full_checkpoint, tmp_path
):
    """A checkpoint holding the whole physics state resumes to the same run; the checkpoints
    written after it are compact."""
    run = tmp_path / "run"
    shutil.copytree(full_checkpoint, run)
    _, full, meta = checkpoint.load_train_state(run)
    assert meta["format"] == 1 and {"efc_J", "M", "contact", "xpos"} <= physics_fields(full)
    trainer.resume(run, flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    assert_same_run(run, reference)
    _, after, _ = checkpoint.load_train_state(run)
    assert physics_fields(after) == KEPT["jax"]


def test_the_size_estimate_counts_what_a_checkpoint_holds(reference, full_checkpoint):
    """`env_state_bytes` is, to the byte, what a checkpoint holds per training env, compact and
    full; the rat's `gpu` preset drops from over 400 MiB to under 24."""
    cfg = config()
    env = cfg.make_env()
    for run, compact in ((reference, True), (full_checkpoint, False)):
        _, arrays, _ = checkpoint.load_train_state(run, K)
        held = sum(v.nbytes for k, v in arrays.items() if k.startswith(".env"))
        assert cfg.ppo.num_envs * rundir.env_state_bytes(env, compact) == held, compact
    rat = train_config.build("rodent_run", "gpu")
    full, compact = (rundir.checkpoint_bytes(rat, rat.make_env(), compact=c) for c in (False, True))
    assert full > 400 * 2**20 and compact < 24 * 2**20, (full / 2**20, compact / 2**20)


def test_the_training_state_is_written_compressed(reference):
    """train_state.npz is deflated (the zeros of the applied forces and of the first states'
    controls take no room): smaller than `np.savez` writes the same arrays."""
    path = checkpoint.step_dir(reference, K) / checkpoint.TRAIN_STATE
    with zipfile.ZipFile(path) as z:
        assert all(e.compress_type == zipfile.ZIP_DEFLATED for e in z.infolist())
    with np.load(path) as z:
        plain = io.BytesIO()
        np.savez(plain, **{k: z[k] for k in z.files})
    assert path.stat().st_size < 0.9 * len(plain.getvalue()), (path.stat().st_size, len(plain.getvalue()))


def _wrapped_state(env):
    """The shapes of one training env's state, as training wraps it."""
    import jax

    from vnl.envs.wrappers import wrap_for_training

    return jax.eval_shape(wrap_for_training(env, episode_length=1).reset, jax.ShapeDtypeStruct((1, 2), np.uint32))


# --- what a step reads of a previous state ---------------------------------------------------------


def _probe():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import checkpoint_state

    return checkpoint_state


CASES = [(name, {}) for name in ("ant_run", "ant_run_gaps", "rodent_run", "rodent_run_gaps", "rodent_two_touch")]
CASES += [(name, {}) for name in ("escape_bowl", "cue_memory", "find_target", "brax_ant_run", "rodent_imitate")]
CASES += [("ant_run", {"foot_slip_cost_weight": 0.1})]
CASES += [("rodent_run_gaps", {"terminate_foot_below": -0.1, "healthy_min_upright": None})]


@pytest.mark.parametrize(("name", "overrides"), CASES)
def test_a_task_declares_every_field_its_step_reads_of_a_previous_state(name, overrides):
    """Each derived physics field outside the task's `previous_state_reads`, made wrong (finite
    values: a compact checkpoint refills them with a reset's), changes nothing a step returns
    that training uses, on a normal step and on one that blows up (MuJoCo C physics: the fields
    are MJX's, and it compiles in seconds); the declared ones are all read."""
    result = _probe().reads(name, "c", overrides=overrides)
    assert result["declared"] is not None
    assert result["read"] == result["declared"], result


@pytest.mark.parametrize("name", ["test_point", "ant_run"])
def test_mjx_steps_read_nothing_a_compact_checkpoint_leaves_out(name):
    """On MJX, every field a checkpoint leaves out made wrong at once, in the current and the
    first state, through an episode's end and from a blown-up step: every output a step returns
    but those fields is bit-identical for 3 steps (`qfrc_constraint`, which MJX 3.17 reads of a
    model without constraints, is kept: the point mass has none)."""
    result = _probe().joint(name, "jax")
    assert result["dropped"] and not result["differs"], result


@pytest.mark.parametrize("impl", ["jax", "c"])
def test_an_env_that_does_not_say_what_it_reads_keeps_its_whole_state(impl):
    state = _wrapped_state(registry.make("test_point", impl=impl))
    assert physics.derived_paths(state, None) == []
    assert len(physics.derived_paths(state, ())) > (50 if impl == "jax" else 20)
