"""open_loop / closed_loop: python-control objects of the cascade's loops, checked against the grid
analysis (margins by control.stability_margins) and python-control's own interconnection."""

from __future__ import annotations

import math
import warnings

import control as ct
import numpy as np
import pytest

import thsa_control as thsa
from thsa_control.errors import DesignError
from thsa_control.loops.analysis import analyse_loops
from thsa_control.loops.linear import DEFAULT_EFFECTS, DEFAULT_LEVEL, OperatingCondition, plant_model

# 25 degC mid-grid, and the nominal design's worst point (slow, aiding, conditionally stable velocity loop)
CONDITIONS = [OperatingCondition(10e-3, 20e3, 25.0), OperatingCondition(2e-3, -55e3, 70.0)]


@pytest.fixture(scope="module")
def model(params):
    return plant_model(DEFAULT_LEVEL, DEFAULT_EFFECTS, params)


@pytest.mark.parametrize("cond", CONDITIONS, ids=["25C", "aiding"])
def test_stability_margins_of_the_statespace_equal_the_analysis(design, params, model, cond):
    a = analyse_loops(design, params, [cond], model=model, steps=False)
    for loop in ("current", "velocity", "position"):
        L = thsa.open_loop(loop, cond, design, params, model=model)
        assert isinstance(L, ct.StateSpace) and L.dt == design.control_period and L.isdtime(strict=True)
        m = a.loops[f"{loop}_loop"].margins
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # python-control's fallback from 'poly' to 'frd'
            gm, pm, sm, wpc, wgc, wms = ct.stability_margins(L)
        # python-control's 'frd' fallback interpolates its own frequency grid: a few 1e-6 relative
        assert pm == pytest.approx(m.phase_margin_deg[0], abs=1e-3), loop
        assert wgc / (2 * math.pi) == pytest.approx(m.crossover_hz[0], rel=1e-5), loop
        assert 1 / sm == pytest.approx(m.ms[0], rel=1e-5), loop
        if loop == "current" and not design.computation_delay_samples:
            # its phase crossover is at Nyquist, z = -1, which python-control's margins skip: evaluate there
            assert m.gain_margin_db[0] == pytest.approx(-20 * math.log10(abs(L(-1.0))), rel=1e-9)
        else:
            assert 20 * math.log10(gm) == pytest.approx(m.gain_margin_db[0], abs=1e-4), loop
    if cond.aiding:  # conditionally stable: python-control sees the lower gain margin too
        assert a.loops["velocity_loop"].margins.gain_margin_db[0] < 0


@pytest.mark.parametrize("loop, ref, out", [("current", "current_ref", "motor_current"),
                                            ("velocity", "speed_ref", "motor_speed"),
                                            ("position", "position_ref", "nut_position")])
def test_closed_loop_is_python_controls_feedback_of_the_open_loop(design, params, model, loop, ref, out):
    cond = CONDITIONS[1]
    L = thsa.open_loop(loop, cond, design, params, model=model)
    T = thsa.closed_loop(f"{loop}_loop", cond, design, params, model=model)
    assert ref in T.input_labels and out in T.output_labels
    Tc = T[T.output_labels.index(out), T.input_labels.index(ref)]
    F = ct.feedback(L, 1)
    w = np.geomspace(1.0, math.pi / design.control_period * 0.999, 200)
    np.testing.assert_allclose(Tc.frequency_response(w).complex.ravel(), F.frequency_response(w).complex.ravel(),
                               rtol=1e-7, atol=1e-12)
    # the grid analysis' step response is this system's step response
    a = analyse_loops(design, params, [cond], model=model)
    lm = a.loops[f"{loop}_loop"]
    decim = a.settings.step_decimation[("current", "velocity", "position").index(loop)]
    t = np.arange(lm.step_time.size * decim) * design.control_period
    y = ct.step_response(Tc, T=t).outputs[::decim]
    np.testing.assert_allclose(y, lm.step[0], rtol=1e-6, atol=1e-9 * np.max(np.abs(y)))
    np.testing.assert_allclose(np.sort(np.abs(T.poles())), np.sort(np.abs(lm.poles[0])), rtol=1e-6, atol=1e-9)


def test_load_step_channel_and_named_states(design, params, model):
    cond = CONDITIONS[0]
    T = thsa.closed_loop("velocity", cond, design, params, model=model)
    assert T.input_labels == ["speed_ref", "load_force", "disturbance_torque"]
    assert T.output_labels == ["motor_current", "motor_speed", "nut_speed"]
    assert {"velocity_pi", "current_pi", "motor_speed"} <= set(T.state_labels)
    # with the integrator, a constant load leaves no steady speed error
    assert abs(float(ct.dcgain(T[2, 1]))) < 1e-9
    # and its first response opposes the motion (compressive load, positive speed)
    y = ct.step_response(T[2, 1], T=np.arange(200) * design.control_period).outputs
    assert y[np.argmax(np.abs(y))] < 0


def test_invalid_points_and_names_are_refused(design, params, model):
    with pytest.raises(DesignError, match="zero speed"):
        thsa.open_loop("velocity", (0.0, 20e3, 25.0), design, params, model=model)
    with pytest.raises(ValueError, match="unknown loop"):
        thsa.open_loop("torque", CONDITIONS[0], design, params, model=model)
    with pytest.raises(ValueError, match="OperatingCondition"):
        thsa.open_loop("velocity", 5.0, design, params, model=model)


def test_plant_model_and_cli_share_the_default_effects(monkeypatch):
    import inspect

    from thsa_control import cli
    from thsa_control.cli.common import analysis_effects
    from thsa_control.loops.analysis import AnalysisSettings

    assert inspect.signature(plant_model).parameters["level"].default == DEFAULT_LEVEL
    assert AnalysisSettings().level == DEFAULT_LEVEL and AnalysisSettings().effects == DEFAULT_EFFECTS
    args = cli.build_parser().parse_args(["linearize", "--level", "B", "--speed", "1", "--load", "0"])
    assert tuple(analysis_effects(args)) == DEFAULT_EFFECTS
