"""vnl.recording.timebase: the bins an NWB file is read on, spike counts and sampled series on them,
checked against direct computations and pynapple's own binning."""

import numpy as np
import pytest

from vnl.errors import VnlError
from vnl.recording import timebase


def test_bins_are_centred_on_the_grid_and_belong_to_the_first_episode_holding_their_centre():
    # grid 0.05 + k * 0.1; episodes [0, 1) and [0.7, 1.3) overlap; [2.06, 2.14) holds no centre
    g = timebase.grid(0.05, 0.1, np.array([[0.0, 1.0], [0.7, 1.3], [2.06, 2.14]]))
    np.testing.assert_allclose(g.centre[0], 0.05 + 0.1 * np.arange(10))
    np.testing.assert_allclose(g.centre[1, :3], [1.05, 1.15, 1.25])  # 0.75 .. 0.95 went to episode 0
    assert g.active.sum(1).tolist() == [10, 3, 0] and np.isnan(g.centre[1, 3:]).all()
    assert g.index()[1, :3].tolist() == [10, 11, 12] and (g.index()[2] == -1).all()


def test_an_episode_that_starts_on_a_sample_keeps_it_whatever_the_rounding():
    """0.14 / 0.02 is 7.000000000000001 and 0.27 / 0.03 is 9.000000000000002: the sample at an
    episode's start is kept, the one at its stop is not."""
    g = timebase.grid(0.0, 0.02, np.array([[0.14, 0.2]]))
    np.testing.assert_allclose(g.centre[0], [0.14, 0.16, 0.18])
    g = timebase.grid(0.0, 0.03, np.array([[0.0, 0.27]]))
    np.testing.assert_allclose(g.centre[0], np.arange(9) * 0.03)


def test_no_bin_inside_any_episode_is_refused():
    with pytest.raises(VnlError, match="no bin of 1 s"):
        timebase.grid(0.0, 1.0, np.array([[0.2, 0.4]]))
    with pytest.raises(VnlError, match="positive"):
        timebase.grid(0.0, 0.0, np.array([[0.0, 1.0]]))


def test_counts_match_a_direct_count_of_each_half_open_bin():
    rng = np.random.default_rng(0)
    trains = [np.sort(rng.uniform(0, 10, n)) for n in (50, 0, 300)]
    trains[0][:3] = [0.95, 1.05, 1.15]  # on bin edges: [c - w/2, c + w/2) takes its left edge
    times, ends = np.concatenate(trains), np.cumsum([len(t) for t in trains])
    g = timebase.grid(0.0, 0.1, np.array([[1.0, 4.0], [6.0, 9.5]]))
    counts = timebase.count(times, ends, g)
    for e in range(2):
        for j in np.nonzero(g.active[e])[0]:
            c = g.centre[e, j]
            for u, train in enumerate(trains):
                inside = ((train >= c - 0.05 - 1e-7) & (train < c + 0.05 - 1e-7)).sum()
                assert counts[e, j, u] == inside, (e, j, u)
    assert counts[..., 1].sum() == 0 and (counts[~g.active] == 0).all()


def test_counts_match_pynapple_on_the_same_bins():
    import pynapple as nap

    rng = np.random.default_rng(1)
    trains = {i: np.sort(rng.uniform(0, 20, 400)) for i in range(3)}
    g = timebase.grid(0.01, 0.02, np.array([[2.0, 8.0]]))
    counts = timebase.count(np.concatenate(list(trains.values())), np.cumsum([400] * 3), g)
    first = g.centre[0, 0]
    epoch = nap.IntervalSet(start=first - 0.01, end=first - 0.01 + 0.02 * g.active.sum())
    theirs = nap.TsGroup({i: nap.Ts(t) for i, t in trains.items()}).count(0.02, epoch)
    np.testing.assert_allclose(theirs.index.values, g.centre[0, g.active[0]], atol=1e-9)
    np.testing.assert_array_equal(theirs.values, counts[0, g.active[0]])


def test_a_series_is_read_unchanged_at_its_own_samples_and_linearly_between():
    t = np.arange(100) * 0.02 + 0.003  # sampled as t0 + k / rate
    v = np.stack([np.sin(t), t**2], axis=1)
    same = timebase.grid(t[0], timebase.sampling_interval(t), np.array([[0.0, 10.0]]))
    np.testing.assert_array_equal(timebase.interpolate(t, v, same)[0, :100], v)  # exact, not within rounding
    half = timebase.grid(t[0] + 0.01, 0.02, np.array([[0.0, 1.0]]))
    got = timebase.interpolate(t, v, half)[0, half.active[0]]
    np.testing.assert_allclose(got, (v[:-1] + v[1:])[: len(got)] / 2)


def test_a_series_is_nan_outside_its_span_and_across_a_gap():
    t = np.concatenate([np.arange(10), np.arange(20, 30)]) * 0.1  # tracking lost between 0.9 and 2.0 s
    v = np.arange(20.0)
    g = timebase.grid(0.0, 0.1, np.array([[0.0, 4.0]]))
    got = timebase.interpolate(t, v, g)[0, :, 0]
    assert np.isfinite(got[:10]).all() and np.isnan(got[10:20]).all() and np.isfinite(got[20:30]).all()
    assert np.isnan(got[30:]).all()  # after the series' last sample


def test_timestamps_that_go_back_or_too_few_are_refused():
    with pytest.raises(VnlError, match="not finite and increasing"):
        timebase.sampling_interval(np.array([0.0, 0.2, 0.1]), "pose")
    with pytest.raises(VnlError, match="has 1 sample"):
        timebase.sampling_interval(np.array([0.0]), "pose")
    assert timebase.sampling_interval(np.arange(5) * (1 / 30)) == pytest.approx(1 / 30, abs=1e-15)
    with pytest.raises(VnlError, match="median interval 0"):
        timebase.sampling_interval(np.array([0.0, 0.0, 0.0, 0.1]), "pose")
