"""Two rules of the tracer's bookkeeping (thsa_control.trace.engine), on fit summaries built here:

* a declared component's detailed model whose only refusal is that the run determines none of its coefficients
  stands at the parameter file's values, each reported as not determined (what it adds is its structure: the rig
  no-back's holding margin at a drive-off stop, docs/trace_notes.md "A damping the stop chose");
* a found effect's entry reports its parameters as the final model has them and says which moved after it was added.

The tracer's own run of both is judged on rig-sim's speed excitation in tests/test_trace_foreign.py."""

from types import SimpleNamespace

import numpy as np
import pytest

from thsa_control.model import CandidateSpec
from thsa_control.model.params import default_parameters
from thsa_control.trace.engine import _declared_detail_at_file_values, _final_values
from thsa_control.trace.scoring import Reason

FILE = default_parameters()
NB = CandidateSpec("noback_quadrant_friction", ("noback.mu_coulomb_pos", "noback.mu_static_pos"), {}, "all",
                   "motor_speed")


def _fit(**est):
    return {"estimates": {n: {"value": v, "stderr": sd, "unit": "N m/N", "at_bound": None, "min": 0.0, "max": 0.1}
                          for n, (v, sd) in est.items()}}


def test_the_detailed_no_back_stands_at_file_values_when_the_run_determines_none():
    fit = _fit(**{"noback.mu_coulomb_pos": (0.0048, None), "noback.mu_static_pos": (0.0072, None)})
    why = [Reason("no parameter determined by the run: noback.mu_coulomb_pos, noback.mu_static_pos", "undetermined")]
    held = _declared_detail_at_file_values(fit, NB, ("standby_motor", "noback_ideal"), why, FILE)
    assert [h["parameter"] for h in held] == ["noback.mu_coulomb_pos", "noback.mu_static_pos"]
    assert held[0]["held_at"] == 0.0048 and "parameter file's values" in held[0]["reason"]


def test_only_a_declared_components_detail_and_only_for_undetermined_coefficients():
    fit = _fit(**{"noback.mu_coulomb_pos": (0.0048, None), "noback.mu_static_pos": (0.0072, None)})
    undet = [Reason("no parameter determined by the run", "undetermined")]
    # the level declares no idealised no-back it would detail: a found effect, judged as any other
    assert _declared_detail_at_file_values(fit, NB, ("standby_motor",), undet, FILE) == []
    # any other refusal (a determined coefficient collapsing to zero, one at a bound) stands
    assert _declared_detail_at_file_values(fit, NB, ("noback_ideal",), undet + [
        Reason("noback.mu_static_pos = 0 collapses to zero", "zero", "noback.mu_static_pos")], FILE) == []
    assert _declared_detail_at_file_values(fit, NB, ("noback_ideal",), [], FILE) == []  # nothing refused it
    # an undetermined coefficient the fit moved away from the file's value: not the declared component at file values
    moved = _fit(**{"noback.mu_coulomb_pos": (0.0300, None), "noback.mu_static_pos": (0.0072, None)})
    assert _declared_detail_at_file_values(moved, NB, ("noback_ideal",), undet, FILE) == []


def test_a_found_effect_reports_the_values_the_final_model_gives_it():
    added = [{"name": "drivetrain_compliance",
              "parameters": {"gear.torsional_damping": {"value": 17.6, "stderr": 0.52, "unit": "N m s/rad"},
                             "gear.torsional_stiffness": {"value": 9700.0, "stderr": 80.0, "unit": "N m/rad"}}},
             {"name": "noback_quadrant_friction", "parameters": {}}]
    current = {"estimates": {
        "gear.torsional_damping": {"value": 2.73, "stderr": 0.11, "unit": "N m s/rad", "at_bound": None, "min": 0.0},
        "gear.torsional_stiffness": {"value": 9757.0, "stderr": 35.0, "unit": "N m/rad", "at_bound": None,
                                     "min": 100.0}}}
    found = {"drivetrain_compliance": SimpleNamespace(round=1), "noback_quadrant_friction": SimpleNamespace(round=2)}
    _final_values(added, current, found)
    e = added[0]
    assert e["parameters_final"]["gear.torsional_damping"]["value"] == 2.73
    # the stiffness moved 57 N m/rad: within its errors and 1 %, not a change
    assert e["changed_after_added"] == {"parameters": ["gear.torsional_damping"], "with": ["noback_quadrant_friction"]}
    assert "parameters_final" not in added[1]  # nothing of its own in the final fit


def test_a_move_is_judged_on_the_runs_own_errors_like_the_weight_check():
    # posterior errors 0.1 say 1.0 -> 1.4 moved (2.8 combined errors); the run's own information (0.2 each) says it
    # is within 2 combined errors (1.4): not a change, as the weight check would judge the same two values
    def entry(v):
        return {"value": v, "stderr": 0.1, "stderr_data": 0.2, "unit": "N m", "at_bound": None, "min": 0.0}
    added = [{"name": "coulomb_friction", "parameters": {"friction.coulomb": entry(1.0)}}]
    _final_values(added, {"estimates": {"friction.coulomb": entry(1.4)}},
                  {"coulomb_friction": SimpleNamespace(round=1)})
    assert "changed_after_added" not in added[0]
    added[0]["parameters"]["friction.coulomb"]["stderr_data"] = 0.1
    _final_values(added, {"estimates": {"friction.coulomb": {**entry(1.4), "stderr_data": 0.1}}},
                  {"coulomb_friction": SimpleNamespace(round=1)})
    assert added[0]["changed_after_added"]["parameters"] == ["friction.coulomb"]


def test_the_summary_and_the_table_show_the_same_final_values():
    from thsa_control.report.trace import _final_text
    e = {"changed_after_added": {"parameters": ["gear.torsional_damping"], "with": ["noback_quadrant_friction"]},
         "parameters_final": {"gear.torsional_damping": {"value": 2.725, "stderr": 0.11, "unit": "N m s/rad",
                                                         "ci95": [2.506, 2.944]}}}
    t = _final_text(e)
    assert "refitted with noback_quadrant_friction" in t and "2.725 N m s/rad" in t and "2.506" in t and "2.944" in t


def _est(v, sd, lo=0.0, hi=1e4):
    return {"value": v, "stderr": sd, "stderr_data": sd, "unit": "N m s/rad", "at_bound": None, "min": lo, "max": hi}


def _every_case(monkeypatch, chi2_search=100.0, chi2_every=80.0, converged=True):
    """A final model (a drive-train compliance, a Coulomb base correction) and a stubbed fit on every segment that
    moves the damping and the Coulomb torque; each fit's error over every sample is its ``chi2_all``."""
    from thsa_control.trace import engine

    current = {"chi2_all": chi2_search, "free": ["gear.torsional_damping", "gear.torsional_stiffness",
                                                 "drive.coulomb_torque"], "estimates": {
        "gear.torsional_damping": _est(0.42, 0.10), "gear.torsional_stiffness": _est(9784.0, 41.0),
        "drive.coulomb_torque": _est(0.05, 0.002)}}
    added = [{"name": "drivetrain_compliance", "parameters": {
        "gear.torsional_damping": {"value": 0.42, "stderr": 0.10, "unit": "N m s/rad"},
        "gear.torsional_stiffness": {"value": 9784.0, "stderr": 41.0, "unit": "N m/rad"}}},
             {"name": "noback_quadrant_friction", "implied_by": "noback_backlash", "parameters": {}}]
    added[0]["parameters_final"] = {n: {**p, **({"range_over_channel_weights": [0.3, 0.5]}
                                                if n == "gear.torsional_damping" else {})}
                                    for n, p in added[0]["parameters"].items()}
    every = {"chi2_all": chi2_every, "chisqr": chi2_every, "converged": converged, "estimates": {
        "gear.torsional_damping": _est(1.62, 0.075), "gear.torsional_stiffness": _est(9790.0, 40.0),
        "drive.coulomb_torque": _est(0.03, 0.002)}}
    seen = {}

    def job(label, effs, free, pset, data, **kw):
        return {"label": label, "settings": SimpleNamespace(holdout_every=3)}

    def run_jobs(jobs, workers, say):
        seen["holdout_every"] = jobs[0]["settings"].holdout_every
        return [every]
    monkeypatch.setattr(engine, "_run_jobs", run_jobs)
    monkeypatch.setattr(engine.dataclasses, "replace", lambda s, **kw: SimpleNamespace(**{**vars(s), **kw}))
    monkeypatch.setattr(engine, "_chi2_by_channel", lambda fit, noise, select, w=None: {"motor_speed": fit["chi2_all"]})
    st = SimpleNamespace(determination_z=2.0, holdout_layout="every_kth", final_on_every_segment=True)

    def check(added_=None, effects=("drivetrain_compliance",)):
        return engine._every_segment_check(added if added_ is None else added_, current, effects,
                                           tuple(current["free"]), default_parameters(), [], {}, st, job,
                                           lambda *a: None)
    return engine, current, every, added, st, seen, check


def test_the_every_segment_check_reports_a_move_with_the_range_of_both_fits(monkeypatch):
    """The final model fitted on every segment, the held-out ones too (engine._every_segment_check): a parameter
    beyond 2 combined standard errors and 10 % is reported (the entry's every_segment, the final value's range over
    both fits' 95 % intervals, the doc's list); one within its errors is not; a base correction's move goes to the
    doc's moved_other; a final model without a found effect is fitted too; a failed fit is said, nothing moved."""
    engine, current, every, added, st, seen, check = _every_case(monkeypatch)
    doc, fit = check()
    assert fit is every and doc["sound"] is True
    assert seen["holdout_every"] == 0  # every segment fitted
    assert doc["moved"] == ["gear.torsional_damping"] and doc["holdout_layout"] == "every_kth"
    assert list(doc["moved_other"]) == ["drive.coulomb_torque"]
    lo_c, hi_c = doc["moved_other"]["drive.coulomb_torque"]["range"]
    assert lo_c == pytest.approx(0.03 - 1.96 * 0.002) and hi_c == pytest.approx(0.05 + 1.96 * 0.002)
    from thsa_control.report.trace import _every_segment_other_text, _every_segment_text
    (other,) = _every_segment_other_text({"every_segment": doc})
    assert "drive.coulomb_torque = 0.03" in other and "0.05 on the training segments" in other
    ev = added[0]["every_segment"]
    assert ev["moved"] == ["gear.torsional_damping"] and ev["parameters"]["gear.torsional_damping"]["value"] == 1.62
    lo, hi = added[0]["parameters"]["gear.torsional_damping"]["range_over_segment_sets"]
    assert lo == pytest.approx(0.42 - 1.96 * 0.10) and hi == pytest.approx(1.62 + 1.96 * 0.075)
    assert "range_over_segment_sets" not in added[0]["parameters"]["gear.torsional_stiffness"]
    (line,) = _every_segment_text(added[0])
    assert "1.62" in line and "0.42 on the training segments" in line
    # a final model with base corrections only (no found effect) is fitted on every segment too
    doc_b, fit_b = check([], ())
    assert fit_b is every and set(doc_b["moved_other"]) == {"gear.torsional_damping", "drive.coulomb_torque"}
    monkeypatch.setattr(engine, "_run_jobs", lambda jobs, w, say: [{"error": "solver failed"}])
    doc_e, fit_e = check([dict(added[0], every_segment=None)], ())
    assert fit_e is None and doc_e["error"] == "solver failed" and doc_e["sound"] is False


def test_an_every_segment_fit_that_went_astray_is_not_read(monkeypatch):
    """A fit on every segment that did not converge, or whose error over every sample is above the search's last
    fit's (it starts there: rig_ratchet_backlash's went to 680716 against 130073), is not read: no move is said, no
    range put, and the doc says why."""
    for args, why in (((100.0, 100.5), "above the search's"), ((100.0, 80.0, False), "did not converge")):
        engine, current, every, added, st, seen, check = _every_case(monkeypatch, *args)
        doc, fit = check()
        assert fit is None and doc["sound"] is False and why in doc["why"], doc
        assert doc["moved"] == [] and doc["moved_other"] == {} and "every_segment" not in added[0]
        assert "range_over_segment_sets" not in added[0]["parameters"]["gear.torsional_damping"]


def test_the_every_segment_fit_starts_at_the_search_and_goes_on_past_its_evaluation_limit(monkeypatch):
    """The fit on every segment starts from the search's optimum, its segment states included (from the measured
    states it found other optima: rig_cogging 4990 against the search's 4176); stopped by the evaluation limit it
    goes on from where it stopped (its values and states), at most EVERY_SEGMENT_FITS fits; a time budget is not
    retried."""
    engine, current, every, added, st, seen, check = _every_case(monkeypatch)
    st.max_nfev = 40
    current["segment_states"] = {"r": np.arange(4.0)}
    stopped = {**every, "converged": False, "params_toml": default_parameters().to_toml(),
               "status": "not converged: status 0: maximum number of function evaluations (40) exceeded; best point",
               "segment_states": {"r": np.arange(4.0) + 1}}
    calls = []

    def run_jobs(jobs, workers, say, queue=[stopped, every]):
        calls.append(jobs[0])
        return [queue[min(len(calls), len(queue)) - 1]]
    monkeypatch.setattr(engine, "_run_jobs", run_jobs)
    doc, fit = check()
    assert fit is every and doc["sound"] is True and doc["fits"] == 2
    assert calls[0]["initial_states"] is current["segment_states"]
    assert calls[1]["initial_states"] is stopped["segment_states"] and calls[1]["settings"].holdout_every == 0
    calls.clear()
    monkeypatch.setattr(engine, "_run_jobs", lambda jobs, w, say: calls.append(1) or [stopped])
    doc, fit = check()
    assert fit is None and len(calls) == engine.EVERY_SEGMENT_FITS and "did not converge (not converged: status 0"\
        in doc["why"]
    calls.clear()
    budget = {**stopped, "status": "not converged: time budget 120 s reached; best point of 31 evaluations"}
    monkeypatch.setattr(engine, "_run_jobs", lambda jobs, w, say: calls.append(1) or [budget])
    doc, fit = check()
    assert fit is None and len(calls) == 1 and "time budget" in doc["why"]


def test_the_final_values_are_the_every_segment_fits_where_it_is_sound(monkeypatch):
    """Once the held-out segments decided the effects, every sample estimates their values
    (engine._adopt_every_segment): the final model is the every-segment fit, each found effect's parameters_final
    its values with the ranges kept; a fit not read or not asked for leaves the search's values, and says why."""
    said = []
    engine, current, every, added, st, seen, check = _every_case(monkeypatch)
    doc, fit = check()
    assert engine._adopt_every_segment(added, current, fit, doc, st, said.append) is every
    p = added[0]["parameters_final"]["gear.torsional_damping"]
    assert p["value"] == 1.62 and p["stderr"] == 0.075 and p["range_over_segment_sets"][1] == pytest.approx(1.767)
    # the weight check's range was about the search's value (0.42): the final 1.62 lies outside it, so it is kept
    # as the training fit's, not shown as the final value's
    assert "range_over_channel_weights" not in p and p["range_over_channel_weights_training"] == [0.3, 0.5]
    assert any("lies outside it" in m for m in said) and doc["adopted"] is True
    assert added[0]["every_segment"]["adopted"] is True and "parameters_final" not in added[1]
    engine, current, every, added, st, seen, check = _every_case(monkeypatch, 100.0, 100.5)
    doc, fit = check()
    assert engine._adopt_every_segment(added, current, fit, doc, st, said.append) is current
    assert doc["adopted"] is False and "above the search's" in doc["why"] and "above the search's" in said[-1]
    assert added[0]["parameters_final"]["gear.torsional_damping"]["value"] == 0.42
    engine, current, every, added, st, seen, check = _every_case(monkeypatch)
    doc, fit = check()
    off = SimpleNamespace(final_on_every_segment=False)
    assert engine._adopt_every_segment(added, current, fit, doc, off, said.append) is current
    assert doc["adopted"] is False and "final_on_every_segment" in doc["why"]
    assert engine._adopt_every_segment(added, current, fit, None, st, said.append) is current


def test_a_final_value_the_segments_spread_wider_is_said_with_their_interval():
    """A final value whose segment-clustered standard error is more than twice the information's gets a line with
    the interval the segments support (report.trace._segments_text); one within that, or without it, none; and the
    interval is from the larger of the two standard errors, inside the physical range (scoring._segments_entry)."""
    from thsa_control.report.trace import _segments_text
    from thsa_control.trace.scoring import _param_entry

    def entry(sd, ss):
        return _param_entry({"value": 9.7, "stderr": sd, "stderr_segments": ss, "unit": "N m s/rad",
                             "at_bound": None, "min": 0.0})
    e = {"parameters_final": {"gear.torsional_damping": entry(0.27, 5.8), "gear.torsional_stiffness": entry(76.0, 90.0)}}
    (line,) = _segments_text(e)
    lo, hi = e["parameters_final"]["gear.torsional_damping"]["ci95_segments"]
    assert lo == 0.0 and hi == pytest.approx(9.7 + 1.96 * 5.8)  # inside the physical range: not below zero
    assert "gear.torsional_damping" in line and "21.5 x" in line and f"{hi:.4g}" in line
    narrow = entry(0.27, 0.1)["ci95_segments"]  # the larger of the two: never narrower than the information's
    assert narrow == pytest.approx([9.7 - 1.96 * 0.27, 9.7 + 1.96 * 0.27])
    assert _segments_text({"parameters": {"x": entry(0.27, None)}}) == []


def test_the_segments_that_pull_a_value_most_are_named_where_one_moves_it_by_two_standard_errors():
    """scoring._pulled_by: the three segments whose leaving out moves an estimate most (the fit's first-order
    segment influence, in standard errors), with their run and times, where one moves it by 2 or more; none where
    every segment moves it less; the report's segments line says which way and by how much."""
    from types import MappingProxyType
    from thsa_control.report.trace import _segments_text
    from thsa_control.trace.scoring import _param_entry, _pulled_by

    infl = np.zeros((6, 2))
    infl[2, 0], infl[4, 0], infl[1, 0], infl[3, 1] = 13.0, -11.0, 3.0, 1.5
    res = SimpleNamespace(estimates=MappingProxyType({"gear.torsional_damping": None, "gear.torsional_stiffness": None}),
                          segment_influence={"run": infl},
                          predictions={"run": {"segment_starts": np.arange(6) * 0.05 + 5.5}},
                          settings=SimpleNamespace(segment_duration=0.05))
    got = _pulled_by(res, "gear.torsional_damping")["pulled_by"]
    assert [q["moves_by_stderr"] for q in got] == [13.0, -11.0, 3.0]
    assert got[0]["run"] == "run" and got[0]["t0"] == pytest.approx(5.6) and got[0]["t1"] == pytest.approx(5.65)
    assert _pulled_by(res, "gear.torsional_stiffness") == {}  # 1.5 standard errors at most: not named
    assert _pulled_by(SimpleNamespace(estimates={}, segment_influence={}), "x") == {}
    p = _param_entry({"value": 9.95, "stderr": 0.29, "stderr_segments": 5.8, "unit": "N m s/rad", "at_bound": None,
                      "min": 0.0, "pulled_by": got})
    (line,) = _segments_text({"parameters_final": {"gear.torsional_damping": p}})
    assert "up by 13 without 5.60-5.65 s" in line and "down by 11 without 5.70-5.75 s" in line


def test_a_move_to_zero_on_every_segment_is_a_move(monkeypatch):
    """The every-segment fit of the same model determines its values as the search's did: one it puts at zero within
    its errors has moved, and gets its range (rig_sensor_gain_lvdt: the soft zone 16.8 +- 0.23 um on the training
    segments, 0 +- 0.24 um on every segment; rig-sim's load path is linear).  The weight check keeps its rule (an
    estimate at zero there says the weighting does not determine it)."""
    engine, current, every, added, st, seen, check = _every_case(monkeypatch)
    every["estimates"]["gear.torsional_damping"] = _est(0.0, 0.075)
    doc, fit = check()
    assert "gear.torsional_damping" in doc["moved"], doc
    lo, hi = added[0]["parameters"]["gear.torsional_damping"]["range_over_segment_sets"]
    assert lo == pytest.approx(0.0) and hi == pytest.approx(0.42 + 1.96 * 0.10)  # clipped at the physical minimum
    from thsa_control.trace import weights as wt
    assert wt.compare(_est(0.42, 0.10), {"w": _est(0.0, 0.075)}, 2.0)[1] is None


def test_a_ripples_final_amplitude_is_the_final_models():
    """A cosine and sine pair's amplitude is reported as the final model has it (``amplitude_final``, the every-segment
    fit where adopted: engine._put_amplitude_final), beside the amplitude when it was added; the summary and the table
    say the final one where it differs; a held part gives none, and an effect that is no pair none."""
    from thsa_control.report.trace import _amplitude_lines
    from thsa_control.trace.candidates import CANDIDATES
    from thsa_control.trace.engine import _put_amplitude_final
    from thsa_control.trace.scoring import _amplitude_out

    spec = CANDIDATES["cogging_torque"]
    a, b = spec.free

    def fit(c, s, sd=0.002):
        entry = dict(stderr=sd, unit="N m", at_bound=None, min=-1.0, max=1.0)
        return {"estimates": {a: {**entry, "value": c, "corr": {b: 0.0}}, b: {**entry, "value": s, "corr": {a: 0.0}}}}

    e = {"name": "cogging_torque", **_amplitude_out(fit(0.03, 0.04), spec)}
    _put_amplitude_final(e, fit(0.0, 0.05, 0.001))
    assert e["amplitude"]["value"] == pytest.approx(0.05) and e["amplitude_final"]["value"] == pytest.approx(0.05)
    assert e["amplitude_final"]["stderr"] == pytest.approx(0.001)  # along the radius: the one part's alone
    assert _amplitude_lines(e) == _amplitude_lines({"amplitude": e["amplitude"]})  # the same size: one line
    _put_amplitude_final(e, fit(0.0, 0.062))
    lines = _amplitude_lines(e)
    assert len(lines) == 2 and lines[1].startswith("in the final model: amplitude 0.062")
    held = fit(0.0, 0.062)
    held["estimates"][a]["held"] = True
    _put_amplitude_final(e, held)
    assert "amplitude_final" not in e
    other = {"name": "noback_quadrant_friction"}
    _put_amplitude_final(other, fit(0.03, 0.04))
    assert "amplitude_final" not in other
