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
