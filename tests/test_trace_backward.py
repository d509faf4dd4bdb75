"""The tracer's backward check and the order of what is explained (thsa_control.trace.backward).

The model without an effect (what comes back, what goes with it) and the admission criterion applied given the
other effects, on predictions built by hand: a residual an effect removes must keep it, a residual another effect
already removes must not.  The whole-trace behaviour is checked on rig-sim runs (tests/test_trace_foreign.py,
``campaign``) and on the virtual rig's plain screw drive (tests/test_trace.py).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from thsa_control.model import resolve_effects
from thsa_control.trace.backward import Added, judge_removal, model_key, reduced_model
from thsa_control.trace.engine import CANDIDATES


def _added(name, **kw):
    spec = CANDIDATES[name]
    return Added(name=name, spec=spec, round=1, job=kw.pop("job", {}), k=len(spec.free) + len(spec.profile),
                 drop_when_added=100.0, **kw)


def test_without_an_effect_its_implied_effect_goes_and_the_declared_one_comes_back(params):
    """noback_backlash on level A pulls in the detailed no-back (which replaces the ideal one): without the
    backlash the model is level A again, and the parameters freed with the two are no longer free."""
    declared = resolve_effects("A")
    with_it = resolve_effects(None, add=[e for e in declared if e != "noback_ideal"]
                              + ["noback_quadrant_friction", "noback_backlash"])
    freed = ("noback.mu_coulomb_pos", "noback.mu_coulomb_neg")
    free = ("screw.efficiency_direct",) + freed
    a = _added("noback_backlash", replaced=("noback_ideal",), implied=("noback_quadrant_friction",), freed=freed)
    effs, fr, pset = reduced_model(a, with_it, free, params)
    assert set(effs) == set(declared)
    assert fr == ("screw.efficiency_direct",)
    assert pset is params


def test_an_effect_found_beyond_its_base_correction_gets_its_bound_back(params):
    """A Coulomb drag lifted beyond its plausible bound: without it, the same model with the bound restored (the value
    clipped into it), the parameter still free; the fitted model's key tells the two apart."""
    n = "drive.coulomb_torque"
    lifted = params.replace_parameters({n: dataclasses.replace(params[n], value=0.1, min=0.0, max=1.0)})
    effs = resolve_effects("A", add=["coulomb_friction"])
    a = _added("coulomb_friction", beyond_base=True, rebound={n: (0.0, 0.057)})
    e2, f2, p2 = reduced_model(a, effs, (n,), lifted)
    assert e2 == effs and f2 == (n,)
    assert p2.value(n) == pytest.approx(0.057) and p2[n].max == pytest.approx(0.057)
    assert model_key(effs, (n,), lifted) != model_key(e2, f2, p2)


def _fit(measured, simulated, hold, starts, t, aic, estimates=None):
    return {"predictions": {"r": {"time": t, "measured": {"motor_speed": measured}, "simulated": {"motor_speed": simulated},
                                  "holdout": hold, "segment_starts": starts}},
            "aic": aic, "estimates": estimates or {}, "free": list(estimates or {})}


@pytest.fixture()
def record():
    """A 1 kHz motor speed: a known signal, white noise of 1 rad/s, a step of 3 rad/s (the effect's part) from 2 s;
    50 ms segments, every third held out."""
    rng = np.random.default_rng(3)
    t = np.arange(0, 4, 1e-3)
    signal = 100 * np.sin(2 * np.pi * 0.5 * t)
    part = np.where(t >= 2, 3.0, 0.0)
    y = signal + part + rng.standard_normal(t.size)
    starts = np.arange(0, t.size, 50)
    seg = np.searchsorted(starts, np.arange(t.size), side="right") - 1
    hold = seg % 3 == 2
    return t, signal, part, y, starts, hold


def _judge(a, full, reduced, window=None):
    return judge_removal(a, full, reduced, noise={"motor_speed": 1.0}, mask=None, window_mask=window, alpha=1e-3,
                         min_window_reduction=0.05, max_channel_increase=0.1, z=2.0, robust=False)


def test_an_effect_that_still_explains_its_part_is_kept(record):
    """Full model = signal + the part; without the effect = signal only: the held-out drop is the part's
    (3^2 x the held-out samples after 2 s, about 6000), far above the chi2(1) quantile; the window error falls by
    two thirds; the training samples prefer it."""
    t, signal, part, y, starts, hold = record
    full = _fit(y, signal + part, hold, starts, t, aic=0.0)
    without = _fit(y, signal, hold, starts, t, aic=5000.0)
    rec = _judge(_added("coulomb_friction"), full, without)
    n_part = int(np.sum(hold & (t >= 2)))
    assert rec["holdout_chi2_drop"] == pytest.approx(9.0 * n_part, rel=0.1)
    assert rec["holdout_chi2_drop_all_samples"] == pytest.approx(rec["holdout_chi2_drop"])
    assert rec["window_reduction"]["motor_speed"] > 0.4
    assert rec["prelim"] and not rec["fails"], rec["fails"]


def test_an_effect_whose_part_another_explains_is_not_kept(record):
    """The later effect already carries the part: taking the earlier one out changes the prediction by a few
    hundredths of the noise, so its held-out drop is far below the chi2(1) quantile, its window error does not
    fall by 5 %, and the training samples do not prefer it (AIC)."""
    t, signal, part, y, starts, hold = record
    full = _fit(y, signal + part, hold, starts, t, aic=0.0)
    without = _fit(y, signal + part + 0.01 * np.sin(2 * np.pi * 3 * t), hold, starts, t, aic=-1.0)
    rec = _judge(_added("coulomb_friction"), full, without)
    assert not rec["prelim"]
    assert any("chi2(1) quantile" in w for w in rec["fails"]), rec["fails"]
    assert any("window" in w for w in rec["fails"]) and any("AIC" in w for w in rec["fails"]), rec["fails"]


def test_a_parameter_collapsing_to_zero_given_the_others_is_a_reason_not_an_undetermined_one(record):
    """Given the others, a parameter the data determine at zero says the effect is absent (not kept); one the final
    fit's information does not determine is reported, not a reason (its part is judged by the drop)."""
    t, signal, part, y, starts, hold = record
    without = _fit(y, signal, hold, starts, t, aic=5000.0)
    job = {"judge": {"drive.coulomb_torque": 0.05}, "absent": {"drive.coulomb_torque": True}}
    a = _added("coulomb_friction", job=job)
    zero = {"drive.coulomb_torque": {"value": 1e-4, "stderr_data": 1e-3, "at_bound": None}}
    rec = _judge(a, _fit(y, signal + part, hold, starts, t, aic=0.0, estimates=zero), without)
    assert rec["determination"] == {"drive.coulomb_torque": "zero"}
    assert any("collapses to zero" in w for w in rec["fails"]), rec["fails"]
    undetermined = {"drive.coulomb_torque": {"value": 0.04, "stderr_data": None, "at_bound": None}}
    rec = _judge(a, _fit(y, signal + part, hold, starts, t, aic=0.0, estimates=undetermined), without)
    assert rec["determination"] == {"drive.coulomb_torque": "not determined"}
    assert rec["prelim"], rec["fails"]


def test_a_ripple_is_judged_on_its_amplitude_given_the_others_not_on_one_part(record):
    """A screw ripple whose phase puts one part near zero: the cosine part alone is within 2 standard errors of zero
    and far from its reference (the per-parameter verdict "zero"), the amplitude 0.05 N m is determined to about
    0.002 along the radius.  It still explains its part, so it is kept (before, the cosine part's verdict took it
    out: a blind cold ramp's 3.5 N m ripple, 86 % of its window explained).  A pair whose amplitude is within its
    error of zero is taken out, with the amplitude named."""
    t, signal, part, y, starts, hold = record
    without = _fit(y, signal, hold, starts, t, aic=5000.0)
    cos, sin = "drive.screw_ripple_torque_cos", "drive.screw_ripple_torque_sin"
    job = {"judge": {cos: 0.05, sin: 0.05}, "absent": {cos: True, sin: True}}
    a = _added("screw_friction_ripple", job=job)
    phase = {cos: {"value": -0.002, "stderr_data": 0.01, "at_bound": None, "corr": {sin: 0.0}},
             sin: {"value": 0.05, "stderr_data": 0.002, "at_bound": None, "corr": {cos: 0.0}}}
    rec = _judge(a, _fit(y, signal + part, hold, starts, t, aic=0.0, estimates=phase), without)
    assert rec["determination"][cos] == "zero"  # the one part alone reads as absent ...
    assert rec["prelim"], rec["fails"]  # ... the ripple is not
    gone = {cos: {"value": 0.001, "stderr_data": 0.01, "at_bound": None, "corr": {sin: 0.0}},
            sin: {"value": -0.002, "stderr_data": 0.01, "at_bound": None, "corr": {cos: 0.0}}}
    rec = _judge(a, _fit(y, signal + part, hold, starts, t, aic=0.0, estimates=gone), without)
    assert any(w.startswith("amplitude 0.00224 collapses to zero") and w.endswith("given the others")
               for w in rec["fails"]), rec["fails"]
    undetermined = {**phase, cos: {**phase[cos], "stderr_data": None}}
    rec = _judge(a, _fit(y, signal + part, hold, starts, t, aic=0.0, estimates=undetermined), without)
    assert rec["prelim"], rec["fails"]  # a part the final fit does not determine is no reason


@pytest.mark.slow
def test_a_removed_effect_leaves_the_model_and_is_said_so(tmp_path, rig_1khz, params, monkeypatch):
    """The engine's side of a removal, on the plain screw drive of tests/test_trace.py (Coulomb 0.1 N m + offset
    600 N, both found): with the criterion made to refuse the Coulomb friction given the offset (a stand-in for a
    part the later effect explains), the Coulomb friction leaves the model after round 2 with the numbers, the
    model the trace ends with is the one without it, it is not offered again, and the summary and the report say
    so."""
    from handcalc import RIG_NOISE

    from thsa_control.data.rigdata import read_run
    from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs
    from thsa_control.report.trace import conclusion_table_html, format_trace_summary
    from thsa_control.trace import TraceSettings, trace
    from thsa_control.trace import backward as bw

    design = dataclasses.replace(rig_1khz, velocity_ki=0.0)
    truth = params.replace({"drive.coulomb_torque": 0.1, "drive.axial_force_offset": 600.0})
    u = excitation_inputs(2.5, bipolar=True, load=0.0, control_period=1e-3, seed=1, temperature=25.0)
    VirtualRig(None, effects=("coulomb_friction", "force_offset"), params=truth, design=design, noise=RIG_NOISE,
               seed=1).record(u, tmp_path / "run")
    run = read_run(tmp_path / "run.csv")
    real = bw.judge_removal

    def refuse_coulomb(a, full, reduced, **kw):
        rec = real(a, full, reduced, **kw)
        if a.name == "coulomb_friction":
            rec["fails"].append("refused by the test")
            rec["prelim"] = False
        return rec

    monkeypatch.setattr(bw, "judge_removal", refuse_coulomb)
    res = trace(run, "A", remove=["noback_ideal"], params=params,
                settings=TraceSettings(candidates=("coulomb_friction", "force_offset"), max_nfev=30))
    doc = res.to_dict()
    assert [e["name"] for e in doc["effects_added"]] == ["force_offset"], doc["rounds"]
    (r,) = doc["effects_removed"]
    assert r["name"] == "coulomb_friction" and r["explained_by"] == ["force_offset"] and r["removed_after_round"] == 2
    assert r["holdout_chi2_drop_given_others"] > r["chi2_threshold"]  # the real criterion kept it: only the test refused
    assert "coulomb_friction" not in doc["final_effects"] and "force_offset" in doc["final_effects"]
    assert doc["order"] is None  # one found effect left: nothing to order
    # not offered again: offered, it would have made a third round of candidates
    assert len(doc["rounds"]) == 2 and "backward" in doc["rounds"][1], doc["rounds"]
    jsonschema = pytest.importorskip("jsonschema")
    schema = Path(__file__).resolve().parents[1] / "docs" / "trace_schema.json"
    jsonschema.validate(json.loads(json.dumps(doc, default=float)), json.loads(schema.read_text()))
    assert "removed after round 2" in format_trace_summary(doc)
    assert "removed (backward check)" in conclusion_table_html(doc)
