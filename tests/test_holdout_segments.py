"""The held-out segments of a multiple-shooting fit (thsa_control.fit.shooting.held_out_segments): one in each block,
the last of each (every k-th, the default) or dithered (a place drawn from a fixed seed, so that a test profile that
repeats does not hide one phase from the fit)."""
import numpy as np
import pytest

from thsa_control.fit.identify import IdentificationSettings
from thsa_control.fit.shooting import held_out_segments, segment_layout


@pytest.mark.parametrize("layout", ["every_kth", "dithered"])
@pytest.mark.parametrize("M, every", [(200, 3), (201, 3), (202, 3), (57, 4), (10, 2)])
def test_one_segment_in_each_block_is_held_out(M, every, layout):
    h = held_out_segments(M, every, layout)
    blocks = M // every
    assert h.sum() == blocks
    assert all(h[b * every:(b + 1) * every].sum() == 1 for b in range(blocks))
    assert not h[blocks * every:].any()  # an incomplete last block holds none
    np.testing.assert_array_equal(h, held_out_segments(M, every, layout))  # the same fit, the same layout
    if layout == "every_kth":
        np.testing.assert_array_equal(np.flatnonzero(h), np.arange(every - 1, blocks * every, every))


def test_none_held_out_without_a_block():
    for layout in ("every_kth", "dithered"):
        assert not held_out_segments(200, 0, layout).any()
        assert not held_out_segments(2, 3, layout).any()


def test_an_unknown_layout_is_named():
    with pytest.raises(ValueError, match="'random'"):
        held_out_segments(200, 3, "random")
    with pytest.raises(ValueError, match="holdout_layout = 'random'"):
        IdentificationSettings(holdout_every=3, holdout_layout="random").validate()


def test_a_repeating_profile_shows_almost_every_phase_to_the_fit():
    """rig-sim's reversals under load repeat every 2.4 s, 48 segments of 50 ms: with every third segment held out,
    a third of the phases of the repeat (the breakaway after the reversal among them) were never fitted.  Now, for
    any repeat of a multiple of three segments that the record holds three times or more, at most a tenth of its
    phases are held out in every repeat (3**-R by chance)."""
    M = 200
    h = held_out_segments(M, 3, "dithered")
    every_third = held_out_segments(M, 3)
    for period in range(6, M // 3 + 1, 3):
        reps = M // period
        always = h[:reps * period].reshape(reps, period).all(axis=0).mean()
        old = every_third[:reps * period].reshape(reps, period).all(axis=0).mean()
        assert old == pytest.approx(1 / 3)
        assert always <= 0.1, (period, always)


@pytest.mark.parametrize("layout", ["every_kth", "dithered"])
def test_the_layout_holds_out_whole_segments(layout):
    t = np.arange(5001) * 0.002
    L, M, hold = segment_layout(t, IdentificationSettings(segment_duration=0.05, holdout_every=3,
                                                          holdout_layout=layout))
    assert (L, M) == (25, 201)
    seg = hold.reshape(M, L)
    assert np.all(seg.all(axis=1) | ~seg.any(axis=1))
    np.testing.assert_array_equal(seg[:, 0], held_out_segments(M, 3, layout))
