"""The tracer's judgement of what a fit leaves (issue #21): base transients, structured against base-like
remainders, the ambiguity gap's autocorrelation factor and the concentration of a held-out drop.

Analytic cases on synthetic series: fast.
"""

from __future__ import annotations

import numpy as np
import pytest

from thsa_control.trace.engine import _holdout_iact
from thsa_control.trace.scoring import _holdout_segment_changes
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


def test_holdout_segment_changes_inside_a_window_and_the_sign_test():
    """Only segments with samples in the window count; a change carried by a few segments does not pass the sign
    test, one that improves every segment does."""
    n, seg = 3000, 50
    t = np.arange(n) * 1e-3
    k = np.arange(n) // seg
    hold = k % 3 == 2  # 20 held-out segments
    starts = t[::seg]
    meas = np.ones(n)
    before = _fit(np.zeros(n), meas, hold, starts, t)
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
