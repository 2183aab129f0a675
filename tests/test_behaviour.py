"""vnl.recording.behaviour: the behaviour features' definitions."""

import numpy as np
import pytest

from vnl.recording import behaviour


def test_gait_phase_rises_linearly_between_touchdowns():
    contact = np.array([[0, 1, 1, 0, 0, 1, 1, 1, 0, 1, 0]])
    active = np.ones_like(contact, bool)
    np.testing.assert_array_equal(behaviour.touchdowns(contact, active)[0], [0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0])
    phase = behaviour.gait_phase(contact, active)[0]
    np.testing.assert_allclose(phase[1:9], [0, 0.25, 0.5, 0.75, 0, 0.25, 0.5, 0.75])
    assert np.isnan(phase[0]) and np.isnan(phase[9:]).all()  # before the first, after the last touchdown
    # A touchdown needs the step before to be active too.
    active[0, :5] = False
    assert not behaviour.touchdowns(contact, active)[0, 5]


def test_gap_distance_from_the_corridor_layout():
    # Platforms [0, 1], [1, 2] (no gap), [2.5, 3], then unused slots: one gap, from 2 to 2.5.
    start = np.array([[0.0, 1.0, 2.5, np.inf]])
    length = np.array([[1.0, 1.0, 0.5, 1.0]])
    x = np.array([[0.2, 1.9, 2.2, 2.6]])
    np.testing.assert_allclose(behaviour.gap_distance(start, length, x)[0], [1.8, 0.1, 0.0, np.nan])


def test_gap_time_counts_down_to_the_next_gap():
    # Episode 0 reaches a gap at steps 3-4 and another at 7; episode 1 ends (inactive) before its gap.
    nan = np.nan
    distance = np.array([[0.3, 0.2, 0.1, 0.0, 0.0, 0.4, 0.2, 0.0, 0.5], [0.3, 0.2, 0.1, 0.05, 0.0, 0, 0, 0, 0]])
    active = np.ones(distance.shape, bool)
    active[1, 4:] = False
    t = behaviour.gap_time(distance, active, dt=0.5)
    np.testing.assert_allclose(t[0], [1.5, 1.0, 0.5, 0.0, 0.0, 1.0, 0.5, 0.0, nan])
    np.testing.assert_allclose(t[1], [nan] * 9)


def test_forward_speed_is_along_the_heading():
    v = np.array([[1.0, 2.0, 5.0]])
    yaw = np.pi / 2  # facing +y
    quat = np.array([[np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]])
    assert behaviour.forward_speed(v, quat)[0] == pytest.approx(2.0)
    assert behaviour.forward_speed(v, np.array([[1.0, 0, 0, 0]]))[0] == pytest.approx(1.0)


def test_events_count_falls_but_not_blow_ups_and_only_while_active():
    done = np.array([[0, 0, 1, 1], [0, 1, 1, 1]])
    active = np.array([[1, 1, 1, 0], [1, 1, 0, 0]])
    metrics = {"physics_nan": np.array([[0, 0, 0, 0], [0, 1, 0, 0]]), "measure/gaps_crossed": np.ones((2, 4))}
    ev = behaviour.events(metrics, done, active)
    np.testing.assert_array_equal(ev["fall"], [[0, 0, 1, 0], [0, 0, 0, 0]])
    np.testing.assert_array_equal(ev["gap_crossed"], active)
    assert "bowl_left" not in ev


@pytest.mark.slow
@pytest.mark.xdist_group("neuro_record")
def test_behaviour_features_agree_with_the_task(rat_recording):
    run, ds, _, _ = rat_recording
    active = ds["active"].values > 0
    # The task's x_velocity (the root subtree's COM velocity after step t, in JAX) is the host
    # replay's com_velocity of the next state.
    both = active[:, 1:] & active[:, :-1]
    np.testing.assert_allclose(
        ds["com_velocity"].values[:, 1:, 0][both], ds["x_velocity"].values[:, :-1][both], rtol=1e-3, atol=1e-3
    )
    # Facing +x at spawn: the forward speed starts as the x velocity.
    np.testing.assert_allclose(ds["forward_speed"].values[:, 0], ds["com_velocity"].values[:, 0, 0], atol=0.05)
    # A foot in contact is low: its lowest body point near the platforms' top (z = 0).
    contact = ds["foot_contact"].values > 0
    assert contact.any() and (~contact).any()
    feet = [list(ds["body"].values).index(b) for b in ds["end_effector"].values]
    z = ds["body_pos"].values[:, :, feet, 2]
    assert np.median(z[contact]) < np.median(z[~contact & active[..., None]])
    # Events are the task's measures while the episode runs; a fall ends the episode.
    assert ds["event_gap_crossed"].values.sum() == ds["measure_gaps_crossed"].values[active].sum()
    falls = ds["event_fall"].values
    assert (falls.sum(1) <= 1).all() and all(
        not active[e, t + 1 :].any() for e, t in zip(*np.nonzero(falls), strict=True)
    )
    # The gap distance is measured from the episode's own corridor.
    assert np.nanmin(ds["gap_distance"].values) >= 0 and np.isfinite(ds["gap_distance"].values[active]).any()
    # The time to the next gap comes from the gap distance at the task's control step (this
    # untrained rat never reaches a gap: NaN throughout; test_gap_time_of_a_body_that_reaches_a_gap).
    expected = behaviour.gap_time(ds["gap_distance"].values, active, ds.attrs["control_dt"])
    np.testing.assert_array_equal(ds["gap_time"].values, expected)
    assert ds.attrs["walker"] == "rodent" and ds["walker_body"].values.sum() > 30
    assert ds["joint_angle"].shape[-1] == len(ds["joint"]) > 30


@pytest.mark.slow
@pytest.mark.xdist_group("neuro_record")
def test_gap_time_of_a_body_that_reaches_a_gap(rat_recording):
    """`variables` on the recording's states with the root body moved along x across a gap (from
    0.5 to 1.0 m): the time to the gap counts down in the env's control steps to 0 at 0.5 m."""
    run, ds, _, _ = rat_recording
    e_, t_ = ds["active"].shape
    root = int(run.env.unwrapped.root_body_id)
    body_pos = ds["body_pos"].values.copy()
    body_pos[:, :, root, 0] = np.linspace(0.0, 0.8, t_)
    raw = {k: ds[k].values for k in ("qpos", "qvel", "body_quat", "active", "done")}
    raw.update(body_pos=body_pos, metrics={}, active=np.ones((e_, t_), np.int8))
    raw.update(layout_start=np.tile([0.0, 1.0], (e_, 1)), layout_length=np.tile([0.5, 5.0], (e_, 1)))
    out, _, _ = behaviour.variables(run.env, raw)
    reached = int(np.argmax(np.linspace(0.0, 0.8, t_) >= 0.5))
    time = out["gap_time"][1]
    np.testing.assert_allclose(time[:, 0], reached * run.env.dt)
    np.testing.assert_allclose(time[:, reached:], 0.0)  # over the gap to the end
    np.testing.assert_allclose(np.diff(time[:, : reached + 1], axis=1), -run.env.dt)
