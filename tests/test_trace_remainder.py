"""The tracer's judgement of what a fit leaves (issue #21): base transients, structured against base-like
remainders, the ambiguity gap's autocorrelation factor and the concentration of a held-out drop.

Analytic cases on synthetic series: fast.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binom

from thsa_control.trace.scoring import _holdout_iact
from thsa_control.trace import TraceSettings
from thsa_control.trace.scoring import _holdout_segment_changes, admission_tests
from thsa_control.trace.signature import (
    SignatureSettings,
    base_transients,
    position_local_test,
    remainder_kind,
    split_remainder,
)


def _trim(n=5000, dt=2e-3):
    """A trim run: still, extend at constant speed, stop, retract, stop (speed in rad/s, load 30 kN)."""
    t = np.arange(n) * dt
    w = np.zeros(n)
    w[(t > 1.0) & (t < 4.5)] = 50.0
    w[(t > 5.5) & (t < 9.0)] = -50.0
    return t, w, np.full(n, 30e3)


def test_base_transients_cover_starts_stops_and_load_changes_only():
    t, w, f = _trim()
    tr = base_transients(t, w, f, 0.3)
    for event in (1.0, 4.5, 5.5, 9.0):  # every start and stop, within 0.3 s either side
        near = np.abs(t - event) < 0.29
        assert tr[near].all(), event
    steady = ((t > 1.4) & (t < 4.1)) | ((t > 5.9) & (t < 8.6))
    assert not tr[steady].any()
    f2 = f.copy()
    f2[t > 3.0] = 20e3  # a load step in the middle of the extension
    tr2 = base_transients(t, w, f2, 0.3)
    assert tr2[np.abs(t - 3.0) < 0.29].all() and not tr2[(t > 1.4) & (t < 2.6)].any()


def test_a_creep_below_five_per_cent_ends_in_a_stop_at_the_motion_band():
    """A position loop's approach: fast travel (500 rad/s), a slow deceleration into a creep at 2 % of it (10 rad/s)
    for 1.2 s, then the stop.  With the default band (5 % of the top speed, 25 rad/s) the creep counts as "stopped",
    so its end is no event and the samples before and after it are steady; with ``motion_band`` (the band a window
    calls motion) the creep's end is a stop (within 0.3 s either side), and the band's crossings of 5 % stay events
    (the operating point changes there)."""
    dt = 2e-3
    t = np.arange(0, 6.0, dt)
    w = np.zeros_like(t)
    w[(t >= 0.5) & (t < 2.0)] = 500.0
    dec = (t >= 2.0) & (t < 3.0)  # 490 rad/s over 1 s: below the fast-change rule's 0.5 x 500 rad/s per s
    w[dec] = 500.0 - 490.0 * (t[dec] - 2.0)
    w[(t >= 3.0) & (t < 4.2)] = 10.0
    f = np.full_like(t, 10e3)
    creep_end = np.abs(t - 4.2) < 0.29
    default = base_transients(t, w, f, 0.3, sustained=True)
    banded = base_transients(t, w, f, 0.3, sustained=True, motion_band=1.0)
    assert not default[creep_end & (t < 4.0)].any()  # the creep before its end: steady by the 5 % band
    assert banded[creep_end].all()
    crossing = t[np.flatnonzero((w[:-1] > 25.0) & (w[1:] <= 25.0))[0] + 1]  # 5 % of 500 rad/s, in the deceleration
    near = np.abs(t - crossing) < 0.29
    assert default[near].all() and banded[near].all()
    assert (banded | ~default).all()  # the band adds events, it removes none
    mid_creep = (t > 3.35) & (t < 3.85)
    assert not banded[mid_creep].any()


def test_position_feature_at_the_start_position_is_not_local_once_transients_are_masked():
    """A trim run starts and stops at the same position: a start/stop transient repeats there over passes and the
    pass-replicated test takes it for a position feature; outside the base's transients it does not, while a bump
    in the middle of the stroke is still found."""
    rng = np.random.default_rng(0)
    t, w, f = _trim()
    x = np.cumsum(w) * 2e-3 * 1e-4  # nut position [m]
    d = np.sign(np.where(np.abs(w) > 1, w, 0))
    transient = np.zeros_like(t)
    for ev in (1.0, 4.5, 5.5, 9.0):
        transient += 0.3 * np.exp(-np.abs(t - ev) / 0.05)
    e = transient + 0.01 * rng.standard_normal(t.size)
    tr = base_transients(t, w, f, 0.3)
    assert position_local_test(e, x, d)["significant"]  # the start/stop positions look local
    assert not position_local_test(np.where(tr, np.nan, e), x, d)["significant"]
    xm = 0.5 * (x.min() + x.max())
    bump = 0.1 * np.exp(-0.5 * ((x - xm) / 1e-3) ** 2)
    assert position_local_test(np.where(tr, np.nan, e + bump), x, d)["significant"]


def test_remainder_kinds():
    s = SignatureSettings()
    assert remainder_kind({"variable": "nut_position (repeated over passes)"}, 0.0, s) == "structured"
    assert remainder_kind({"variable": "motor_angle"}, 0.0, s) == "structured"
    assert remainder_kind({"variable": "time (slow drift)"}, 0.0, s) == "structured"
    assert remainder_kind({"variable": "quadrant"}, 0.0, s) == "base"
    assert remainder_kind({"variable": "time_since_reversal"}, 0.0, s) == "base"
    assert remainder_kind({"variable": "temperature"}, 0.4, s) == "base"  # a warming run: a proxy for time
    assert remainder_kind({"variable": "temperature"}, 40.0, s) == "structured"
    sig = {"tests": [{"variable": "quadrant", "significant": True, "remainder": "base"},
                     {"variable": "motor_angle", "significant": False, "remainder": "structured"}],
           "sensors": [{"variable": "motor_speed vs gear_ratio x screw_speed", "significant": True}]}
    structured, base = split_remainder(sig)
    assert [t["variable"] for t in structured] == ["motor_speed vs gear_ratio x screw_speed"]
    assert [t["variable"] for t in base] == ["quadrant"]


def _fit(sim, meas, hold, starts, t):
    return {"predictions": {"r": {"time": t, "measured": {"motor_speed": meas}, "simulated": {"motor_speed": sim},
                                  "holdout": hold, "segment_starts": starts}}}


def test_holdout_iact_is_one_for_white_noise_and_grows_with_correlation():
    rng = np.random.default_rng(1)
    n = 6000
    t = np.arange(n) * 1e-3
    hold = (np.arange(n) // 50) % 3 == 2
    starts = t[::50]
    white = rng.standard_normal(n)
    assert _holdout_iact(_fit(np.zeros(n), white, hold, starts, t), {"motor_speed": 1.0}) == pytest.approx(1.0, abs=0.3)
    ar = np.zeros(n)
    for k in range(1, n):  # AR(1), rho 0.9: tau = (1 + rho) / (1 - rho) = 19
        ar[k] = 0.9 * ar[k - 1] + white[k]
    tau = _holdout_iact(_fit(np.zeros(n), ar, hold, starts, t), {"motor_speed": 1.0})
    assert 8 < tau < 30, tau


def test_holdout_segment_changes_count_and_concentrate():
    n = 600
    t = np.arange(n) * 1e-3
    hold = (np.arange(n) // 50) % 3 == 2  # segments 2, 5, 8, 11 held out
    starts = t[::50]
    meas = np.ones(n)
    before = _fit(np.zeros(n), meas, hold, starts, t)
    sim = np.full(n, 0.5)  # every held-out segment improves ...
    sim[(np.arange(n) // 50) == 11] = 10.0  # ... but one much worse
    d = _holdout_segment_changes(before, _fit(sim, meas, hold, starts, t), {"motor_speed": 1.0})
    assert d["segments"] == 4 and d["improved"] == 3 and d["worse"] == 1
    assert d["top3_share"] > 0.95 and d["median_drop"] > 0
    # the sign test: 3 improved of 4 is not beyond chance (P(X >= 3 | n 4, p 1/2) = 5/16)
    assert d["sign_p"] == pytest.approx(5 / 16)


def _held_out_record(n, seg):
    """A record of ``n`` samples in segments of ``seg``, every third held out, measured 1 where the model before says
    0: ``(t, segment index per sample, held-out mask, segment starts, measured, fit before)``."""
    t = np.arange(n) * 1e-3
    k = np.arange(n) // seg
    hold = k % 3 == 2
    starts = t[::seg]
    meas = np.ones(n)
    return t, k, hold, starts, meas, _fit(np.zeros(n), meas, hold, starts, t)


def test_holdout_segment_changes_inside_a_window_and_the_sign_test():
    """Only segments with samples in the window count; a change carried by a few segments does not pass the sign
    test, one that improves every segment does."""
    n, seg = 3000, 50
    t, k, hold, starts, meas, before = _held_out_record(n, seg)  # 20 held-out segments
    window = {"r": k < 30}  # the first 30 segments: 10 held out
    few = np.zeros(n)
    few[np.isin(k, (2, 5))] = 1.0  # two segments fixed, the others as before (no change: ties, left out)
    few[np.isin(k, (8, 11, 14))] = -0.2  # three slightly worse
    d = _holdout_segment_changes(before, _fit(few, meas, hold, starts, t), {"motor_speed": 1.0})
    assert d["improved"] == 2 and d["worse"] == 3 and d["sign_p"] > 0.5
    every = np.full(n, 0.5)
    d = _holdout_segment_changes(before, _fit(every, meas, hold, starts, t), {"motor_speed": 1.0}, window)
    assert d["segments"] == 10 and d["improved"] == 10 and d["sign_p"] == pytest.approx(0.5 ** 10)
    d = _holdout_segment_changes(before, _fit(every, meas, hold, starts, t), {"motor_speed": 1.0})
    assert d["segments"] == 20 and d["sign_p"] < 1e-5


def test_signed_rank_weighs_a_segment_by_its_change_and_still_refuses_a_drop_few_segments_carry():
    """The robustness test of a constant torque (TraceSettings.robust_test).  Where the candidate improves most
    segments clearly and worsens the rest a little (a constant torque on a base that differs: small coin flips where
    it matters little), the sign test counts only the votes, 38 of 60 (p 0.026), and refuses; the signed-rank test
    weighs the clear improvements and admits (p < 1e-5).  A drop carried by three segments with the other 57 a little
    worse fails both."""
    n, seg = 9000, 50
    t, k, hold, starts, meas, before = _held_out_record(n, seg)  # 60 held-out segments
    held = np.unique(k[hold])
    clear = np.full(n, -0.1)  # a little worse (1.21 against 1 per sample) ...
    clear[np.isin(k, held[:38])] = 0.5  # ... 38 segments clearly better (0.25 against 1)
    d = _holdout_segment_changes(before, _fit(clear, meas, hold, starts, t), {"motor_speed": 1.0})
    assert (d["improved"], d["worse"]) == (38, 22)
    assert d["sign_p"] == pytest.approx(binom.sf(37, 60, 0.5)) and d["sign_p"] > 1e-3
    assert d["signed_rank_p"] < 1e-5
    # the admission rule reads the test the settings name
    after = {**_fit(clear, meas, hold, starts, t), "aic": 0.0}
    common = dict(k=1, alpha=1e-3, mask=None, window=None, channel="motor_speed", min_window_reduction=0.5,
                  max_channel_increase=0.1, robust=True)
    by = {test: admission_tests({**before, "aic": 1.0}, after, {"motor_speed": 1.0}, robust_test=test, **common)
          for test in ("sign", "signed-rank")}
    assert "sign test p = 0.026" in by["sign"]["robust_fail"] and by["signed-rank"]["robust_fail"] is None
    with pytest.raises(ValueError, match="robust_test 'median'"):
        admission_tests({**before, "aic": 1.0}, after, {"motor_speed": 1.0}, robust_test="median", **common)
    # and the settings refuse an unknown test before any fit
    with pytest.raises(ValueError, match="TraceSettings.robust_test = 'median'"):
        TraceSettings(robust_test="median").validate()
    few = np.full(n, -0.1)
    few[np.isin(k, held[:3])] = 1.0  # three segments fixed, every other one a little worse
    d = _holdout_segment_changes(before, _fit(few, meas, hold, starts, t), {"motor_speed": 1.0})
    assert (d["improved"], d["worse"]) == (3, 57) and d["sign_p"] > 0.5 and d["signed_rank_p"] > 0.5


def test_a_constant_torque_on_too_few_segments_is_refused_as_undecidable_not_as_inconsistent():
    """Both robustness tests are smallest with every segment improved, at 2^-n: at alpha 1e-3 a window with nine
    held-out segments that the candidate changes cannot pass however clear they are, and the refusal says so (with
    what would hold enough: ten held-out segments, one in three of 50 ms, 1.5 s); with ten, all improved, the
    signed-rank test passes (p 2^-10 = 9.8e-4) and nothing is reported."""
    n, seg = 3000, 50
    t, k, hold, starts, meas, before = _held_out_record(n, seg)  # 20 held-out segments
    every = {**_fit(np.full(n, 0.5), meas, hold, starts, t), "aic": 0.0}
    common = dict(k=1, alpha=1e-3, channel="motor_speed", min_window_reduction=0.5, max_channel_increase=0.1,
                  robust=True)
    for in_window, passes in ((9, False), (10, True)):
        window = {"r": k < 3 * in_window}  # in_window held-out segments
        adm = admission_tests({**before, "aic": 1.0}, every, {"motor_speed": 1.0}, mask=window, window=window,
                              **common)
        assert adm["window_segments"]["segments"] == adm["window_segments"]["improved"] == in_window
        if passes:
            assert adm["robust_fail"] is None and "robust_too_few_segments" not in adm, adm["robust_fail"]
        else:
            assert adm["robust_too_few_segments"] == {"segments": 9, "needed": 10, "smallest_p": 0.5 ** 9}
            assert "too few segments to decide" in adm["robust_fail"] and "9 of 9" in adm["robust_fail"]
    # a refusal on enough segments is no shortness: 12 of 20 improved, the rest worse
    mixed = np.full(n, -0.1)
    mixed[np.isin(k, np.unique(k[hold])[:12])] = 0.5
    adm = admission_tests({**before, "aic": 1.0}, {**_fit(mixed, meas, hold, starts, t), "aic": 0.0},
                          {"motor_speed": 1.0}, mask=None, window=None, **common)
    assert adm["robust_fail"] and "robust_too_few_segments" not in adm and "too few" not in adm["robust_fail"]


def _trim_xd():
    t, w, f = _trim()
    x = np.cumsum(w) * 2e-3 * 1e-4  # nut position [m]: 17.5 mm out and back
    d = np.sign(np.where(np.abs(w) > 1, w, 0))
    return t, w, f, x, d


def test_friction_bump_crossed_each_way_is_local_although_its_sign_follows_the_motion():
    """A friction bump opposes the motion: the missing torque it leaves is -T at the bump when extending and +T
    when retracting.  Averaged over the two passes it cancels; the test of the dissipative law (the residual
    times the direction) finds it, and names the law."""
    rng = np.random.default_rng(3)
    t, w, f, x, d = _trim_xd()
    tr = base_transients(t, w, f, 0.3)
    xm = 0.5 * (x.min() + x.max())
    bump = -0.1 * np.exp(-0.5 * ((x - xm) / 1.5e-3) ** 2) * d  # opposes the motion
    base = 0.025 * (d > 0)  # a direction-dependent base drag the declared model lacks
    e = np.where(tr, np.nan, base + bump + 0.01 * rng.standard_normal(t.size))
    r = position_local_test(e, x, d)
    assert r["significant"] and r["law"].startswith("dissipative"), r
    assert r["peak_bin"][0] - 2e-3 <= xm <= r["peak_bin"][1] + 2e-3, (r["peak_bin"], xm)
    assert not position_local_test(np.where(tr, np.nan, base + 0.01 * rng.standard_normal(t.size)), x, d)["significant"]


def test_slow_drift_in_time_is_not_a_position_feature():
    """Within a pass time and position advance together, and on the way back a drift in time is a trend in
    position of the other sign: times the direction, the same trend.  The per-pass trend is nuisance, so a
    drift is not called local."""
    rng = np.random.default_rng(4)
    t, w, f, x, d = _trim_xd()
    tr = base_transients(t, w, f, 0.3)
    e = np.where(tr, np.nan, 0.01 * t + 0.005 * rng.standard_normal(t.size))
    r = position_local_test(e, x, d)
    assert r is not None and not r["significant"], r


@pytest.mark.parametrize("shapes", [None, {"screw_friction_ripple": 12e-3}])
def test_position_test_false_alarm_rate_is_its_level(shapes):
    """Calibration: on residuals without a position feature (noise correlated over a few samples, per-pass
    offsets and slopes), the test rejects at its nominal level: at alpha = 0.05 over 300 seeds the rejection rate
    lies inside the binomial 99.9 % band around 5 %; also tested beyond an added ripple's shape (its two degrees of
    freedom taken from the bins')."""
    from scipy.stats import binom

    t, w, f, x, d = _trim_xd()
    tr = base_transients(t, w, f, 0.3)
    n, alpha, hits = 300, 0.05, 0
    kernel = np.ones(5) / 5  # correlated over 5 samples (0.15 mm at this speed), well inside a 2 mm bin
    for seed in range(n):
        rng = np.random.default_rng(100 + seed)
        noise = np.convolve(rng.standard_normal(t.size), kernel, mode="same")
        trend = np.where(d > 0, rng.normal() + rng.normal() * t, rng.normal() + rng.normal() * t) * 0.01
        r = position_local_test(np.where(tr, np.nan, noise + trend), x, d, alpha=alpha, shapes=shapes)
        hits += bool(r["significant"])
    lo, hi = binom.ppf(0.0005, n, alpha), binom.ppf(0.9995, n, alpha)
    assert lo <= hits <= hi, (hits, lo, hi)


def _segments(rng, level=(0.02, 0.0), slope=(0.0, 0.0), sd=0.003, seg=0.05):
    """Per-segment missing torques of a trim run's two steady passes (extend 1.4..4.1 s, retract 5.9..8.6 s)."""
    from thsa_control.trace.signature import drift_test  # noqa: F401  (imported by the tests)

    tm, y, d = [], [], []
    for (a, b), lv, sl, sgn in zip(((1.4, 4.1), (5.9, 8.6)), level, slope, (1.0, -1.0)):
        mid = np.arange(a + seg / 2, b, seg)
        tm += list(mid)
        y += list(lv + sl * (mid - mid.mean()) + sd * rng.standard_normal(mid.size))
        d += [sgn] * mid.size
    return np.array(tm), np.array(y), np.array(d)


def test_drift_test_takes_levels_per_pass_as_nuisance_and_finds_a_drift_of_either_sign():
    """An extension followed by a retraction with different constant remainders (a base's direction dependence)
    is no drift (a regression on time over the record would call it one); a drift whose sign differs between
    the passes (a load-cell zero seen through the load torque driving, through the no-back's drag back-driven)
    is found, with its slopes."""
    from thsa_control.trace.signature import drift_test

    rng = np.random.default_rng(5)
    r = drift_test(*_segments(rng, level=(0.03, -0.01)))
    assert not r["significant"] and r["passes"] == 2, r
    r = drift_test(*_segments(rng, slope=(0.01, -0.008)))
    assert r["significant"], r
    assert r["slopes"][0] == pytest.approx(0.01, abs=4 * r["slope_stderr"][0])
    assert r["slopes"][1] == pytest.approx(-0.008, abs=4 * r["slope_stderr"][1])


def test_a_speed_step_inside_a_pass_is_no_drift_once_the_passes_are_cut_at_the_command():
    """A remainder that depends on the speed (a Stribeck drag of another rig's base, 0.01 N m per step of the
    command) on a pass whose command steps down halfway without a stop: over the pass the step reads as a slope in
    time (significant); cut at the command (the segments' constant speed command), each pass is one level, and a
    real drift on the same passes is still found."""
    from thsa_control.trace.signature import drift_test

    rng = np.random.default_rng(7)
    tm, y, d = _segments(rng, level=(0.02, -0.01))
    cmd = np.where(d > 0, np.where(tm < 2.75, 60.0, 30.0), np.where(tm < 7.25, -60.0, -30.0))
    y = y + 0.01 * (np.abs(cmd) == 60.0)
    assert drift_test(tm, y, d, alpha=1e-4)["significant"]
    r = drift_test(tm, y, d, cmd, alpha=1e-4)
    assert r["passes"] == 4 and not r["significant"], r
    r = drift_test(tm, y + 0.01 * tm, d, cmd, alpha=1e-4)
    assert r["passes"] == 4 and r["significant"], r
    assert all(v == pytest.approx(0.01, abs=4 * e) for v, e in zip(r["slopes"], r["slope_stderr"])), r
    # a command ramping by 0.2 % from segment to segment (11 % over a pass) is cut wherever it has moved 0.5 %: three
    # segments a piece, too few for a pass
    ramp = d * 60.0 * 1.002 ** np.r_[np.arange(np.sum(d > 0)), np.arange(np.sum(d < 0))]
    assert drift_test(tm, y + 0.01 * tm, d, alpha=1e-4)["significant"]
    assert drift_test(tm, y + 0.01 * tm, d, ramp, alpha=1e-4) is None


def test_command_level_is_the_segments_command_where_it_is_one_constant():
    """A velocity-loop plateau (the command constant, or within 0.5 % of it) has one level; a proportional position
    loop's command over one 50 ms segment (1.8 1/s: 9 % decay), a zero command, a gap in the record have none."""
    from thsa_control.trace.signature import COMMAND_RTOL, command_level

    assert command_level(np.full(50, -62.5)) == -62.5
    assert command_level(62.5 * (1 + 0.9 * COMMAND_RTOL * np.sin(np.arange(50)))) == pytest.approx(62.5, rel=COMMAND_RTOL)
    assert command_level(150.0 * np.exp(-1.8 * np.arange(50) * 1e-3)) is None
    assert command_level(np.zeros(50)) is None
    assert command_level(np.r_[np.full(25, 62.5), np.nan, np.full(24, 62.5)]) is None


def test_drift_test_false_alarm_rate_is_its_level():
    """Calibration over 400 seeds of per-pass levels and white segment noise: the rejection rate at alpha = 0.05
    lies inside the binomial 99.9 % band."""
    from scipy.stats import binom

    from thsa_control.trace.signature import drift_test

    n, alpha = 400, 0.05
    hits = sum(drift_test(*_segments(np.random.default_rng(1000 + k), level=(0.02, -0.01)), alpha=alpha,
                          min_r2=0.0)["significant"] for k in range(n))
    assert binom.ppf(0.0005, n, alpha) <= hits <= binom.ppf(0.9995, n, alpha), hits


def test_segment_torques_recover_the_missing_torque_from_each_segments_speed_slope():
    """A constant missing torque T makes the speed residual of every segment grow at T / J from the segment's own
    (free) offset; each segment's estimate is J times that slope."""
    from thsa_control.trace.signature import segment_torques

    dt, J, T = 2e-3, 4e-4, 0.05
    t = np.arange(1000) * dt
    starts = np.arange(0, 1000, 25)
    e = np.zeros_like(t)
    for k, a in enumerate(starts):
        e[a:a + 25] = (k % 3 - 1) * 0.2 + T / J * (t[a:a + 25] - t[a])
    got = segment_torques(t, e, starts, J)
    assert len(got) == starts.size
    assert np.allclose([g[3] for g in got], T)


def _excitation(seed: int, n: int = 5000, dt: float = 2e-3):
    """A speed excitation at one load: the current is the rotor's acceleration torque plus a constant load torque
    over Kt; noise on the measured acceleration and the residual torque."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    inertia, kt = 1.4e-4, 0.28
    accel = 400.0 * np.sin(2 * np.pi * (0.5 + 1.5 * t) * t)  # a chirp 0.5-30 Hz [rad/s^2]
    current = (inertia * accel + 0.08) / kt
    return rng, t, inertia, kt, accel, current


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_an_inertia_error_on_an_excitation_is_not_a_torque_constant_error(seed):
    """On a speed excitation at one load the current follows the acceleration: a residual torque of a 5 % inertia
    error is proportional to the current as much as a torque-constant error would be.  Tested given the measured
    acceleration, the current explains nothing; a torque-constant error whose current also carries a load change
    the acceleration does not is still found."""
    from thsa_control.trace.signature import sg_derivative, signature_tests

    rng, t, inertia, kt, accel, current = _excitation(seed)
    noise = 2e-4 * rng.standard_normal(t.size)
    speed = np.cumsum(accel) * (t[1] - t[0])  # the measured motor speed, 0.2 rad/s noise, differentiated as the
    acc_meas = inertia * sg_derivative(speed + 0.2 * rng.standard_normal(t.size), 21, t[1] - t[0])  # tracer does
    current = current + 0.02 * rng.standard_normal(t.size)  # the current sensor's noise
    # the rotor 5 % heavier than declared; the missing torque is J d(speed error)/dt through the same filter
    resid = -0.05 * inertia * sg_derivative(speed, 21, t[1] - t[0]) + noise
    plain = signature_tests(resid, {"i": ("linear", current)})[0]
    given = signature_tests(resid, {"i": ("linear", current)}, given={"i": acc_meas})[0]
    assert plain["significant"] and plain["p_value"] < 1e-12  # what the unconditioned test took for a Kt error
    assert not given["significant"] and given["p_value"] > 1e-3, given
    # a 3 % torque-constant error, the load stepping from 0.08 to 0.3 N m half-way: found given the acceleration
    current2 = current + np.where(t > t[-1] / 2, 0.22 / kt, 0.0)
    resid2 = 0.03 * kt * current2 + noise
    found = signature_tests(resid2, {"i": ("linear", current2)}, given={"i": acc_meas})[0]
    assert found["significant"] and found["slope"] == pytest.approx(0.03 * kt, rel=0.1), found


def test_threshold_scale_counts_the_samples_its_chi2_sums():
    """A channel of zero noise adds neither chi2 nor samples: the reduced chi2 is the weighted channel's mean squared
    error (2^2 = 4 here), not diluted by the unweighted channel's samples (2, counting both)."""
    import numpy as np

    from thsa_control.trace.scoring import threshold_scale

    n = 400
    hold = np.ones(n, bool)
    fit = {"predictions": {"r": {"holdout": hold,
                                 "measured": {"a": np.full(n, 2.0), "b": np.full(n, 1.0)},
                                 "simulated": {"a": np.zeros(n), "b": np.zeros(n)}}}}
    red, _tau = threshold_scale(fit, {"a": 1.0, "b": 0.0})
    assert red == 4.0


def test_an_added_ripples_own_shape_left_in_the_residual_is_its_size_not_a_local_effect():
    """A screw ripple the model has, fitted 20 % short (rig-sim's pair of a no-back and a ripple on a trim record:
    0.040 N m against 0.050), leaves a once-per-lead friction in the residual, repeated over both passes: the
    pass-replicated test alone calls it local.  Told the model's own periodic drags (``shapes``), it tests beyond
    their shape (not local) and reports what the residual holds along it (the amplitude left, within 10 %).  A
    friction bump beside it is still found beyond the shape."""
    rng = np.random.default_rng(5)
    t, w, f, x, d = _trim_xd()
    x = 2.5 * x  # 44 mm out and back, as rig-sim's trim record: 3.6 leads
    lead = 12e-3
    tr = base_transients(t, w, f, 0.3)
    left = 0.01 * (1 + np.sin(2 * np.pi * x / lead + 0.7)) * -d  # the ripple's missing part, opposing the motion
    e = np.where(tr, np.nan, 0.02 * (d > 0) + left + 0.01 * rng.standard_normal(t.size))
    alone = position_local_test(e, x, d)
    assert alone["significant"] and alone["law"].startswith("dissipative") and "added_shapes" not in alone, alone
    told = position_local_test(e, x, d, shapes={"screw_friction_ripple": lead})
    assert not told["significant"], told
    along = told["added_shapes"]["screw_friction_ripple"]
    assert along["significant"] and abs(along["amplitude"] - 0.01) < 0.001, along
    # against the ripple as fitted (0.04 N m in the same phase: cos 0.04 sin 0.7, sin 0.04 cos 0.7): short by 0.01
    from thsa_control.model.params import default_parameters
    from thsa_control.trace.residual import _against_fitted

    fitted = default_parameters().replace({"drive.screw_ripple_torque_cos": 0.04 * np.sin(0.7),
                                           "drive.screw_ripple_torque_sin": 0.04 * np.cos(0.7), "screw.lead": lead})
    _against_fitted(along, "screw_friction_ripple", fitted)
    assert abs(along["fitted_amplitude"] - 0.04) < 1e-12 and abs(along["in_phase"] - 0.01) < 0.001, along
    flipped = dict(along)
    _against_fitted(flipped, "screw_friction_ripple", fitted.replace({
        "drive.screw_ripple_torque_cos": -0.04 * np.sin(0.7), "drive.screw_ripple_torque_sin": -0.04 * np.cos(0.7)}))
    assert abs(flipped["in_phase"] + 0.01) < 0.001  # a fit in the opposite phase: the residual says too large
    xm = 0.5 * (x.min() + x.max())
    bump = -0.03 * np.exp(-0.5 * ((x - xm) / 1.5e-3) ** 2) * d
    assert position_local_test(e + bump, x, d, shapes={"screw_friction_ripple": lead})["significant"]
    # a period shorter than two bins (the cogging's 0.18 mm) is not resolved by the bins: not taken as a shape
    assert "added_shapes" not in position_local_test(e, x, d, shapes={"cogging_torque": 1e-4})


def test_a_window_whose_events_fell_in_training_segments_is_judged_on_all_its_samples():
    """A window of two short events (a back-drive through the pawl clearance at each trim stop), both in training
    segments: its held-out samples are where the effect changes nothing, so its held-out drop says nothing about it.
    The effect that explains the events is judged over all the window's samples (and says so); where the held-out
    samples do hold the window's error, the held-out drop stands, and an effect that explains nothing in the window
    gains nothing from the rule."""
    n, seg = 3000, 50
    t, k, hold, starts, meas, _ = _held_out_record(n, seg)  # segments 2, 5, 8, ... held out
    meas = np.zeros(n)
    events = np.isin(k, (12, 13, 30, 31))  # two events of two training segments each (12 % 3 = 0, 13 % 3 = 1)
    assert not (events & hold).any()
    meas[events] = 20.0  # a jump neither model's start state holds
    window = {"r": events | np.isin(k, (20, 38))}  # the events and two held-out motion starts
    common = dict(k=2, alpha=1e-3, mask=None, window=window, channel="motor_speed", min_window_reduction=0.05,
                  max_channel_increase=0.1)
    explains = np.where(events, 19.0, 0.0)
    explains[np.isin(k, (20, 38))] = 0.1  # a little worse on the starts (noise 1: chi2 1.01 against 1 per sample)
    rng = np.random.default_rng(3)
    noisy = meas + rng.standard_normal(n)
    before = {**_fit(np.zeros(n), noisy, hold, starts, t), "aic": 1.0}
    adm = admission_tests(before, {**_fit(explains, noisy, hold, starts, t), "aic": 0.0}, {"motor_speed": 1.0},
                          **common)
    on_all = adm["window_on_all_samples"]["motor_speed"]
    assert on_all["holdout_reduction"] < 0.01 and on_all["heldout_samples"] == 100 and on_all["samples"] == 300
    assert on_all["heldout_error_ratio"] < 0.01  # mean chi2 ~1 held out against ~(200 x 401 + 100) / 300 in all
    assert adm["window_reduction"]["motor_speed"] > 0.9 and adm["window_ok"]
    # the same effect when one event lies in a held-out segment: the held-out drop stands
    events2 = np.isin(k, (12, 13, 29, 30))  # 29 % 3 = 2: held out
    meas2 = np.where(events2, 20.0, 0.0) + rng.standard_normal(n)
    before2 = {**_fit(np.zeros(n), meas2, hold, starts, t), "aic": 1.0}
    adm2 = admission_tests(before2, {**_fit(np.where(events2, 19.0, 0.0), meas2, hold, starts, t), "aic": 0.0},
                           {"motor_speed": 1.0}, **{**common, "window": {"r": events2 | np.isin(k, (20, 38))}})
    assert adm2["window_on_all_samples"] == {} and adm2["window_reduction"]["motor_speed"] > 0.8
    # an effect that changes nothing where the events are is not helped: over all samples it explains nothing either
    adm3 = admission_tests(before, {**_fit(np.where(np.isin(k, (20, 38)), 0.1, 0.0), noisy, hold, starts, t),
                                    "aic": 0.0}, {"motor_speed": 1.0}, **common)
    assert "motor_speed" in adm3["window_on_all_samples"]
    assert adm3["window_reduction"]["motor_speed"] < 0.01 and not adm3["window_ok"]


def test_an_effect_that_buys_its_window_with_the_rest_of_the_record_is_refused():
    """The window's drop is scored on part of the record (outside the base's transients): an effect that explains its
    window but makes the held-out error over every held-out sample larger stands for something else and is refused
    (rig-sim, fresh trim record with an axial force: a drive-train compliance at 175 N m s/rad, drop 189 in its
    window, -73721 over every held-out sample).  The same effect that leaves the rest as it was passes; the base
    step's bars (whole_record False) do not ask it."""
    n, seg = 3000, 50
    t, k, hold, starts, _, _ = _held_out_record(n, seg)
    rng = np.random.default_rng(5)
    meas = np.where(k < 30, 1.0, 0.0) + rng.standard_normal(n)
    window = {"r": k < 30}
    common = dict(k=2, alpha=1e-3, mask=window, window=window, channel="motor_speed", min_window_reduction=0.05,
                  max_channel_increase=0.1)
    before = {**_fit(np.zeros(n), meas, hold, starts, t), "aic": 1.0}
    fits = np.where(k < 30, 1.0, 0.0)
    good = admission_tests(before, {**_fit(fits, meas, hold, starts, t), "aic": 0.0}, {"motor_speed": 1.0}, **common)
    assert good["significant"] and good["all_samples_fail"] is None
    costly = fits + np.where(k >= 30, 2.0, 0.0)  # outside the window it moves the prediction by twice the noise
    bad = admission_tests(before, {**_fit(costly, meas, hold, starts, t), "aic": 0.0}, {"motor_speed": 1.0}, **common)
    assert bad["significant"] and bad["holdout_chi2_drop"] == pytest.approx(good["holdout_chi2_drop"])
    assert bad["holdout_chi2_drop_all_samples"] < 0 and "over every held-out sample grows" in bad["all_samples_fail"]
    assert admission_tests(before, {**_fit(costly, meas, hold, starts, t), "aic": 0.0}, {"motor_speed": 1.0},
                           whole_record=False, **common)["all_samples_fail"] is None


def _reversal_xd(passes=8, dt=2e-3, speed=6e-3, period=1.2, settle=0.35):
    """Speed reversals without stops (rig-sim's reversals_under_load): the nut goes 0 -> 7.2 mm and back every 1.2 s;
    the first and last ``settle`` s of each pass are the base's transients (NaN), so a pass's steady part is 3 mm."""
    k = int(round(period / dt))
    tau = np.arange(k) * dt
    xs, ds, keep = [], [], []
    for j in range(passes):
        up = j % 2 == 0
        xs.append(speed * tau if up else speed * (period - tau))
        ds.append(np.full(k, 1.0 if up else -1.0))
        keep.append((tau >= settle) & (tau <= period - settle))
    t = np.arange(passes * k) * dt
    return t, np.concatenate(xs), np.concatenate(ds), np.concatenate(keep)


def test_short_passes_get_bins_narrow_enough_to_test_and_keep_the_level():
    """On a reversal record the steady part of a pass is 3 mm: at 2 mm bins a pass crosses two, which its own
    intercept and slope take, and the flank of a friction bump (at 5 mm, 1.5 mm wide: rig-sim's) is not seen; with
    the bins narrowed until the median pass crosses four, it is, the width is reported, and noise with per-pass
    offsets and slopes (a direction drag, a drift in time) is rejected at the test's level (300 seeds at 5 %)."""
    from scipy.stats import binom

    t, x, d, keep = _reversal_xd()
    rng = np.random.default_rng(7)
    kernel = np.ones(5) / 5
    bump = -0.1 * np.exp(-0.5 * ((x - 5e-3) / 1.5e-3) ** 2) * d  # opposes the motion
    e = np.where(keep, bump + 0.01 * np.convolve(rng.standard_normal(t.size), kernel, mode="same"), np.nan)
    coarse = position_local_test(e, x, d, bins_per_pass=1)  # the bins kept at 2 mm
    assert coarse is None or not coarse["significant"], coarse
    r = position_local_test(e, x, d)
    assert r["significant"] and r["law"].startswith("dissipative") and r["bin_width"] < 1e-3, r
    assert r["bin_width"] == pytest.approx(np.ptp(x[keep][:300]) / 4, rel=0.05)
    # the place is reported within the positions tested: the steady part of the passes, every bin crossed by them
    lo, hi = r["tested_range"]
    assert lo == pytest.approx(np.nanmin(x[keep]), abs=r["bin_width"]) and hi - lo == pytest.approx(
        r["bins"] * r["bin_width"]), r
    assert lo <= r["peak_bin"][0] < r["peak_bin"][1] <= hi + 1e-12, r
    n, alpha, hits = 300, 0.05, 0
    for seed in range(n):
        g = np.random.default_rng(500 + seed)
        noise = np.convolve(g.standard_normal(t.size), kernel, mode="same")
        trend = 0.01 * (g.normal() * d + g.normal() * t)  # a direction drag and a drift in time
        res = position_local_test(np.where(keep, noise + trend, np.nan), x, d, alpha=alpha)
        hits += bool(res["significant"])
    lo, hi = binom.ppf(0.0005, n, alpha), binom.ppf(0.9995, n, alpha)
    assert lo <= hits <= hi, (hits, lo, hi)


def _one_pass(rng, bump=0.0, x_c=11.5e-3, trend=0.005, wiggle=0.003, noise=0.01, travel=26e-3, n=1300):
    """One extending pass outside the base's transients: the missing torque's level, a trend along the stroke and a
    smooth wiggle (what a declared model of another rig's base leaves), white noise (0.001 N m on a 2 mm bin's mean)
    and a friction bump of ``bump`` N m (Gaussian, 1.5 mm) opposing the motion at ``x_c``."""
    x = np.linspace(0.0, travel, n)
    e = (0.004 + trend * x / travel + wiggle * np.sin(2 * math.pi * x / 9e-3 + rng.uniform(0, 2 * math.pi))
         - bump * np.exp(-0.5 * ((x - x_c) / 1.5e-3) ** 2) + noise * rng.standard_normal(n))
    return e, x, np.ones(n)


def test_a_bump_crossed_once_stands_out_of_the_records_own_bins():
    """A friction bump of 0.05 N m at the motor crossed once (rig-sim's 5.2 N m at the screw through the gearbox is
    0.08) beside a base remainder with a trend and a wiggle of 0.003: found, in its bin, opposing the motion; the
    same pass without it is not flagged, whatever the wiggle's phase; a pass of six bins is not tested."""
    from thsa_control.trace.signature import ONE_PASS_VARIABLE, one_pass_bump_test

    for seed in range(5):
        r = one_pass_bump_test(*_one_pass(np.random.default_rng(seed), bump=0.05), bin_width=2e-3, origin=0.0)
        assert r["variable"] == ONE_PASS_VARIABLE and r["significant"], r
        assert r["peak_bin"][0] - 2e-3 <= 11.5e-3 <= r["peak_bin"][1] + 2e-3, r
        assert r["law"].startswith("dissipative"), r
        r0 = one_pass_bump_test(*_one_pass(np.random.default_rng(seed)), bin_width=2e-3, origin=0.0)
        assert not r0["significant"] and r0["p_value"] > 1e-2, r0
    assert one_pass_bump_test(*_one_pass(np.random.default_rng(0), bump=0.05, travel=12e-3, n=600),
                              bin_width=2e-3, origin=0.0) is None


def test_one_pass_bump_test_false_alarm_rate_is_at_most_its_level():
    """Calibration over 2000 seeds of a pass of white noise (13 bins, 11 compared): the rejection rate at alpha =
    0.05 is at most the level (the Bonferroni bound over the bins compared, nearly tight: the bins' t values are
    weakly dependent; 4.85 % on 4000 draws of the bin means themselves), below the binomial 99.9 % band's upper end."""
    from scipy.stats import binom

    from thsa_control.trace.signature import one_pass_bump_test

    n, alpha = 2000, 0.05
    hits = sum(one_pass_bump_test(*_one_pass(np.random.default_rng(2000 + k), trend=0.0, wiggle=0.0),
                                  bin_width=2e-3, origin=0.0, alpha=alpha)["significant"] for k in range(n))
    assert hits <= binom.ppf(0.9995, n, alpha), hits
