"""Two candidates whose held-out drops are close are rivals (the ambiguity rule: none is named) only where they explain
the same part of the residual (thsa_control.trace.engine._another_part): a candidate whose own channel the best one
leaves is no rival."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from thsa_control.trace.engine import SAME_PART_SHARE, _another_part


def _cand(channel: str, **reduction: float) -> dict:
    return {"_spec": SimpleNamespace(channel=channel), "error_reduction": reduction}


def test_a_candidate_whose_own_channel_the_best_leaves_is_no_rival():
    """The load path's compliance (its channel the LVDT) against the drive-train compliance (its channel the screw
    speed): rig-sim's measured shares, the screw speed 59 % better with the compliance, 0 % with the load path."""
    best = _cand("nut_position", motor_speed=-0.001, nut_position=0.194, screw_speed=0.0)
    other = _cand("screw_speed", motor_speed=0.755, nut_position=0.118, screw_speed=0.592)
    assert _another_part(best, other)


@pytest.mark.parametrize("share", [SAME_PART_SHARE, 0.8, 1.2])
def test_a_best_that_explains_enough_of_the_rivals_own_channel_keeps_it_a_rival(share):
    best = _cand("nut_position", nut_position=0.3, screw_speed=share * 0.4)
    assert not _another_part(best, _cand("screw_speed", nut_position=0.1, screw_speed=0.4))


def test_constant_torques_on_one_channel_stay_rivals():
    """A direction drag and an axial force on one load magnitude: the same two torques, the same channel (rig-sim's
    run set set_axial_offset: the motor speed 38.7 % and 38.9 % better)."""
    assert not _another_part(_cand("motor_speed", motor_speed=0.387), _cand("motor_speed", motor_speed=0.389))


def test_a_candidate_whose_channel_is_not_measured_or_that_does_not_help_it_stays_a_rival():
    best = _cand("nut_position", nut_position=0.3)
    assert not _another_part(best, _cand("screw_speed", nut_position=0.2))  # no screw-speed sensor
    assert not _another_part(_cand("nut_position", nut_position=0.3, screw_speed=0.0),
                             _cand("screw_speed", nut_position=0.2, screw_speed=-0.05))  # its channel worse
