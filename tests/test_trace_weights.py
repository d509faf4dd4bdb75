"""The weight check of a found effect's estimate (thsa_control.trace.weights): the channel scales a maximum-likelihood
fit gives channels the model cannot describe, and the verdict that an estimate depends on the weighting.

The tracer's own run of it is judged on rig-sim records in tests/test_trace_foreign.py (the drive-train compliance
over a PRBS, whose damping the motor speed's misfit chose)."""

import math

import pytest

from thsa_control.trace import weights as wt


def _est(value, stderr, lo=0.0, hi=1e4):
    return {"value": value, "stderr": stderr, "stderr_data": stderr, "min": lo, "max": hi}


NOISE = {"motor_speed": 0.23, "screw_speed": 0.029}


def test_a_channel_at_its_noise_keeps_its_noise_as_scale():
    s = wt.ml_channel_scales(NOISE, {"motor_speed": 0.65, "screw_speed": 0.02})
    assert s == {"motor_speed": 0.65, "screw_speed": 0.029}  # never below the sensor's noise
    assert wt.structural_channels(s, NOISE, 2.0) == ["motor_speed"]  # 2.8 x its noise
    assert wt.structural_channels(wt.ml_channel_scales(NOISE, {}), NOISE, 2.0) == []


def test_scales_settle_within_the_tolerance():
    old = {"a": 1.0, "b": 2.0}
    assert wt.scales_settled(old, {"a": 1.0 + 0.9 * wt.SCALE_TOLERANCE, "b": 2.0})
    assert not wt.scales_settled(old, {"a": 1.0, "b": 2.0 * (1 + 1.5 * wt.SCALE_TOLERANCE)})


def test_only_parameters_the_final_fit_estimated_are_checked():
    step = {"parameters": {"k": {"value": 1.0}, "d": {"value": 2.0}, "held_one": {"value": 3.0, "held": True},
                           "count": {"value": 6.0, "profiled": True}, "not_free": {"value": 1.0},
                           "no_error": {"value": 1.0}}}
    final = {"free": ["k", "d", "held_one", "count", "no_error"],
             "estimates": {"k": _est(1.0, 0.1), "d": _est(2.0, 0.2), "held_one": _est(3.0, 0.1),
                           "count": _est(6.0, 0.1), "no_error": _est(1.0, math.inf) | {"stderr": None},
                           "not_free": _est(1.0, 0.1)}}
    assert wt.checked_parameters(step, final) == ("k", "d")


def _verdict(final, alts, names=("d",)):
    return wt.weight_verdict({"estimates": final}, {k: {"estimates": v} for k, v in alts.items()}, names,
                             {"motor_speed": 0.65, "screw_speed": 0.029}, NOISE, 2.0, ["motor_speed"])


def test_an_estimate_that_moves_beyond_its_errors_depends_on_the_weights():
    # the drive-train compliance's damping on rig-sim's PRBS record: 17.6 +- 0.5 with sensor-noise weights, 4.3 +-
    # 0.15 at the residual scales, 1.9 +- 0.11 from the screw speed alone
    v = _verdict({"d": _est(17.6, 0.52)}, {"residual_scales": {"d": _est(4.28, 0.15)},
                                           "without_structural_channels": {"d": _est(1.88, 0.11)}})
    assert v["depends_on_weights"] == ["d"]
    lo, hi = v["range"]["d"]
    assert lo == pytest.approx(1.88 - 1.96 * 0.11) and hi == pytest.approx(17.6 + 1.96 * 0.52)
    assert set(v["parameters"]["d"]) == {"sensor_noise_weights", "residual_scales", "without_structural_channels"}
    assert v["structural_channels"] == ["motor_speed"]


def test_a_shift_within_the_errors_or_below_the_floor_is_no_dependence():
    within = _verdict({"d": _est(2.0, 0.3)}, {"residual_scales": {"d": _est(2.5, 0.3)}})  # 1.2 combined errors
    assert within["depends_on_weights"] == [] and within["range"] == {}
    small = _verdict({"d": _est(100.0, 0.01)}, {"residual_scales": {"d": _est(100.0 * (1 + wt.WEIGHT_SHIFT_FLOOR / 2),
                                                                              0.01)}})
    assert small["depends_on_weights"] == []  # many errors apart, but a few per cent


def test_a_weighting_that_does_not_determine_the_parameter_does_not_move_it():
    # left without the motor speed, a cogging amplitude has no information: its estimate there is no alternative
    v = _verdict({"d": _est(0.02, 0.002)}, {"without_structural_channels": {"d": _est(0.3, 0.5)}})
    assert v["depends_on_weights"] == []
    assert v["parameters"]["d"]["without_structural_channels"]["value"] == 0.3  # reported all the same


def test_the_range_stays_inside_the_physical_range():
    v = _verdict({"d": _est(0.5, 0.3, lo=0.0)}, {"residual_scales": {"d": _est(10.0, 0.5, lo=0.0)}})
    assert v["depends_on_weights"] == ["d"] and v["range"]["d"][0] == 0.0


def test_a_failed_alternative_fit_is_reported_not_used():
    v = wt.weight_verdict({"estimates": {"d": _est(17.6, 0.5)}}, {"residual_scales": {"error": "solver failed"}},
                          ["d"], NOISE, NOISE, 2.0, [])
    assert v["weightings"] == {"residual_scales": "error: solver failed"} and v["depends_on_weights"] == []
