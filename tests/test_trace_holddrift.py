"""The load cell where the physics holds the load (issue #21, rig-sim's ``loadcell_drift``): a reading that trends
with time in the holds, which the structure's deflection does not follow, is a drifting sensor.

Synthetic trim records (fast), the committed rig-sim runs read from their CSVs (no trace, fast), and the test's
level over seeds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binom

from thsa_control.data.rigdata import read_run
from thsa_control.trace.residual import hold_drift_of_runs
from thsa_control.trace.signature import hold_drift_test, hold_samples

DATA = Path(__file__).resolve().parent / "data" / "rigsim"

#: the structure's compliance seen by the LVDT while the no-back holds the nut: the load path (1.2e8 N/m) in series
#: with the ball-screw contact (3e8 N/m), rig-sim README "Plant structure"; a compressive load pushes the nut back
COMPLIANCE = -(1 / 1.2e8 + 1 / 3e8)


def _trim(seed: int, *, drift=0.0, load_ramp=None, lvdt=True, ar=0.0, dt=2e-3, sd_f=25.0, sd_x=2e-6):
    """A trim record: load applied 0.1-0.3 s with the drive off, +15 mm/s 1-4 s, stop, -15 mm/s 5.5-8.5 s, stop
    (speed command exactly 0 in the stops).  ``drift`` [N/s] adds to the load reading only; ``load_ramp`` = (t0, t1,
    rate) changes the true load (the LVDT deflects by the compliance); ``ar`` the lag-1 correlation of the load
    reading's noise.  Returns time, motor speed [rad/s], load reading [N], LVDT [m], speed command [m/s]."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 10.0, dt)
    v = np.zeros_like(t)
    v[(t > 1.0) & (t < 4.0)] = 0.015
    v[(t > 5.5) & (t < 8.5)] = -0.015
    v = np.convolve(v, np.ones(250) / 250, mode="same")  # 0.5 s ramps
    cmd = np.where(np.abs(v) > 1e-9, v, 0.0)
    w = v * 2 * np.pi / 0.012 * 65.61 + 0.3 * rng.standard_normal(t.size)
    f_true = 30e3 * np.clip((t - 0.1) / 0.2, 0.0, 1.0)
    if load_ramp is not None:
        t0, t1, rate = load_ramp
        f_true = f_true + rate * np.clip(t - t0, 0.0, t1 - t0)
    e = rng.standard_normal(t.size)
    if ar:
        for i in range(1, t.size):
            e[i] = ar * e[i - 1] + np.sqrt(1 - ar**2) * e[i]
    f = f_true + drift * t + sd_f * e
    x = np.cumsum(v) * dt + COMPLIANCE * f_true + sd_x * rng.standard_normal(t.size)
    return t, w, f, (x if lvdt else None), cmd


def _test(t, w, f, x, cmd, **kw):
    held = hold_samples(t, w, f, cmd)
    still = (cmd == 0) & (np.abs(w) < 5.0)
    return hold_drift_test(t, f, x, held, compliance_samples=still, **kw)


def test_holds_are_the_stops_outside_the_base_transients():
    """The held samples: speed command 0, nut still, 0.3 s clear of a stop and of the load application."""
    t, w, f, _x, cmd = _trim(1)
    h = hold_samples(t, w, f, cmd)
    assert not h[(t > 0.9) & (t < 4.5)].any() and not h[(t > 5.4) & (t < 9.0)].any()  # moving, or just stopped
    assert not h[t < 0.55].any()  # the load application and its settling
    assert h[(t > 4.6) & (t < 4.9)].all() and h[t > 9.1].all()


def test_a_position_loop_pulsing_the_drive_for_a_sample_does_not_end_a_hold():
    """A position loop at its deadband's edge commands a creep for a sample now and then (rig-sim's position_steps at
    1 kHz): the nut stays still, the hold goes on; a command held for 50 ms ends it."""
    t, w, f, _x, cmd = _trim(6)
    pulsed = cmd.copy()
    pulsed[np.flatnonzero((t > 9.2) & (np.arange(t.size) % 25 == 0))] = 3e-4  # 1 sample every 50 ms
    h = hold_samples(t, w, f, pulsed)
    assert h[t > 9.1].all()
    long_cmd = cmd.copy()
    long_cmd[(t > 9.5) & (t < 9.55)] = 3e-4
    h = hold_samples(t, w, f, long_cmd)
    assert not h[(t > 9.5) & (t < 9.55)].any() and h[(t > 9.2) & (t < 9.45)].all()


def test_a_planted_drift_is_found_with_its_rate_and_a_flat_hold_is_not():
    r = _test(*_trim(2, drift=40.0))
    assert r["significant"] and r["channel"] == "load_force", r
    assert r["variable"].startswith("time (slow drift)")  # the catalogue's signature of a slow drift
    assert r["holds"] >= 2 and r["slope"] == pytest.approx(40.0, abs=4 * r["stderr"])
    assert not r["load_change_seen_by_lvdt"]
    assert r["compliance"] == pytest.approx(COMPLIANCE, rel=0.05)  # from the load application while held
    r = _test(*_trim(2))
    assert not r["significant"] and r["p_value"] > 1e-3, r
    r = _test(*_trim(3, drift=-40.0))  # either sign
    assert r["significant"] and r["slope"] < 0, r


def test_a_real_load_ramp_in_a_hold_is_not_a_drift():
    """A load that really changes while the nut is held (300 N/s, slower than the base's load-change rule of 500 N in
    0.3 s) deflects the structure: the LVDT follows the load at the structure's compliance, so it is no drift.
    Without the LVDT the same record is flagged: the witness decides."""
    rec = _trim(4, load_ramp=(9.2, 10.0, 300.0))
    r = _test(*rec)
    assert r["load_change_seen_by_lvdt"] and not r["significant"], r
    assert r["load_rate_seen_by_lvdt"] == pytest.approx(r["slope"], abs=4 * r["load_rate_seen_by_lvdt_stderr"])
    t, w, f, _x, cmd = rec
    r = _test(t, w, f, None, cmd)
    assert r["significant"] and not r["load_change_seen_by_lvdt"] and r["witness"].startswith("none"), r


def test_a_drift_below_what_a_reading_resolves_is_not_flagged():
    """A drift significant by its t test on a densely sampled record (50 kHz) but moving the zero by half a noise
    standard deviation over the holds' span: a reading does not resolve it, no flag."""
    r = _test(*_trim(5, drift=2.3, dt=2e-5))
    assert r["p_value"] < 1e-6 and abs(r["change_over_span"]) < r["noise_sd"] and not r["significant"], r


@pytest.mark.parametrize("ar", [0.0, 0.8])
def test_the_hold_drift_test_false_alarm_rate_is_its_level(ar):
    """Over 300 seeds of flat holds, white or correlated reading noise (the count corrected by the autocorrelation
    time): the rejection rate at alpha = 0.05 lies inside the binomial 99.9 % band."""
    n, alpha = 300, 0.05
    hits = 0
    for k in range(n):
        r = _test(*_trim(2000 + k, ar=ar), alpha=alpha)
        hits += r["p_value"] < alpha
    assert binom.ppf(0.0005, n, alpha) <= hits <= binom.ppf(0.9995, n, alpha), hits


def test_rigsim_loadcell_drift_is_found_from_the_record_and_the_nulls_are_clean():
    """rig-sim, rig base, trim against 30 kN: the 40 N/s load-cell drift (+ a 10 N/s^0.5 walk) is flagged in the
    stops; the same scenario's nulls (rig and papers bases) and a bipolar null are not."""
    r = hold_drift_of_runs([read_run(DATA / "rig_loadcell_drift.csv")])
    assert r["significant"] and r["slope"] == pytest.approx(40.0, abs=4 * r["stderr"]), r
    for name in ("null_rig_trim_s1", "null_papers_trim_s1", "null_rig_bipolar_s3", "rig_kt_temperature"):
        r = hold_drift_of_runs([read_run(DATA / f"{name}.csv")])
        assert r is not None and not r["significant"] and r["p_value"] > 1e-3, (name, r)


def test_a_record_that_never_moves_has_holds_between_its_load_changes():
    """The drive off for the whole record while the load is applied and held (rig-sim's ``check_hold`` kind): the
    speed is its sensor's noise, whose 5 % of its own largest value is crossed every few samples; those crossings are
    no starts or stops, so the holds are the samples 0.3 s clear of the load changes, and a drifting reading there is
    flagged (before: every sample a transient, no hold, the drift test not run)."""
    from thsa_control.trace.signature import base_transients

    rng = np.random.default_rng(7)
    dt = 2e-3
    t = np.arange(0.0, 6.0, dt)
    w = 0.3 * rng.standard_normal(t.size)  # the resolver's noise, drive off
    f_true = 30e3 * np.clip((t - 0.1) / 0.4, 0.0, 1.0)
    x = COMPLIANCE * f_true + 2e-6 * rng.standard_normal(t.size)
    cmd = np.zeros(t.size)
    tr = base_transients(t, w, f_true, 0.3)
    assert tr[(t > 0.1) & (t < 0.5)].all() and not tr[t > 1.2].any()  # 0.3 s after the last 0.3 s of change
    for drift, flagged in ((40.0, True), (0.0, False)):
        f = f_true + drift * t + 25.0 * rng.standard_normal(t.size)
        held = hold_samples(t, w, f, cmd)
        assert held[t > 1.2].all() and not held[t < 0.5].any()
        r = hold_drift_test(t, f, x, held, compliance_samples=np.abs(w) < 5.0)
        assert r is not None and r["significant"] == flagged, r
        if flagged:
            assert r["slope"] == pytest.approx(drift, abs=4 * r["stderr"])


def test_a_load_step_is_a_transient_for_the_transient_time_either_side():
    """A load step (the loading actuator's 4 ms) on a still drive: the base transient is the 0.3 s either side of it,
    not 0.6 s after it (a window over which the load changed was marked at its end and widened again)."""
    from thsa_control.trace.signature import base_transients

    dt = 1e-3
    t = np.arange(0.0, 4.0, dt)
    f = np.where(t >= 2.0, 20e3, 0.0)
    tr = base_transients(t, np.zeros(t.size), f, 0.3)
    on = t[tr]
    assert on.min() == pytest.approx(1.7, abs=2 * dt) and on.max() == pytest.approx(2.3, abs=2 * dt), (on.min(), on.max())


def test_a_motor_speed_read_through_the_screw_speed_sensor_keeps_its_holds():
    """Without a motor-speed column the motor speed is the gear ratio times the screw-speed sensor's reading, with
    65.61 times its noise (3 rad/s against the resolver's 0.3): the 50 ms speed-change test must not call that noise a
    transient.  It did at 4.6 % of a stop's samples, so the stops' holds fell apart into stretches of tens of
    milliseconds and the load-cell drift test never ran (a blind rig-sim cold ramp); now the stops are holds as with a
    resolver, and a planted 60 N/s drift is found."""
    from thsa_control.trace.signature import base_transients, stretches

    t, w, f, x, cmd = _trim(9, drift=60.0)
    rng = np.random.default_rng(10)
    w = w + 4.0 * rng.standard_normal(t.size)  # the screw-speed sensor's 0.06 rad/s times 65.61, over the resolver's
    h = hold_samples(t, w, f, cmd)
    longest = max(t[q[-1]] - t[q[0]] for q in stretches(h))
    assert longest > 0.8, longest  # the 4.5-5.5 s and 9-10 s stops, 0.3 s clear of their ends
    # the real speed changes stay transients: the 0.5 s ramps (1030 rad/s^2 at the motor) beyond the noise's floor
    ramps = ((t > 0.85) & (t < 1.15)) | ((t > 3.85) & (t < 4.15))
    assert base_transients(t, w, f, 0.3)[ramps].all()
    d = _test(t, w, f, x, cmd)
    assert d is not None and d["holds"] == 2 and d["significant"], d
    assert d["slope"] == pytest.approx(60.0, abs=4 * d["stderr"])
