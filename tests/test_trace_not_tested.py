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
