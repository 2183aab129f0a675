"""Gaps corridor layouts: drawn in JAX per reset, dm_control's distributions, exact window boxes."""

import jax
import jax.numpy as jp
import numpy as np

from vnl.arenas import gaps

P = gaps.GapsParams()


def _layout(seed):
    return jax.device_get(gaps.sample_layout(jax.random.PRNGKey(seed), P))


def test_layouts_differ_across_keys_and_vmapped_envs():
    a, b = _layout(0), _layout(1)
    assert not np.allclose(a.length, b.length)
    batch = jax.vmap(lambda k: gaps.sample_layout(k, P))(jax.random.split(jax.random.PRNGKey(2), 8))
    assert len({tuple(np.round(np.asarray(s[:20]), 4)) for s in batch.start}) == 8


def test_layout_follows_dm_control_distributions():
    for seed in range(5):
        segs = gaps.layout_numpy(_layout(seed))
        starts = np.array([s for s, _ in segs])
        ends = np.array([e for _, e in segs])
        lengths = ends - starts
        assert starts[0] == 0 and starts.max() < P.corridor_length <= ends.max()
        assert ((lengths >= P.platform_length[0] - 1e-6) & (lengths <= P.platform_length[1] + 1e-6)).all()
        gap = starts[1:] - ends[:-1]
        in_start = starts[1:] < P.start_length
        # Platforms that begin inside the start region abut; later ones have dm_control's gaps.
        # (Within float32 round-off of the cumulative sums.)
        assert np.abs(gap[in_start & (ends[:-1] < P.start_length)]).max() < 1e-5
        later = gap[starts[1:] > P.start_length + P.platform_length[1]]
        assert ((later >= P.gap_length[0] - 1e-5) & (later <= P.gap_length[1] + 1e-5)).all() and len(later) > 30


def test_window_boxes_cover_exactly_the_platforms_near_the_walker():
    layout = _layout(3)
    segs = gaps.layout_numpy(layout)
    half = P.platform_length[0] / 2
    for x in (5.0, 9.3, 20.0):
        pos = np.asarray(gaps.place_window(layout, jp.float32(x), P))
        assert pos.shape == ((P.window + P.visual_ahead) * P.pieces, 3)
        i = int(gaps.platform_index(layout, jp.float32(x)))
        slots = range(i - P.behind, i - P.behind + P.window + P.visual_ahead)
        for k, slot in enumerate(slots):
            boxes = pos[k * P.pieces : (k + 1) * P.pieces]
            if slot < 0 or slot >= len(segs):
                assert (boxes[:, 2] == gaps.HIDDEN_Z).all()
                continue
            s, e = segs[slot]
            lo, hi = (boxes[:, 0] - half).min(), (boxes[:, 0] + half).max()
            np.testing.assert_allclose([lo, hi], [s, e], atol=1e-5)  # union = the platform
            # Top surface at z = 0; overlapping pieces a hair lower so no faces are coplanar.
            np.testing.assert_allclose(boxes[0, 2], -gaps.THICKNESS)
            assert (np.diff(boxes[:, 2]) < 0).all() and boxes[:, 2].min() > -gaps.THICKNESS - 1e-3
        # The platform under (or just behind) the walker is in the collidable window.
        assert segs[i][0] <= x


def test_on_platform():
    layout = _layout(4)
    (s0, e0), (s1, _) = [seg for seg in gaps.layout_numpy(layout) if seg[0] > P.start_length][:2]
    assert bool(gaps.on_platform(layout, jp.float32((s0 + e0) / 2)))
    assert not bool(gaps.on_platform(layout, jp.float32((e0 + s1) / 2)))
