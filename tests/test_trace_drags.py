"""Base drags against planted constant torques (issue #21): the guards the rig-sim runs needed (fast checks; the
traces themselves are judged by tests/test_trace_foreign.py's campaign)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thsa_control.data.rigdata import read_run
from thsa_control.trace.candidates import RESOLVES

DATA = Path(__file__).resolve().parent / "data" / "rigsim"


@pytest.mark.parametrize("name, travel_mm, resolved", [
    ("null_rig_reversals_s2", 7.2, False),  # +-6 mm/s reversals every 1.2 s: 0.6 screw revolution of stroke
    ("null_rig_trim_s1", 45.0, True),  # 15 mm/s ramps for 3 s: 3.7 revolutions
])
def test_screw_ripple_needs_two_leads_of_nut_travel(params, name, travel_mm, resolved):
    """A ripple once per screw revolution is scored only where the same screw angle recurs at another nut position
    (two leads of travel); the reason names the travel and the two leads."""
    run = read_run(DATA / f"{name}.csv")
    x = np.asarray(run.signals["nut_position"], float)
    assert float(np.nanmax(x) - np.nanmin(x)) * 1e3 == pytest.approx(travel_mm, rel=0.1)
    why = RESOLVES["screw_friction_ripple"](params, [run])
    if resolved:
        assert why is None
    else:
        assert why is not None and "less than two screw leads (24 mm)" in why


def test_screw_ripple_travel_from_the_motor_speed_without_an_lvdt(params):
    """Without a nut-position channel the travel is the measured motor speed integrated through the kinematics."""
    import dataclasses

    run = read_run(DATA / "null_rig_trim_s1.csv")
    sig = dict(run.signals)
    sig["nut_position"] = np.full(len(run.time), np.nan)
    blind = dataclasses.replace(run, signals=sig)
    assert RESOLVES["screw_friction_ripple"](params, [blind]) is None
