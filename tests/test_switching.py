"""Active/standby switch-over (issue #3 item 4): recovery, growth with the delay, hand-over."""

import numpy as np
import pytest

from thsa_control.loops.switching import analyse_switchover


@pytest.fixture(scope="module")
def analysis(design, params):
    return analyse_switchover(design, params, level="B", delays_s=(0.005, 0.015, 0.05), handover=(False, True))


def test_recovers_after_the_papers_delay(analysis):
    c = analysis.case(0.015, True)
    print(f"15 ms delay: peak speed error {c.peak_speed_error_m_s * 1e3:.2f} mm/s, "
          f"position error {c.peak_position_error_m * 1e3:.3f} mm, recovery {c.recovery_time_s:.3f} s")
    # papers: about 0.15 s; the no-back brakes the aided motion during the gap
    assert 0.02 < c.recovery_time_s < 0.3
    assert np.isfinite(c.recovery_time_s)


def test_recovery_and_errors_grow_with_the_delay(analysis):
    for hand in (False, True):
        rec = [analysis.case(d, hand).recovery_time_s for d in (0.005, 0.015, 0.05)]
        pos = [analysis.case(d, hand).peak_position_error_m for d in (0.005, 0.015, 0.05)]
        assert rec[0] < rec[1] < rec[2]
        assert pos[0] < pos[1] < pos[2]


def test_handover_reduces_the_bump(analysis):
    # short delay: holding the velocity integrator keeps the load torque, so the standby takes over smoothly
    with_h, without = analysis.case(0.005, True), analysis.case(0.005, False)
    assert with_h.peak_position_error_m < 0.5 * without.peak_position_error_m
    assert with_h.recovery_time_s < without.recovery_time_s


def test_standby_current_only_after_the_delay(analysis):
    c = analysis.case(0.05, True)
    t = c.time
    assert np.all(c.standby_current[t < analysis.fault_time_s + 0.05 - 1e-9] == 0.0)
    assert np.min(c.standby_current[t > analysis.fault_time_s + 0.06]) < -1.0  # drives the retraction
