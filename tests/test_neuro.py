"""vnl.neuro and vnl.behaviour on synthetic data with planted structure: encoding, decoding,
behavioural states, RDMs, DSA, the behaviour features' definitions and the CLI's input checks."""

import json

import numpy as np
import pytest
import xarray as xr
from scipy.spatial.distance import pdist
from scipy.stats import ortho_group

from vnl import behaviour, compare
from vnl.cli import main
from vnl.errors import VnlError
from vnl.neuro import decoding, dsa, encoding, features, similarity, states

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


def test_encoding_finds_the_planted_unit_and_nothing_else(tmp_path):
    ds = synthetic()
    result = encoding.encode(ds, ["policy_hidden_0"], ["joint_angle"], n_folds=3)
    r2 = result.r2["policy_hidden_0"]
    assert r2[0] > 0.99  # unit 0 = 2 * joint angle 1 + 0.5
    assert np.all(np.abs(r2[1:]) < 0.1)  # noise units: nothing to explain
    assert result.control_r2["policy_hidden_0"][0] < 0.3  # the features shifted in time explain little
    assert result.folds == 3 and result.samples == E * T - 20
    out = encoding.figure(result, tmp_path / "enc.png")
    assert out.stat().st_size > 5000
    doc = json.loads(json.dumps(result.to_json()))
    assert doc["layers"]["policy_hidden_0"]["r2"][0] == pytest.approx(r2[0])


def test_decoding_reads_the_planted_target_against_its_control(tmp_path):
    ds = synthetic()
    result = decoding.decode(ds, "policy_hidden_1", "forward_speed", n_folds=3, repeats=3)
    assert result.r2 > 0.95
    assert np.all(result.control_r2 < 0.3)
    assert len(result.control_r2) == 3
    # Only active steps enter: episode 0 contributes T - 20.
    assert (result.episode == 0).sum() == T - 20
    # A population that does not carry it decodes nothing.
    assert decoding.decode(ds, "policy_hidden_0", "forward_speed", n_folds=3).r2 < 0.1
    assert decoding.figure(result, tmp_path / "dec.png", 0.02).stat().st_size > 5000
    assert result.to_json()["control_r2_mean"] == pytest.approx(float(np.mean(result.control_r2)))


def test_decoding_targets_and_errors():
    ds = synthetic()
    y, labels = features.target(ds, "joint:j2")  # a joint by its short name
    np.testing.assert_array_equal(y[..., 0], ds["joint_angle"].values[..., 2])
    ds["gait_phase"] = (("episode", "time"), np.tile(np.arange(T) % 10 / 10, (E, 1)))
    y, labels = features.target(ds, "gait_phase")
    assert labels == ["cos(gait_phase)", "sin(gait_phase)"]
    np.testing.assert_allclose(y[0, 3], [np.cos(0.6 * np.pi), np.sin(0.6 * np.pi)])
    with pytest.raises(VnlError, match="no target 'nope'"):
        decoding.decode(ds, "policy_hidden_0", "nope")
    with pytest.raises(VnlError, match="no joint 'knee'"):
        features.target(ds, "joint:knee")
    with pytest.raises(VnlError, match="no layer"):
        decoding.decode(ds, "policy_hidden_9")
    with pytest.raises(VnlError, match="at least 2 episodes"):
        decoding.decode(ds.isel(episode=[1]), "policy_hidden_1")
    assert features.last_hidden_layer(ds) == "policy_hidden_1"


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


@pytest.mark.parametrize("method", ["hmm", "kmeans"])
def test_segmentation_recovers_a_planted_state_sequence(method):
    truth, pose = planted_states()
    labels = states.segment(pose.reshape(E * T, -1), [T] * E, 3, method)
    assert states.agreement(labels, truth.ravel()) > 0.95
    assert set(labels) == {0, 1, 2} and labels[0] == 0  # numbered by first appearance
    # Planted labels against a shuffled copy of themselves: near chance.
    shuffled = np.random.default_rng(1).permutation(truth.ravel())
    assert states.agreement(shuffled, truth.ravel()) < 0.5


def test_states_relate_layers_to_the_segmentation(tmp_path):
    truth, pose = planted_states()
    ds = synthetic()
    ds["joint_angle"] = (("episode", "time", "joint"), pose[..., :4])
    ds["forward_speed"] = (("episode", "time"), pose[..., 4])
    # policy_hidden_0 unit 0 follows the state; policy_hidden_1 does not.
    h0 = np.random.default_rng(2).normal(size=(E, T, 8)) * 0.1
    h0[..., 0] += truth
    ds["policy_hidden_0"] = (("episode", "time", "policy_hidden_0_unit"), h0)
    result = states.states(ds, 3, "hmm", n_folds=3)
    assert result.accuracy["policy_hidden_0"] > 0.9
    assert result.accuracy["policy_hidden_1"] < 0.6
    assert result.control_accuracy["policy_hidden_0"] < 0.6
    assert result.means["policy_hidden_0"].shape == (3, 8)
    assert states.figure(result, tmp_path / "s.png", 0.02).stat().st_size > 5000
    assert json.loads(json.dumps(result.to_json()))["states"] == 3


def test_controls_move_features_within_each_episode_only():
    ds = synthetic()
    s = features.samples(ds, ds["joint_angle"].values, ds["policy_hidden_0"].values, [], [])
    for kind in features.CONTROLS:
        order = features.control(s, kind, np.random.default_rng(0))
        assert np.array_equal(s.episode[order], s.episode)  # never across episodes
        assert sorted(order) == list(range(len(order)))  # a permutation
        assert np.mean(order != np.arange(len(order))) > 0.9
    order = features.control(s, "shift", np.random.default_rng(0))
    idx = np.nonzero(s.episode == 2)[0]
    shift = idx.tolist().index(order[idx[0]])  # a rotation: consecutive steps stay consecutive
    assert np.array_equal(order[idx], np.roll(idx, -shift))
    with pytest.raises(VnlError, match="unknown control"):
        features.control(s, "nope", np.random.default_rng(0))


def test_predictions_are_held_out_by_episode():
    # Each episode has its own offset, and the features say which episode a step is from: a model
    # scored on the episodes it was fitted on explains it all, one scored on held-out episodes nothing.
    rng = np.random.default_rng(0)
    episode = np.repeat(np.arange(6), 50)
    x = np.eye(6)[episode] + 0.01 * rng.normal(size=(300, 6))
    y = rng.normal(size=6)[episode][:, None]
    assert features.r2(y, features.ridge_predict(x, y, episode, 3))[0] < 0.05
    # The same regression does fit within episodes: a per-step signal it can read.
    within = np.concatenate([x, rng.normal(size=(300, 1))], axis=1)
    y2 = within[:, -1:] * 2.0
    assert features.r2(y2, features.ridge_predict(within, y2, episode, 3))[0] > 0.99


def test_r2_is_the_coefficient_of_determination():
    rng = np.random.default_rng(0)
    y = rng.normal(size=(50, 2))
    pred = y + rng.normal(scale=0.5, size=(50, 2))
    expected = 1 - ((y - pred) ** 2).sum(0) / ((y - y.mean(0)) ** 2).sum(0)
    np.testing.assert_allclose(features.r2(y, pred), expected)
    assert np.isnan(features.r2(np.ones((5, 1)), np.ones((5, 1))))[0]


# ---- behaviour features -----------------------------------------------------------------------


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


# ---- RDMs and DSA -----------------------------------------------------------------------------


def test_rdm_comparison_equals_a_direct_cosine_of_rdms():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(20, 6)), rng.normal(size=(20, 4))
    a = {"x": x, "y": y, "flat": np.ones((20, 3))}
    b = {"rotated": x @ ortho_group.rvs(6, random_state=1), "y": y}
    m = similarity.compare_layers(a, b, "euclidean", "cosine")
    ra, rb = pdist(x, "sqeuclidean"), pdist(y, "sqeuclidean")  # rsatoolbox's euclidean: squared, per unit
    direct = ra @ rb / np.linalg.norm(ra) / np.linalg.norm(rb)
    assert m[0, 1] == pytest.approx(direct, rel=1e-6)
    assert m[0, 0] == pytest.approx(1.0) and m[1, 1] == pytest.approx(1.0)  # rotation; itself
    assert np.isnan(m[2]).all()  # a constant layer has no RDM to compare
    with pytest.raises(VnlError, match="unknown RDM comparison"):
        similarity.compare_layers(a, b, "euclidean", "nope")


def rotation(theta):
    return np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])


@pytest.mark.parametrize("a,b", [(0.3, 0.5), (0.2, 1.0), (0.4, -0.4)])
def test_procrustes_of_rotations_matches_the_closed_form(a, b):
    # C R(b) C^T is R(b) or R(-b) for orthogonal C, so the angular distance is min(|a - b|, |a + b|).
    d, c = dsa.procrustes(rotation(a), rotation(b))
    assert d == pytest.approx(min(abs(a - b), abs(a + b)), abs=2e-3)
    np.testing.assert_allclose(c @ c.T, np.eye(2), atol=1e-5)


def test_procrustes_finds_a_hidden_change_of_basis():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(6, 6))
    q = ortho_group.rvs(6, random_state=3)
    assert dsa.procrustes(a, q @ a @ q.T)[0] < 0.01
    assert dsa.procrustes(a, rng.normal(size=(6, 6)))[0] > 0.3


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


def test_dsa_tells_same_dynamics_from_different_dynamics():
    rng = np.random.default_rng(0)
    a = oscillator(rng)
    x, y, z = lds(a, rng), lds(a, rng), lds(oscillator(rng, radius=0.7), rng)
    same, other = dsa.dsa(x, y, n_delays=5, rank=12), dsa.dsa(x, z, n_delays=5, rank=12)
    assert same < 0.5 * other
    # A rotation of the units is the same system exactly.
    assert dsa.dsa(x, x @ ortho_group.rvs(32, random_state=5), n_delays=5, rank=12) < 1e-3
    m = dsa.dsa_matrix({"x": x}, {"y": y, "z": z}, n_delays=5, rank=12)
    np.testing.assert_allclose(m, [[same, other]], atol=1e-6)


def test_hankel_embedding_and_havok_operator():
    x = np.arange(2 * 6 * 2, dtype=float).reshape(2, 6, 2)
    h = dsa.hankel(x, 3)
    assert h.shape == (2, 4, 6)
    np.testing.assert_array_equal(h[1, 0], np.concatenate([x[1, 2], x[1, 1], x[1, 0]]))  # newest first
    with pytest.raises(VnlError, match="too few"):
        dsa.hankel(x, 6)
    # A noiseless linear system's operator has the system's eigenvalues.
    a = 0.95 * rotation(0.3)
    s = np.zeros((3, 40, 2))
    s[:, 0] = np.random.default_rng(0).normal(size=(3, 2))
    for t in range(1, 40):
        s[:, t] = s[:, t - 1] @ a.T
    op = dsa.havok(s, n_delays=1, rank=2)
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(op)), np.sort_complex(np.linalg.eigvals(a)), atol=1e-8)


def network(name, layers):
    return compare.Network(name, __import__("pathlib").Path(name), 0, name, layers)


def test_compare_measures_rdm_and_dsa():
    rng = np.random.default_rng(0)
    x = lds(oscillator(rng), rng, trials=3, steps=60, units=8).reshape(180, 8)
    nets = [network("a", {"h": x}), network("b", {"h": x @ ortho_group.rvs(8, random_state=2)})]
    rdm = compare.compare(nets, "rdm", "euclidean", "test", comparison="corr")
    assert rdm.pairs[(0, 1)][0, 0] == pytest.approx(1.0) and rdm.comparison == "corr"
    d = compare.compare(nets, "dsa", source="test", trials=3, n_delays=3, rank=6)
    assert d.pairs[(0, 1)][0, 0] < 1e-3
    assert "DSA angular distance" in compare.table(d)
    mask = np.array([[1, 1, 1, 1, 0], [1, 1, 1, 0, 0]], bool)
    cut, length = compare.trial_mask(mask, 3)
    assert length == 3 and cut.sum(1).tolist() == [3, 3]
    with pytest.raises(VnlError, match="at least 5 steps"):
        compare.trial_mask(mask, 5)


# ---- the CLI's input checks (no heavy imports, exit 2 with one line) ------------------------


def test_cli_rejects_mistakes_with_one_line(tmp_path, capsys):
    rec = tmp_path / "rec.nc"
    synthetic().to_netcdf(rec, engine="h5netcdf")
    cases = [
        (["analyze", str(rec), "--method", "decoding", "--target", "nope"], "no target 'nope'"),
        (["analyze", str(rec), "--method", "encoding", "--layer", "nope"], "no layer 'nope'"),
        (["analyze", str(rec), "--method", "states", "--color", "reward"], "--color colours the PCA"),
        (["analyze", str(tmp_path / "x.nwb"), "--method", "encoding"], "not found"),
        (["record", "--from", str(rec), "--format", "netcdf"], "--from converts"),
        (["record", str(tmp_path), "--format", "nwb", "--out", str(tmp_path / "r.nc")], "ends in .nc"),
        (["record"], "give the run directory"),
        (["compare", "a", "b", "--measure", "rdm", "--rdm-comparison", "nope"], "unknown RDM comparison"),
        (["compare", "a", "b", "--measure", "dsa", "--rsa", "euclidean"], "cannot be combined"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (argv, err)
