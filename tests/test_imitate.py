"""rodent_imitate (vnl.tasks.imitate) and its reference clips (vnl.tasks.reference), on MuJoCo C
physics: the reset pose, the egocentric reference, the reward terms against the clip's own poses,
termination and truncation, resampling, and the clips a config may not name."""

import dataclasses
import functools

import jax
import jax.numpy as jp
import numpy as np
import pytest

import vnl
from vnl.envs import wrappers
from vnl.errors import VnlError
from vnl.mocap.clips import Clip, load_clips, save_clips
from vnl.tasks import contract, imitate, reference

pytestmark = pytest.mark.xdist_group("rodent_imitate-c")

SHIPPED = imitate.DATA / "rodent_clips.h5"


@functools.cache
def env(**overrides):
    return vnl.make("rodent_imitate", impl="c", threads=1, **overrides)


@functools.cache
def jitted(name):
    return jax.jit(getattr(env(), name))


def at_frame(e, clip, index, qpos=None, qvel=None):
    """The physics state of the reference's frame `index` of clip `clip` (or `qpos`/`qvel` instead)."""
    ref = e.frame(jp.int32(clip), jp.int32(index))
    qpos = ref["qpos"] if qpos is None else qpos
    return e.forward(e.make_data(qpos=qpos, qvel=ref["qvel"] if qvel is None else qvel)), ref


def test_reset_places_the_walker_at_its_clips_frame():
    """The walker starts in the drawn frame's pose and velocity: its qpos is the clip's (mapped by
    joint name) and its bodies are where the clips file says (matched by body name)."""
    e = env()
    clips = load_clips(SHIPPED)
    torso = clips[0].body_names.index("walker/torso")
    hand = clips[0].body_names.index("walker/hand_L")
    drawn = set()
    for seed in range(4):
        s = jitted("reset")(jax.random.PRNGKey(seed))
        c, f = int(s.info["clip"]), int(s.info["frame"])
        drawn.add((c, f))
        clip = clips[c]
        np.testing.assert_allclose(s.data.qpos, clip.qpos[f], atol=1e-6)
        np.testing.assert_allclose(s.data.qvel, clip.qvel[f], atol=1e-5)
        np.testing.assert_allclose(s.data.xpos[e.root_body_id], clip.xpos[f, torso], atol=1e-5)
        np.testing.assert_allclose(
            s.data.xpos[e._bodies[e.layout.body_names.index("hand_L")]], clip.xpos[f, hand], atol=1e-5
        )
    assert len(drawn) == 4  # each reset draws its own start


def _turned(e, data, future, yaw, shift):
    """`data` and the reference frames `future` with the world turned by `yaw` about z and moved by `shift`."""
    c, s = np.cos(yaw), np.sin(yaw)
    rot = jp.asarray([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], jp.float32)
    q_yaw = jp.asarray([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)], jp.float32)
    a, v = e.layout.free_qpos, e.layout.free_qvel
    qpos = data.qpos.at[a : a + 3].set(rot @ data.qpos[a : a + 3] + shift)
    qpos = qpos.at[a + 3 : a + 7].set(imitate.quat_mul(q_yaw, data.qpos[a + 3 : a + 7]))
    qvel = data.qvel.at[v : v + 3].set(rot @ data.qvel[v : v + 3])  # world-frame linear velocity
    turned = e.forward(e.make_data(qpos=qpos, qvel=qvel))
    moved = {
        **future,
        "body_pos": future["body_pos"] @ rot.T + shift,
        "body_quat": imitate.quat_mul(q_yaw, future["body_quat"]),
    }
    return turned, moved


def test_the_reference_observation_is_egocentric():
    """Turning and moving the world (walker and reference alike) changes nothing the policy sees;
    moving the reference alone does."""
    e = env()
    data, _ = at_frame(e, 1, 20, qpos=None)
    data = e.forward(e.make_data(qpos=data.qpos.at[e.layout.joint_qpos].add(0.05), qvel=data.qvel))  # off the clip
    future = e.future(jp.int32(1), jp.int32(20))

    def seen(d, fut):
        return np.asarray(jp.concatenate([e.proprioception(d), e.reference_observation(d, fut)]))

    before = seen(data, future)
    assert before.shape == (e.observation_size,)
    turned, moved = _turned(e, data, future, yaw=2.1, shift=jp.asarray([3.0, -1.5, 0.0]))
    np.testing.assert_allclose(seen(turned, moved), before, atol=2e-4)
    only_reference = {**future, "body_pos": future["body_pos"] + jp.asarray([0.1, 0.0, 0.0])}
    assert np.abs(seen(data, only_reference) - before).max() > 0.05


def test_the_clips_own_poses_pay_every_term_in_full_with_no_error():
    """Placed at the reference's pose and velocity, every term pays its weight and the errors are 0."""
    e = env()
    cfg = e.config
    for clip, index in ((0, 0), (1, 37), (2, 99)):
        data, ref = at_frame(e, clip, index)
        terms, errors = e.tracking(data, ref)
        for term in imitate.TERMS:
            assert float(terms[term]) == pytest.approx(getattr(cfg, f"{term}_weight"), rel=1e-3), term
        assert float(errors["body_distance"]) < 1e-5 and float(errors["joint"]) < 1e-6


def test_a_pose_off_the_reference_pays_less_on_every_term():
    e = env()
    data, ref = at_frame(e, 1, 50)
    a = e.layout.free_qpos
    qpos = data.qpos.at[e.layout.joint_qpos].add(0.15).at[a : a + 3].add(jp.asarray([0.03, 0.0, 0.0]))
    qvel = data.qvel.at[e.layout.joint_qvel].add(5.0)
    off, _ = at_frame(e, 1, 50, qpos=qpos, qvel=qvel)
    full, _ = e.tracking(data, ref)
    less, errors = e.tracking(off, ref)
    for term in imitate.TERMS:
        assert float(less[term]) < 0.9 * float(full[term]), term
    assert np.degrees(float(errors["joint"])) == pytest.approx(np.degrees(0.15), rel=1e-3)
    assert float(errors["body_distance"]) > 0.03


def test_straying_fails_and_the_clips_end_truncates():
    e = env()
    step = jitted("step")
    s = jitted("reset")(jax.random.PRNGKey(0))
    a = e.layout.free_qpos
    away = e.forward(e.make_data(qpos=s.data.qpos.at[a].add(0.5), qvel=s.data.qvel))
    strayed = step(s.replace(data=away), jp.zeros(e.action_size))
    assert float(strayed.done) == 1 and float(strayed.info["truncated"]) == 0
    assert float(strayed.metrics["measure/frames_tracked"]) == 0 and float(strayed.metrics["body_error_mm"]) > 400
    # One step before the clip's end, at its pose: the step tracks, and the clip ends.
    last = int(e.clip_lengths[2]) - 1
    data, _ = at_frame(e, 2, last - 1)
    info = {**s.info, "clip": jp.int32(2), "frame": jp.int32(last - 1)}
    ended = step(s.replace(data=data, info=info), jp.zeros(e.action_size))
    assert float(ended.done) == 1 and float(ended.info["truncated"]) == 1
    assert float(ended.metrics["measure/frames_tracked"]) == 1
    going = step(s.replace(data=data, info={**info, "frame": jp.int32(last - 2)}), jp.zeros(e.action_size))
    assert float(going.done) == 0 and float(going.info["truncated"]) == 0


def test_training_counts_a_clips_end_as_a_truncation_not_a_failure():
    """Through the training wrappers, a truncated end is `truncation` (PPO bootstraps through it); a
    failure is not."""
    e = env()
    w = wrappers.wrap_for_training(e, episode_length=1000)
    s = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    last = int(e.clip_lengths[2]) - 1
    data, _ = at_frame(e, 2, last - 1)
    a = e.layout.free_qpos
    stray = e.forward(e.make_data(qpos=data.qpos.at[a].add(0.5), qvel=data.qvel))
    both = jax.tree.map(lambda x, y: jp.stack([x, y]), data, stray)
    info = {**s.info, "clip": jp.full(2, 2, jp.int32), "frame": jp.full(2, last - 1, jp.int32)}
    out = jax.jit(w.step)(s.replace(data=both, info=info), jp.zeros((2, e.action_size)))
    assert out.done.tolist() == [1.0, 1.0]
    assert out.info["truncation"].tolist() == [1.0, 0.0]


def _clip(name, qpos, fps, walker="rodent", joints=("root", "hinge"), bodies=("torso",)):
    t = qpos.shape[0]
    xpos = np.zeros((t, len(bodies), 3), np.float32)
    xpos[:, 0] = qpos[:, :3]
    xquat = np.repeat(qpos[:, None, 3:7], len(bodies), axis=1)
    qvel = np.zeros((t, qpos.shape[1] - 1), np.float32)
    return Clip(name, walker, fps, qpos.astype(np.float32), qvel, xpos, xquat.astype(np.float32), joints, bodies)


def test_resampling_interpolates_positions_and_slerps_quaternions():
    """A clip at 120 fps of a root moving at constant speed and turning at a constant rate, with a
    hinge swinging linearly, resampled to 50 fps: every frame is the motion at its time."""
    fps, t = 120.0, np.arange(121) / 120.0
    yaw = 2.5 * t  # rad; 0.02 rad between frames
    qpos = np.stack([0.7 * t, 0 * t, 0.1 + 0 * t, np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2), 1.2 * t - 0.3], 1)
    out = reference.resample(_clip("c", qpos, fps), 50.0)
    s = np.arange(51) / 50.0
    assert out.frames == 51 and out.fps == 50.0
    np.testing.assert_allclose(out.qpos[:, 0], 0.7 * s, atol=1e-6)
    np.testing.assert_allclose(out.qpos[:, 7], 1.2 * s - 0.3, atol=1e-6)
    want = np.stack([np.cos(1.25 * s), 0 * s, 0 * s, np.sin(1.25 * s)], 1)
    np.testing.assert_allclose(out.qpos[:, 3:7], want, atol=1e-6)
    np.testing.assert_allclose(out.xquat[:, 0], want, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(out.qpos[:, 3:7], axis=1), 1.0, atol=1e-6)
    assert reference.resample(out, 50.0) is out
    with pytest.raises(VnlError, match="shorter than two control steps"):
        reference.resample(_clip("short", qpos[:3], fps), 50.0)


def test_a_clip_at_another_rate_is_resampled_to_the_control_step(tmp_path):
    """The shipped clips at 100 fps (every frame doubled by interpolation) give the env the same
    reference at its 50-Hz control step."""
    clips = load_clips(SHIPPED)
    fine = []
    for c in clips:
        mid = reference.resample(dataclasses.replace(c, fps=1.0), 2.0)  # frames at half steps
        fine.append(dataclasses.replace(mid, fps=100.0))
    save_clips(tmp_path / "fine.h5", fine)
    e = env(clips=str(tmp_path / "fine.h5"))
    assert e.clip_lengths.tolist() == env().clip_lengths.tolist() == [100, 100, 100]
    for k in ("qpos", "joints", "body_pos", "ends_ego"):
        np.testing.assert_allclose(e._ref[k], env()._ref[k], atol=1e-5, err_msg=k)


def test_a_clip_made_from_the_walker_alone_fits_by_name(tmp_path):
    """Bodies in another order, without the `walker/` prefix and without the world's: the same reference."""
    clips = load_clips(SHIPPED)
    alone = []
    for c in clips:
        keep = [i for i, n in enumerate(c.body_names) if n.startswith("walker/") and n != "walker/"][::-1]
        alone.append(
            dataclasses.replace(
                c,
                xpos=c.xpos[:, keep],
                xquat=c.xquat[:, keep],
                body_names=tuple(c.body_names[i].removeprefix("walker/") for i in keep),
                joint_names=tuple(n.removeprefix("walker/") for n in c.joint_names),
            )
        )
    save_clips(tmp_path / "alone.h5", alone)
    e = env(clips=str(tmp_path / "alone.h5"))
    for k, v in env()._ref.items():
        np.testing.assert_array_equal(e._ref[k], v, err_msg=k)


def test_bad_clips_are_refused_before_anything_is_compiled(tmp_path):
    clips = load_clips(SHIPPED)
    builds = contract.world_builds()
    with pytest.raises(VnlError, match="clips: no such file"):
        vnl.make("rodent_imitate", impl="c", clips=str(tmp_path / "none.h5"))
    save_clips(tmp_path / "ant.h5", [dataclasses.replace(clips[0], walker="ant")])
    with pytest.raises(VnlError, match="is of the walker 'ant', and this env's walker is 'rodent'"):
        vnl.make("rodent_imitate", impl="c", clips=str(tmp_path / "ant.h5"))
    c = clips[0]
    short = dataclasses.replace(c, qpos=c.qpos[:, :-1], qvel=c.qvel[:, :-1], joint_names=c.joint_names[:-1])
    save_clips(tmp_path / "short.h5", [short])
    with pytest.raises(VnlError, match=r"does not have this env's walker's joints \(missing \['finger_R'\]"):
        vnl.make("rodent_imitate", impl="c", clips=str(tmp_path / "short.h5"))
    wide = dataclasses.replace(c, qpos=np.concatenate([c.qpos, c.qpos[:, -1:]], 1))
    save_clips(tmp_path / "wide.h5", [wide])
    with pytest.raises(VnlError, match="has qpos of 51 and qvel of 49 columns"):
        vnl.make("rodent_imitate", impl="c", clips=str(tmp_path / "wide.h5"))
    (tmp_path / "text.h5").write_text("not a clips file")
    with pytest.raises(VnlError, match="not a readable HDF5 clips file"):
        vnl.make("rodent_imitate", impl="c", clips=str(tmp_path / "text.h5"))
    with pytest.raises(VnlError, match="observes proprioception and the reference, got 'state'"):
        vnl.make("rodent_imitate", impl="c", observation="state")
    assert contract.world_builds() == builds


def test_another_walker_tracks_a_synthetic_clip_of_its_own(tmp_path):
    """The ant, with a clip synthesised on its own world (default pose, joints swinging, the root
    walking forward at 20 fps): built, resampled to the 50-Hz control step, reset onto the clip,
    and paid in full at the clip's poses."""
    from vnl.arenas import floor
    from vnl.mocap.clips import clip_from_qpos
    from vnl.tasks.base import build_walker, compile_world, spawn_height

    cfg = imitate.ImitateConfig(walker="ant")
    model, _ = compile_world(build_walker(cfg), floor.build(cfg.floor_size))
    t = np.arange(30) / 20.0
    qpos = np.tile(model.qpos0, (len(t), 1))
    qpos[:, 0], qpos[:, 2] = 0.3 * t, spawn_height(model) + 0.02
    qpos[:, 7:] += 0.3 * np.sin(2 * np.pi * 1.5 * t)[:, None]
    save_clips(tmp_path / "ant.h5", [clip_from_qpos("walk", model, qpos, 20.0, "ant", "synthetic")])
    e = vnl.make("rodent_imitate", impl="c", threads=1, walker="ant", clips=str(tmp_path / "ant.h5"))
    assert e.clip_lengths.tolist() == [73]  # 1.45 s at 50 Hz, and its first frame
    s = jax.jit(e.reset)(jax.random.PRNGKey(3))
    ref = e.frame(s.info["clip"], s.info["frame"])
    np.testing.assert_allclose(s.data.qpos, ref["qpos"], atol=1e-6)
    terms, errors = e.tracking(s.data, ref)
    assert all(float(terms[k]) == pytest.approx(1.0, rel=1e-3) for k in imitate.TERMS)
    with pytest.raises(VnlError, match="is of the walker 'ant', and this env's walker is 'rodent'"):
        vnl.make("rodent_imitate", impl="c", clips=str(tmp_path / "ant.h5"))


def test_a_recording_keeps_the_reference_beside_the_pose_and_exports_it(tmp_path):
    """`vnl record` of an imitation keeps, per step, the reference clip's frame the walker was asked
    to take (start frame + t, as the env tracks it): at the reset it is the walker's own pose, and
    the NWB export holds it as a second pose estimation beside the body's."""
    from test_viewer import untrained_run

    from vnl import record
    from vnl.recording import nwb

    run = untrained_run(tmp_path / "run", "rodent_imitate")
    ds = record.record(run, episodes=2, steps=6)
    walker = np.isfinite(ds["reference_body_pos"].values[0, 0, :, 0])
    np.testing.assert_array_equal(np.flatnonzero(walker), env()._bodies)  # the walker's bodies, NaN elsewhere
    np.testing.assert_allclose(ds["reference_qpos"].values[:, 0], ds["qpos"].values[:, 0], atol=1e-6)
    np.testing.assert_allclose(
        ds["reference_body_pos"].values[:, 0][:, walker], ds["body_pos"].values[:, 0][:, walker], atol=1e-5
    )
    # Step t's reference is frame t after the start: the rat, untrained, drifts off it.
    ref = np.asarray(env()._ref["qpos"])
    for e in range(2):
        row = np.flatnonzero(np.all(np.abs(ref - ds["reference_qpos"].values[e, 0]) < 1e-6, axis=-1))
        clip, frame = np.unravel_index(row[0], ref.shape[:2])
        np.testing.assert_allclose(ds["reference_qpos"].values[e, 5], ref[clip, frame + 5], atol=1e-6)
    path = nwb.write(ds, tmp_path / "rec.nwb")
    from pynwb import NWBHDF5IO

    with NWBHDF5IO(str(path), "r") as io:
        behavior = io.read().processing["behavior"]
        reference = behavior["ReferencePoseEstimation"]
        torso = reference.pose_estimation_series["walker.torso"]
        body = list(ds["body"].values).index("walker/torso")
        np.testing.assert_allclose(torso.data[:6], ds["reference_body_pos"].values[0, :, body], atol=1e-6)
        assert "PoseEstimation" in behavior.data_interfaces
