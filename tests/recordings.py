"""Recording-shaped datasets and time series with planted structure, for the tests of the
analysis methods (vnl.neuro) and the recording model (vnl.recording)."""

import numpy as np
import xarray as xr
from scipy.stats import ortho_group

E, T = 6, 150


def ar1(rng, shape, rho=0.95):
    """Smooth random signals (..., T, k) along axis 1."""
    x = np.zeros(shape)
    x[:, 0] = rng.normal(size=(shape[0],) + shape[2:])
    for t in range(1, shape[1]):
        x[:, t] = rho * x[:, t - 1] + np.sqrt(1 - rho**2) * rng.normal(size=(shape[0],) + shape[2:])
    return x


def synthetic(seed=0, units=8, joints=4):
    """A recording-shaped dataset: smooth joint angles; unit 0 of policy_hidden_0 is a linear
    function of joint angle 1, the others noise; forward_speed a linear readout of
    policy_hidden_1; the last 20 steps of episode 0 inactive."""
    rng = np.random.default_rng(seed)
    angle = ar1(rng, (E, T, joints))
    h0 = ar1(rng, (E, T, units), rho=0.5)  # noise units: little autocorrelation, episode means near 0
    h0[..., 0] = 2.0 * angle[..., 1] + 0.5
    h1 = ar1(rng, (E, T, units))
    w = rng.normal(size=units)
    speed = h1 @ w + 0.05 * rng.normal(size=(E, T))
    active = np.ones((E, T))
    active[0, -20:] = 0
    et = ("episode", "time")
    return xr.Dataset(
        {
            "active": (et, active),
            "joint_angle": (et + ("joint",), angle),
            "joint_velocity": (et + ("joint",), np.gradient(angle, axis=1)),
            "forward_speed": (et, speed),
            "policy_hidden_0": (et + ("policy_hidden_0_unit",), h0),
            "policy_hidden_1": (et + ("policy_hidden_1_unit",), h1),
            "reward": (et, rng.normal(size=(E, T))),
        },
        coords={"episode": np.arange(E), "time": np.arange(T) * 0.02, "joint": [f"walker/j{i}" for i in range(joints)]},
        attrs={"env": "synthetic", "checkpoint_step": 0, "control_dt": 0.02},
    )


def planted_states(seed=0, k=3, dwell=25):
    """A sticky Markov chain of k states per episode and pose features drawn around each state's mean."""
    rng = np.random.default_rng(seed)
    truth = np.zeros((E, T), int)
    for e in range(E):
        s = rng.integers(k)
        for t in range(T):
            if rng.random() < 1 / dwell:
                s = (s + rng.integers(1, k)) % k
            truth[e, t] = s
    means = rng.normal(scale=2.0, size=(k, 5))
    pose = means[truth] + rng.normal(size=(E, T, 5))
    return truth, pose


def rotation(theta):
    return np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])


def lds(a, rng, trials=4, steps=150, units=32, noise=0.05):
    """Noisy linear dynamics x_{t+1} = a x_t + noise read out through a random tanh layer."""
    d = len(a)
    x = np.zeros((trials, steps, d))
    x[:, 0] = rng.normal(size=(trials, d))
    for t in range(1, steps):
        x[:, t] = x[:, t - 1] @ a.T + noise * rng.normal(size=(trials, d))
    return np.tanh(x @ rng.normal(size=(units, d)).T / np.sqrt(d))


def oscillator(rng, d=6, radius=0.97):
    """A damped rotation in d dims (pairs of planes), randomly oriented."""
    a = np.zeros((d, d))
    for i in range(d // 2):
        a[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = radius * rotation(rng.uniform(0.05, 0.5))
    q = ortho_group.rvs(d, random_state=int(rng.integers(1 << 30)))
    return q @ a @ q.T


def exportable(seed=0):
    """`synthetic` with what the NWB export writes beside the layers and behaviour (observation,
    action, the body's pose, the centre of mass, feet, gait phase): a recording-shaped dataset that
    `vnl.recording.nwb.write` takes, with episodes of different lengths."""
    ds = synthetic(seed)
    rng = np.random.default_rng(seed + 1)
    e, t = ds.sizes["episode"], ds.sizes["time"]
    ds["active"][1, -35:] = 0
    et = ("episode", "time")
    ds["observation"] = (et + ("observation_feature",), rng.normal(size=(e, t, 5)))
    ds["action"] = (et + ("actuator",), rng.uniform(-1, 1, size=(e, t, 3)))
    ds["body_pos"] = (et + ("body", "xyz"), ar1(rng, (e, t, 3, 3)))
    ds["com_velocity"] = (et + ("xyz",), ar1(rng, (e, t, 3)))
    ds["foot_contact"] = (et + ("end_effector",), (rng.random((e, t, 2)) < 0.5).astype(np.int8))
    ds["gait_phase"] = (et, np.where(rng.random((e, t)) < 0.1, np.nan, rng.random((e, t))))
    ds["walker_body"] = (("body",), np.array([0, 1, 1], np.int8))
    ds["body_parent"] = (("body",), np.array([0, 0, 1]))
    return ds.assign_coords(
        observation_feature=[f"obs[{i}]" for i in range(5)],
        actuator=[f"walker/a{i}" for i in range(3)],
        body=["world", "walker/torso", "walker/foot"],
        xyz=["x", "y", "z"],
        end_effector=["walker/foot_L", "walker/foot_R"],
    ).assign_attrs(run_dir="/nowhere/run", env="synthetic", seed=0, walker="rodent")


def nwb_session(
    path,
    units="spikes",
    behaviour=True,
    trials=True,
    spike_offset=0.0,
    pose_timestamps=False,
    seed=0,
):
    """A small lab NWB file (pynwb, ndx-pose): 40 s of a 2-D keypoint `nose` at 50 Hz (rate, or
    jittered `pose_timestamps`), a `speed` series, 4 trials of 8 s, and units: 6 units whose rate
    follows nose x (`units="spikes"`), a units table without spikes (`"empty"`), without a
    spike_times column (`"no_column"`), rates in processing/ecephys (`"rates"`) or none (None);
    spike times shifted by `spike_offset` s (another clock)."""
    from datetime import UTC, datetime

    from ndx_pose import PoseEstimation, PoseEstimationSeries
    from pynwb import NWBHDF5IO, NWBFile, TimeSeries
    from pynwb.behavior import BehavioralTimeSeries

    rng = np.random.default_rng(seed)
    n, rate = 2000, 50.0
    t = np.arange(n) / rate
    nose = 0.5 + 0.4 * ar1(rng, (1, n, 2), rho=0.99)[0]
    start = datetime(2026, 1, 1, tzinfo=UTC)
    f = NWBFile(session_description="a session", identifier=f"s{seed}", session_start_time=start)
    if behaviour:
        module = f.create_processing_module("behavior", "behaviour")
        clock = {"timestamps": t + rng.uniform(-0.002, 0.002, n)} if pose_timestamps else {"rate": rate}
        series = PoseEstimationSeries(
            name="nose", data=nose, unit="m", reference_frame="arena", confidence=np.ones(n), **clock
        )
        module.add(PoseEstimation(name="PoseEstimation", pose_estimation_series=[series], description="pose"))
        speed = TimeSeries(name="speed", data=np.abs(np.gradient(nose[:, 0])) * rate, unit="m/s", rate=rate)
        module.add(BehavioralTimeSeries(name="BehavioralTimeSeries", time_series=[speed]))
    if trials:
        for i in range(4):
            f.add_trial(start_time=10.0 * i, stop_time=10.0 * i + 8.0)
    lam = 5 + 30 * nose[:, 0]  # spikes/s
    if units in ("spikes", "empty"):
        for _ in range(6):
            hit = rng.random(n) < lam / rate
            f.add_unit(spike_times=(t[hit] + spike_offset) if units == "spikes" else [])
    elif units == "no_column":
        f.add_unit_column("quality", "a unit's quality")
        f.add_unit(quality="good")
    elif units == "rates":
        ecephys = f.create_processing_module("ecephys", "rates")
        ecephys.add(TimeSeries(name="rates", data=np.stack([lam, 2 * lam], axis=1), unit="Hz", rate=rate))
    with NWBHDF5IO(str(path), "w") as io:
        io.write(f)
    return path
