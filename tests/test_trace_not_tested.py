"""The residual signature says which of its tests a record could not make (issue #21): a rig that keeps its drive
energised at zero command never shows the current with the drive off, so a current-sensor offset reads there as a
constant torque that the base's constant-torque explainers share; ``unexplained: false`` must not be read as the
offset test's all-clear.  A record without a hold likewise leaves the load-cell drift untested.

Synthetic: the reversal record of tests/test_trace_angle.py (drive on throughout, load steady, never still), and the
same record with the drive gated off for its last second, the nut held, the current read as a 0.3 A offset there.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from test_trace_angle import _Plant, _record
from thsa_control.model.params import default_parameters
from thsa_control.report.trace import not_tested_lines
from thsa_control.trace.residual import _signature
from thsa_control.trace.signature import SignatureSettings


def _sig(run, fit):
    return _signature(fit, [run], default_parameters(), _Plant(), SignatureSettings())


def test_a_drive_never_off_says_the_current_offset_and_the_load_cell_drift_were_not_tested():
    run, fit = _record(5, lambda t, tau, angle: 0.0 * t)
    sig = _sig(run, fit)
    assert not any(d["kind"] == "sensor_offset" for d in sig["sensors"])
    names = {d["test"]: d for d in sig["not_tested"]}
    co = names["motor_current with the drive off"]
    assert co["run"] == run.name and co["would_show"] == "a current-sensor offset"
    assert "off on 0 samples" in co["why"]
    assert "time (slow drift) of the load reading in the holds" in names
    lines = not_tested_lines(sig)
    assert any(ln.startswith("not tested: motor_current with the drive off on synthetic_reversals (a current-sensor "
                             "offset would show there)") for ln in lines), lines


def test_a_drive_off_stretch_makes_the_current_offset_test_and_finds_the_offset():
    """The last second with the command at zero on a rig that gates its drive there: 500 drive-off samples, the
    current reading 0.3 A (the offset) plus noise; the test runs, flags it, and is not listed as not made."""
    run, fit = _record(5, lambda t, tau, angle: 0.0 * t)
    t = run.time
    off = t >= 9.0
    rng = np.random.default_rng(7)
    sig = dict(run.signals)
    cmd = np.asarray(sig["speed_cmd"], float)
    sig["speed_cmd"] = np.where(off, 0.0, np.where(cmd == 0.0, 1e-9, cmd))  # the reversals pass zero, not stop
    sig["motor_current"] = np.where(off, 0.3 + 0.02 * rng.standard_normal(t.size), sig["motor_current"])
    run = dataclasses.replace(run, signals=sig, motor_disabled_when_cmd_zero=True)
    out = _sig(run, fit)
    co = next(d for d in out["sensors"] if d["kind"] == "sensor_offset")
    assert co["samples"] == int(off.sum()) and abs(co["offset"] - 0.3) < 0.01 and co["significant"]
    assert "motor_current with the drive off" not in {d["test"] for d in out["not_tested"]}


def test_a_drift_is_tested_at_a_constant_command_and_said_untested_where_the_command_decays():
    """A missing torque drifting by 0.01 N m/s on the reversal record: at its constant +-1 mm/s command the drift
    test runs and flags it.  The same residual under a command that decays within each pass (a proportional
    position loop's, 2 1/s: 20 % over a 0.1 s segment) is no longer compared as one operating point: the drift test
    is not made, and the signature says so with the segments it left out."""
    run, fit = _record(5, lambda t, tau, angle: 0.01 * t)
    sig = _sig(run, fit)
    dr = next(d for d in sig["tests"] if d["variable"] == "time (slow drift)")
    assert dr["significant"] and dr["passes"] >= 6 and "segments_off_command" not in dr, dr
    assert "time (slow drift)" not in {d["test"] for d in sig["not_tested"]}
    t = run.time
    start = np.r_[0.0, t[1:][np.diff(np.sign(run.signals["speed_cmd"])) != 0]]
    since = t - start[np.searchsorted(start, t, side="right") - 1]
    decaying = dataclasses.replace(run, signals={**run.signals,
                                                 "speed_cmd": run.signals["speed_cmd"] * np.exp(-2.0 * since)})
    out = _sig(decaying, fit)
    assert not any(d["variable"] == "time (slow drift)" for d in out["tests"]), out["tests"]
    why = next(d for d in out["not_tested"] if d["test"] == "time (slow drift)")
    assert why["run"] is None and "changing speed command" in why["why"], why
    assert int(why["why"].split()[0]) >= dr["segments"], (why, dr["segments"])
    assert any("time (slow drift)" in ln for ln in not_tested_lines(out)), not_tested_lines(out)
