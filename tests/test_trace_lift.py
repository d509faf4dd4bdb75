"""Constant torques beyond a plausible base (issue #21, branch trace-lift): the joint lift of the base corrections,
the whole contribution of an effect partly inside a base correction, and the scoring mask of records whose load
ramps steadily.  The rig-sim traces themselves are judged by tests/test_trace_foreign.py's campaign."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from handcalc import RIG_NOISE

from thsa_control.data.rigdata import read_run
from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs
from thsa_control.trace import TraceSettings, trace
from thsa_control.trace.engine import EFFICIENCY_LIFT as EFF
from thsa_control.trace.lift import beyond_base, current_proportional_is_base
from thsa_control.trace.signature import TORQUE_CONSTANT
from thsa_control.trace.signature import base_transients


def _ramp(load_of_t, duration=10.0, hz=500.0):
    t = np.arange(0.0, duration, 1.0 / hz)
    w = np.full(t.size, 100.0)  # steady motion all along: only the load can make a transient
    return t, w, load_of_t(t)


def test_a_steady_load_ramp_is_no_transient_a_load_step_is():
    """A load ramping at a constant rate (a triangular sweep, 11.6 kN/s) settles nothing: with ``load_steps`` only
    the apexes of the triangle, where the rate reverses, are load changes; a load applied in 0.2 s is one, in both
    definitions."""
    t, w, f = _ramp(lambda t: np.interp(t, [0, 2.5, 7.5, 10.0], [0.0, 29e3, -29e3, 0.0]))
    plain = base_transients(t, w, f, 0.3)
    steps = base_transients(t, w, f, 0.3, load_steps=True)
    assert plain.all()  # every 0.3 s the load moves by 3.5 kN > 5 % of its 58 kN range
    assert steps[np.abs(t - 2.5) < 0.1].all() and steps[np.abs(t - 7.5) < 0.1].all()  # the apexes
    away = (np.abs(t - 2.5) > 0.7) & (np.abs(t - 7.5) > 0.7) & (t > 0.7) & (t < 9.3)
    assert not steps[away].any()
    t, w, f = _ramp(lambda t: np.interp(t, [0, 4.0, 4.2, 10.0], [0.0, 0.0, 30e3, 30e3]))
    for mask in (base_transients(t, w, f, 0.3), base_transients(t, w, f, 0.3, load_steps=True)):
        assert mask[np.abs(t - 4.1) < 0.3].all() and not mask[t < 3.3].any() and not mask[t > 4.9].any()


def _triangle_trace(tmp_path_factory, rig_1khz, params, truth: float) -> dict:
    duration, load = 5.0, 12e3
    u = excitation_inputs(duration, bipolar=True, load=load, control_period=1e-3, seed=3)
    sig = dict(u.signals)
    sig["load_force"] = np.interp(u.time, [0, duration / 2, duration], [load, -load, load])
    u = dataclasses.replace(u, signals=sig)
    stem = tmp_path_factory.mktemp("lift") / "coulomb"
    VirtualRig("A", effects=("coulomb_friction",), params=params.replace({"drive.coulomb_torque": truth}),
               design=rig_1khz, noise=RIG_NOISE, seed=3).record(u, stem)
    run = read_run(stem.with_suffix(".csv"))
    st = TraceSettings(candidates=("coulomb_friction", "force_offset", "direction_friction"), base_corrections=True,
                       max_effects=1, max_nfev=30, workers=1)
    return trace(run, "A", params=params, settings=st).to_dict()


@pytest.fixture(scope="module")
def coulomb_beyond(tmp_path_factory, rig_1khz, params):
    """The virtual rig (level A, its own ideal no-back) with a Coulomb drag of 0.15 N m, 2.6 times the base
    correction's plausible bound (3 % of rated torque, 0.057 N m), bipolar excitation while the load swings
    +12 -> -12 -> +12 kN (each direction opposed and aided at several magnitudes: on one load the efficiencies
    lifted beyond their spread are the same torque as a drag, and the tracer says so); traced with the base step
    and the three constant-torque candidates."""
    return 0.15, _triangle_trace(tmp_path_factory, rig_1khz, params, 0.15)


@pytest.mark.slow
def test_coulomb_beyond_its_bound_is_named_with_its_whole_contribution(coulomb_beyond):
    """The drag is named beyond its base correction, near the truth; its whole contribution (error with none of it
    against all of it, everything else as fitted) is at least what lies beyond the bound, and the bounded share is the
    bound over the value."""
    truth, doc = coulomb_beyond
    bc = {c["parameter"]: c for c in doc["base_corrections"]["corrections"]}
    assert bc["drive.coulomb_torque"]["at_plausible_bound"], bc
    step = next(e for e in doc["effects_added"] if e["name"] == "coulomb_friction")
    assert step.get("beyond_base_correction"), step
    value = step["parameters"]["drive.coulomb_torque"]["value"]
    assert value == pytest.approx(truth, rel=0.15)
    c = step["contribution"]
    bound = bc["drive.coulomb_torque"]["bound"][1]
    assert c["parameter"] == "drive.coulomb_torque" and c["bound"] == pytest.approx(bound)
    assert c["bounded_share"] == pytest.approx(bound / value)
    beyond = step["window_reduction"][c["channel"]]
    assert c["total_window_reduction"] >= beyond - 1e-9, (c, beyond)
    assert 0.0 < c["bounded_window_reduction"] < c["total_window_reduction"], c
    # the error is linear in the torque left unmodelled: a correction at the bound removes its share of the error
    assert c["bounded_window_reduction"] == pytest.approx(c["bounded_share"], abs=0.05), c
    # the held-out errors are ordered as the torque: none > at the bound > all of it
    assert c["holdout_chi2_none"] > c["holdout_chi2_at_bound"] > c["holdout_chi2_all"], c


@pytest.mark.slow
def test_joint_lift_is_carried_by_the_planted_drag(coulomb_beyond):
    """The whole plausible set lifted together passes its likelihood-ratio test, and the Coulomb drag alone carries
    it (its held-out drop within the chi2(k - 1) gap of the joint drop)."""
    _, doc = coulomb_beyond
    j = doc["rounds"][0]["joint_lift"]
    assert j["significant"], j
    assert j["carriers"] == ["coulomb_friction"], j  # alone: neither the efficiencies nor another torque
    assert j["holdout_chi2_drop"] - j["single_drops"]["coulomb_friction"] < j["carry_gap"], j
    b = doc["beyond_plausible_base"]  # the record's answer: named, by the drag added in that round
    assert b["status"] == "named" and [c["name"] for c in b["carriers"] if c["named"]] == ["coulomb_friction"], b
    assert b["carriers"][0]["values"]["drive.coulomb_torque"]["value"] > 0.057, b


@pytest.mark.slow
def test_a_drag_inside_its_bound_names_nothing_beyond_the_base(tmp_path_factory, rig_1khz, params):
    """The same rig with a drag of 0.03 N m, inside the plausible bound: the base correction carries it, nothing is
    named, and no joint lift passes."""
    doc = _triangle_trace(tmp_path_factory, rig_1khz, params, 0.03)
    bc = {c["parameter"]: c for c in doc["base_corrections"]["corrections"]}
    assert bc["drive.coulomb_torque"]["value"] == pytest.approx(0.03, abs=0.01), bc
    assert not [e for e in doc["effects_added"] if e.get("beyond_base_correction")], doc["effects_added"]
    assert not doc["effects_added"] and not doc["ambiguous"], doc["rounds"]
    assert not [r["joint_lift"] for r in doc["rounds"] if (r.get("joint_lift") or {}).get("significant")]
    assert doc["beyond_plausible_base"]["status"] in ("not_fitted", "within"), doc["beyond_plausible_base"]


def test_report_shows_the_whole_contribution_and_the_joint_lift():
    """The summary and the conclusion table carry the effect's whole contribution beside the window drop beyond its
    bound, and each round's joint-lift verdict."""
    from thsa_control.report.trace import conclusion_table_html, format_trace_summary

    err = {"motor_speed": {"rms": 1.0, "unit": "rad/s", "fit_percent": 90.0}}
    contrib = {"parameter": "drive.coulomb_torque", "channel": "motor_speed", "value": 0.151, "bound": 0.057,
               "bounded_share": 0.377, "total_window_reduction": 0.98, "bounded_window_reduction": 0.377}
    joint = {"parameters_lifted": 4, "holdout_chi2_drop": 13191.5, "chi2_threshold": 18.5, "significant": True,
             "carriers": ["coulomb_friction"], "verdict": "carried by coulomb_friction alone",
             "values": {"drive.coulomb_torque": 0.15}, "single_drops": {"coulomb_friction": 13191.5}}
    doc = {"base_model": "A", "declared_effects": ["noback_ideal"], "uncertain_parameters": [],
           "effects_added": [{"name": "coulomb_friction", "beyond_base_correction": True, "score": 1.0, "aic_drop": 1.0,
                              "bic_drop": 1.0, "parameters": {}, "not_determined": [],
                              "window_reduction": {"motor_speed": 0.86}, "error_reduction": {"motor_speed": 0.8},
                              "error_before": err, "error_after": err, "contribution": contrib}],
           "ambiguous": [], "rounds": [{"round": 1, "model": [], "candidates": [], "skipped": [], "joint_lift": joint}],
           "error_before": err, "error_after": err, "unexplained": False,
           "residual_signature": {"structured": [], "base_like": [], "tests": [], "sensors": []}}
    text = format_trace_summary(doc)
    html = conclusion_table_html(doc)
    for out in (text, html):
        assert "whole contribution" in out and "98 %" in out and "38 % of the value" in out
        assert "carried by coulomb_friction alone" in out


def _rounds(joint: dict, model=("standby_motor",), added_round=None, refusal=None) -> list[dict]:
    cands = [{"name": "coulomb_friction", "holdout_chi2_drop": 39.7, "beyond_base_correction": True,
              "parameters": {"drive.coulomb_torque": {"value": 0.096, "ci95": [0.022, 0.17], "unit": "N m"}},
              **({"not_robust": refusal} if refusal else {})},
             {"name": "direction_friction", "holdout_chi2_drop": 37.2,
              "parameters": {"drive.direction_coulomb_torque": {"value": 0.19, "ci95": [0.11, 0.27], "unit": "N m"}}}]
    return [{"round": 1, "model": list(model), "candidates": cands, "joint_lift": joint}]


BASE = {"accepted": True, "corrections": [{"parameter": "drive.coulomb_torque", "bound": [0.0, 0.057]},
                                          {"parameter": "screw.efficiency_direct", "bound": [0.831, 0.969]}]}


def _joint(significant=True, carriers=("coulomb_friction", "direction_friction", EFF)):
    return {"significant": significant, "holdout_chi2_drop": 42.1 if significant else 12.0, "chi2_threshold": 28.5,
            "carriers": list(carriers) if significant else [],
            "single_drops": {"coulomb_friction": 39.7, "direction_friction": 37.2, EFF: 42.1},
            "carrier_values": {EFF: {"screw.efficiency_direct": {"value": 0.80, "ci95": [0.78, 0.82], "unit": "-"}}}}


def test_the_records_answer_beyond_a_plausible_base_follows_the_last_joint_lift():
    """``beyond_plausible_base`` reads the last round's joint lift: no lift fitted, a lift that does not pass, one
    that passes carried by several (each with its own values against the plausible bound and why it was not named),
    one carried by the effect added in that round, and one with no carrier."""
    final = ["standby_motor"]
    b = beyond_base([{"round": 1, "model": final, "candidates": []}], final, BASE, [], EFF)
    assert b["status"] == "not_fitted" and "plausible bound" in b["why"]
    assert beyond_base([], final, None, [], EFF)["status"] == "not_fitted"
    b = beyond_base(_rounds(_joint(significant=False)), final, BASE, [], EFF)
    assert b["status"] == "within" and b["on_final_model"]
    b = beyond_base(_rounds(_joint(), refusal="improves 10 of 15"), final, BASE, [], EFF)
    assert b["status"] == "not_named"
    by = {c["name"]: c for c in b["carriers"]}
    assert set(by) == {"coulomb_friction", "direction_friction", EFF} and by[EFF]["base"]
    assert by["coulomb_friction"]["values"]["drive.coulomb_torque"]["plausible_bound"] == [0.0, 0.057]
    assert "plausible_bound" not in by["direction_friction"]["values"]["drive.direction_coulomb_torque"]
    assert by[EFF]["values"]["screw.efficiency_direct"]["plausible_bound"] == [0.831, 0.969]
    assert by["coulomb_friction"]["not_named_because"] == "improves 10 of 15"
    assert not any(c["named"] for c in b["carriers"])
    added = [{"name": "coulomb_friction", "round_added": 1}]
    b = beyond_base(_rounds(_joint(carriers=("coulomb_friction",))), final + ["coulomb_friction"], BASE, added, EFF)
    assert b["status"] == "named" and not b["on_final_model"] and b["carriers"][0]["named"]
    # the drop carried by a drag lifted that stays inside its plausible bound: nothing beyond the plausible base
    inside = _rounds(_joint(carriers=("coulomb_friction", "direction_friction")))
    inside[0]["candidates"][0]["parameters"]["drive.coulomb_torque"]["value"] = 0.039
    b = beyond_base(inside, final, BASE, [], EFF)
    assert b["status"] == "within" and b["explained_inside_bounds_by"] == "coulomb_friction", b
    assert [c["inside_plausible_bounds"] for c in b["carriers"]] == [True, False]
    b = beyond_base(_rounds(_joint(carriers=())), final, BASE, [], EFF)
    assert b["status"] == "no_carrier" and b["carriers"] == []
    # the model changed after the lift (an effect added in round 1); round 2 on the final model fitted none
    later = _rounds(_joint(), refusal="improves 10 of 15") + [{"round": 2, "model": final + ["cogging_torque"],
                                                              "candidates": []}]
    ripple = [{"name": "cogging_torque", "round_added": 1}]
    b = beyond_base(later, final + ["cogging_torque"], BASE, ripple, EFF)
    assert b["status"] == "within" and b["before"]["status"] == "not_named" and "round 2" in b["verdict"], b
    b = beyond_base(later[:1], final + ["cogging_torque"], BASE, ripple, EFF)  # the search ended on the addition
    assert b["status"] == "not_on_final_model" and "cogging_torque" in b["verdict"], b
    b = beyond_base(_rounds({"error": "solver stopped"}), final, BASE, [], EFF)
    assert b["status"] == "failed" and "solver stopped" in b["why"]


def test_the_answer_beyond_the_base_says_when_the_record_is_too_short_to_name_a_constant_torque():
    """Where every carrier but the base was refused by the robustness test on too few held-out segments to pass at
    all, the not-named answer says the record is too short and what would hold enough; where one of them was refused
    otherwise (here: on enough segments), it does not."""
    final = ["standby_motor"]
    short = {"segments": 4, "needed": 10, "smallest_p": 0.0625, "window_s_needed": 1.5}
    rounds = _rounds(_joint(), refusal="improves 4 of 4 ...: too few segments to decide")
    for c in rounds[0]["candidates"]:
        c["not_robust"] = "improves 4 of 4 ...: too few segments to decide"
        c["too_few_segments"] = dict(short)
    b = beyond_base(rounds, final, BASE, [], EFF)
    assert b["status"] == "not_named" and b["too_few_segments"] == short
    assert "too short for the robustness test to pass any" in b["verdict"] and "10 needed" in b["verdict"]
    assert "1.5 s of steady motion" in b["verdict"]
    by = {c["name"]: c for c in b["carriers"]}
    assert by["coulomb_friction"]["too_few_segments"] == short and "too_few_segments" not in by[EFF]
    from thsa_control.report.trace import beyond_base_lines

    said = "\n".join(beyond_base_lines({"beyond_plausible_base": b}))
    assert "too short for any of them to pass the robustness test" in said and "1.5 s of steady motion" in said
    # one carrier refused on enough segments: the record is not too short for it
    del rounds[0]["candidates"][1]["too_few_segments"]
    rounds[0]["candidates"][1]["not_robust"] = "improves 20 of 40 held-out segments"
    b = beyond_base(rounds, final, BASE, [], EFF)
    assert b["status"] == "not_named" and "too_few_segments" not in b and "too short" not in b["verdict"]
    assert "too short" not in "\n".join(beyond_base_lines({"beyond_plausible_base": b}))


def test_a_current_proportional_remainder_is_the_lossier_base_where_the_efficiencies_carry_the_answer():
    """The signature's torque proportional to the current is what a lossier screw and gearbox leaves: where the
    record's answer beyond a plausible base lists the efficiencies among its unnamed carriers, that test describes
    the base (``unexplained`` no longer follows from it); the current's drift in time at one operating point (a
    torque constant changing with the rotor's temperature) stays structured.  Where the efficiencies do not carry
    the answer, or a carrier was named, or the lift does not pass, the test is left as it was."""
    from thsa_control.report.trace import why_base_lines
    from thsa_control.trace.signature import split_remainder

    def sig():
        return {"tests": [{"variable": TORQUE_CONSTANT, "significant": True, "remainder": "structured"},
                          {"variable": TORQUE_CONSTANT + " drifting in time", "significant": True,
                           "remainder": "structured"},
                          {"variable": "time_since_reversal", "significant": True, "remainder": "base"}],
                "sensors": []}

    final = ["standby_motor"]
    answer = beyond_base(_rounds(_joint(), refusal="improves 10 of 15"), final, BASE, [], EFF)
    assert answer["status"] == "not_named"
    s = sig()
    hit = current_proportional_is_base(s, answer)
    assert hit is not None and hit["name"] == EFF
    by = {t["variable"]: t for t in s["tests"]}
    assert by[TORQUE_CONSTANT]["remainder"] == "base" and "one column" in by[TORQUE_CONSTANT]["why_base"]
    assert by[TORQUE_CONSTANT + " drifting in time"]["remainder"] == "structured"
    structured, base_like = split_remainder(s)
    assert [t["variable"] for t in structured] == [TORQUE_CONSTANT + " drifting in time"]
    lines = why_base_lines(s)  # the summary and the report say why
    assert len(lines) == 1 and lines[0].startswith(TORQUE_CONSTANT + " left as the base's"), lines
    # not carried by the efficiencies, a named carrier, a lift that does not pass: unchanged
    for a in (beyond_base(_rounds(_joint(carriers=("coulomb_friction", "direction_friction")), refusal="improves"),
                          final, BASE, [], EFF),
              beyond_base(_rounds(_joint(carriers=("coulomb_friction", EFF))), final + ["coulomb_friction"], BASE,
                          [{"name": "coulomb_friction", "round_added": 1}], EFF),
              beyond_base(_rounds(_joint(significant=False)), final, BASE, [], EFF)):
        s = sig()
        assert current_proportional_is_base(s, a) is None, a
        assert s == sig()


def test_the_summary_says_what_is_beyond_a_plausible_base_and_what_each_explanation_would_be():
    """The console summary and the report's conclusion give the answer under 'unexplained', each carrier with its
    value, interval and plausible bound."""
    from thsa_control.report.trace import beyond_base_lines, conclusion_table_html, format_trace_summary

    err = {"motor_speed": {"rms": 1.0, "unit": "rad/s", "fit_percent": 90.0}}
    doc = {"base_model": "A", "declared_effects": [], "uncertain_parameters": [], "effects_added": [],
           "ambiguous": [], "rounds": [], "error_before": err, "error_after": err,
           "unexplained": False, "separability": {"sentences": []},
           "residual_signature": {"structured": [], "base_like": [], "tests": [], "sensors": []}}
    doc["beyond_plausible_base"] = beyond_base(_rounds(_joint()), ["standby_motor"], BASE, [], EFF)
    lines = beyond_base_lines(doc)
    assert lines[0].startswith("beyond a plausible base (constant torques): PRESENT, NOT ATTRIBUTED")
    assert any("drive.coulomb_torque = 0.096 N m [0.022, 0.17] (plausible 0.057 at most)" in x for x in lines)
    assert any("screw.efficiency_direct = 0.8 - [0.78, 0.82] (plausible 0.831 .. 0.969)" in x for x in lines)
    text, html = format_trace_summary(doc), conclusion_table_html(doc)
    assert lines[0] in text and "PRESENT, NOT ATTRIBUTED" in html
    doc["beyond_plausible_base"] = {"status": "not_fitted", "why": "no base correction reached its plausible bound"}
    assert beyond_base_lines(doc) == ["beyond a plausible base (constant torques): not tested: no base correction "
                                      "reached its plausible bound"]
    doc["beyond_plausible_base"]["base_step"] = True  # the base step ran and held them: a no
    assert beyond_base_lines(doc)[0].startswith("beyond a plausible base (constant torques): no (no base correction")


def test_a_named_physical_effect_lists_the_single_lifts_it_does_not_rule_out():
    """In a round whose joint lift passes, the single lifts whose drop on the constant torques' samples reaches the
    named effect's own less the carry gap are what the record does not rule out in its place, with their refusals;
    one that explains clearly less is not listed, and none listed gives nothing."""
    from thsa_control.report.trace import not_ruled_out_text
    from thsa_control.trace.lift import not_ruled_out

    joint = {"carry_gap": 23.1, "single_drops": {"coulomb_friction": 11070.0, "force_offset": 11068.0, EFF: 11050.0,
                                                 "direction_friction": 9000.0}}
    cands = {"coulomb_friction": {"joint_lift_refused": "a lossier base explains as much"}}
    n = not_ruled_out(10650.0, joint, cands)
    assert [a["name"] for a in n["alternatives"]] == ["coulomb_friction", "force_offset", EFF]
    assert n["alternatives"][0]["not_named_because"] == "a lossier base explains as much"
    assert "not_named_because" not in n["alternatives"][1]
    # an effect that explains a little more: only the lifts within the gap below it (11090 - 23.1 = 11066.9)
    assert [a["name"] for a in not_ruled_out(11090.0, joint, cands)["alternatives"]] == ["coulomb_friction",
                                                                                         "force_offset"]
    assert not_ruled_out(20000.0, joint, cands) is None
    text = not_ruled_out_text({"not_ruled_out": n})
    assert text.startswith("this record does not rule out, in its place: coulomb_friction (held-out drop 1.107e+04")
    assert not_ruled_out_text({}) is None
