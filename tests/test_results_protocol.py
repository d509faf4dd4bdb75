"""Results print and draw themselves (issue #16 item 6): every result type has ``.report() -> str``,
``.to_dict()`` (strict JSON) and ``.plot(ax=None)`` (a figure, or drawn into given axes)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import thsa_control as thsa
from thsa_control.report.figure import ReportFigure, subplots

EXAMPLE = Path(__file__).resolve().parent / "data" / "rig-data" / "examples" / "excitation_tensile_12kN.csv"


@pytest.fixture(scope="module")
def design():
    return thsa.load_design(thsa.nominal_design_path())


@pytest.fixture(scope="module")
def params():
    return thsa.default_parameters()


def _check(result, n_axes: int | None, *, expect: tuple[str, ...] = (), **plot_kw):
    text = result.report()
    assert isinstance(text, str) and text.strip()
    for piece in expect:
        assert piece in text, piece
    doc = result.to_dict()
    assert isinstance(doc, dict) and doc
    json.dumps(doc, allow_nan=False)  # strict JSON: no NaN, no numpy types
    fig = result.plot(**plot_kw)
    assert isinstance(fig, ReportFigure) and fig.axes
    if n_axes is not None:  # drawn into the caller's axes, on the caller's figure
        own, axes = subplots(n_axes, 1, figsize=(6, 2 * n_axes), squeeze=False)
        out = result.plot(ax=axes[:, 0] if n_axes > 1 else axes[0, 0], **plot_kw)
        assert out is own and all(a.has_data() or a.patches or a.collections for a in axes[:, 0])


def test_simulation_result(design, params):
    res = thsa.simulate(thsa.get_scenario("cold_ramp"), design, params, level="A")
    _check(res, 4, expect=("[[Simulation cold_ramp]]", "nut_speed", "[mm/s]", "motor_speed", "[rpm]"))
    assert res.to_dict()["units"]["nut_speed"] == "m/s"  # SI in the dict, display units in the text


def test_linearization_loops_and_requirements(design, params):
    model = thsa.plant_model(params=params)
    conds = [thsa.OperatingCondition(10e-3, 20e3, 25.0), thsa.OperatingCondition(2e-3, -55e3, -30.0),
             thsa.OperatingCondition(0.0, 20e3, 25.0)]
    lin = thsa.linearize_conditions(model, conds)
    _check(lin, 1, expect=("A =",))
    assert lin.to_dict()["points"][2]["valid"] is False  # zero speed: invalid, with its reason
    loops = thsa.analyse_loops(design, params, conds, model=model)
    _check(loops, 2, expect=("velocity_loop", "phase_margin_deg", "deg", "Not analysed"))
    check = thsa.check_requirements(loops)
    _check(check, 1, expect=("PASS", "phase margin >= 45 deg", "delay margin >= 2 ms"))
    assert check.to_dict()["passed"] == check.passed


def test_design_analysis_on_a_small_grid(design, params):
    settings = thsa.AnalysisSettings(nut_speeds=(2e-3, 10e-3), load_forces=(-20e3, 20e3), temperatures=(25.0,))
    res = thsa.analyse_design(design, params, settings=settings, switching=False, configurations=False,
                              limit_cycles=False)
    _check(res, None, expect=("requirements:", "[[Loop analysis]]"))
    assert res.to_dict()["format"] == "thsa-analysis/1"
    with pytest.raises(ValueError, match="figure of its own"):
        res.plot(ax=object())


def test_replay_and_residuals(params):
    from thsa_control.data.rigdata import read_run
    from thsa_control.fit.replay import analyse_replay, replay

    run = read_run(EXAMPLE)
    rep = replay(run, "B", params=params)
    _check(rep, len(rep.fits), expect=("motor_speed", "rpm", "fit"))
    res = analyse_replay(run, rep)
    _check(res, 3, expect=("[[Residual analysis]]",))
    assert res.to_dict() == res.summary()


def test_fault_analysis_from_its_parts(design, params):
    from thsa_control.faults.analysis import FaultAnalysis, SweepPoint, analyse_fault_case
    from thsa_control.sim.monitor_settings import MonitorSettings

    case = analyse_fault_case("jam", design, params)
    rigid = replace(case, label="rigid drive train")
    sweep = (SweepPoint(1.0, 0.005, (), {"jam": case.detection_s["discrepancy"]}, {"motor_fault_monitored": 0.05}),
             SweepPoint(2.0, 0.005, (), {"jam": np.inf}, {"motor_fault_monitored": 0.07}))
    a = FaultAnalysis("D", ("torque_limiter",), MonitorSettings(), (case,), (), sweep, 0.0, 0.05, 0.1, (rigid,))
    _check(a, 2, expect=("-- fault plant --", "jam: surface_jam", "-- rigid drive train --",
                         "jam [rigid drive train]: ", "sweep: thresholds x 2 miss jam"))
    assert a.to_dict()["format"] == "thsa-faults/1"


@pytest.mark.slow
def test_identification_and_switchover(design, params):
    from thsa_control.data.rigdata import read_run
    from thsa_control.loops.switching import analyse_switchover

    run = read_run(EXAMPLE)
    res = thsa.Identifier("B", params, ("noback.mu_coulomb_pos",),
                          settings=thsa.IdentificationSettings(max_nfev=5)).fit([run])
    _check(res, len(next(iter(res.predictions.values()))["measured"]), expect=("[[Variables]]",))
    sw = analyse_switchover(design, params, delays_s=(0.015,), handover=(False,))
    _check(sw, None, expect=("delay  15.0 ms",))
