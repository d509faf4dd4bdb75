"""An earlier effect's parameter held as undecided, freed again once a later effect is in the model
(:func:`thsa_control.trace.engine._refree_held`; the end-to-end case on rig-sim's pawl clearance is the campaign test
``test_a_disk_coefficient_held_without_the_pawl_clearance_is_determined_once_the_clearance_is_in``).

The fits are stood in for: what is judged here is which holds are tried, with which judge, and when the refit is
adopted.  The determination rule itself is :func:`thsa_control.trace.scoring._undetermined` (tests/test_trace_identifiability.py).
"""

from __future__ import annotations

import pytest

from thsa_control.model.params import default_parameters
from thsa_control.trace import engine
from thsa_control.trace.scoring import determination


def _held(name, value, stderr, **extra):
    return {"parameter": name, "held_at": value, "unit": "N m/N", "reason": "undecided", "value_if_free": 0.05,
            "stderr_if_free": stderr, **extra}


def _est(value, stderr=1e-5, held=False, init=0.0043, ref=0.0043):
    """An estimate as the fit job returns it: a free one judged by the determination rule against ``ref``."""
    e = {"value": value, "stderr": None if held else stderr, "stderr_data": stderr, "unit": "N m/N",
         "at_bound": None, "min": 0.0, "max": 0.1, "init": value if held else init}
    if held:
        e["held"] = True
    else:
        e["determination"] = determination(value, stderr, ref, 2.0, True)
    return e


@pytest.fixture
def setting():
    params = default_parameters()
    added = [
        {"name": "noback_quadrant_friction", "parameters": {},
         "not_determined": [_held("noback.mu_coulomb_neg", 0.0043, 0.19),     # undecided: tried
                            _held("noback.mu_coulomb_pos", 0.0048, None),     # a null direction: not tried
                            _held("noback.load_share", 0.5, 0.3, profile_set=["x"])]},  # profiled: not tried
        {"name": "noback_backlash", "parameters": {},
         "not_determined": [_held("noback.pawl_initial_clearance", 0.5, 0.2)]},  # the effect just added: not tried
    ]
    current = {"chisqr": 100.0, "estimates": {}, "segment_states": {"r": [1.0]}, "custom_states": {}}
    jobs = []

    def job(label, effs, free, pset, data, **kw):
        jb = {"label": label, "effects": tuple(effs), "free": tuple(free), "params_toml": "", "judge": {},
              "hold_at": {}, "absent": {}}
        jobs.append(jb)
        return jb

    return params, added, current, jobs, job


def _call(setting, monkeypatch, fit, ref_held=None):
    params, added, current, jobs, job = setting
    seen = []

    def run_jobs(jbs, workers, progress):
        seen.extend(jbs)
        return [fit(jb) for jb in jbs]

    monkeypatch.setattr(engine, "_run_jobs", run_jobs)
    out = engine._refree_held(added, "noback_backlash", current, ("noback_quadrant_friction", "noback_backlash"),
                              ("screw.efficiency_direct",), params, [], params, {}, ref_held or {}, job,
                              lambda m: None)
    return out, seen


def test_only_an_undecided_hold_of_an_earlier_effect_is_tried_with_its_own_reference(setting, monkeypatch):
    """A finite standard error (information, not enough): tried; a null direction, a profiled parameter and the
    effect just added: not.  The refit starts from the current fit's segment states, judged against the parameter
    file's magnitude, holding at the current value; started from the current fit's segment states and from the
    fit's own, as every candidate's (each alone failed on one of rig-sim's pawl records)."""
    params = setting[0]

    def fit(jb):
        return {"chisqr": 60.0, "free": list(jb["free"]),
                "estimates": {"noback.mu_coulomb_neg": _est(0.00466, 3e-5)}, "held": {}}

    out, seen = _call(setting, monkeypatch, fit)
    assert len(seen) == 2  # two starts: the current fit's segment states, the fit's own
    assert seen[0]["initial_states"] == {"r": [1.0]} and "initial_states" not in seen[1]
    jb = seen[1]
    assert jb["free"] == ("screw.efficiency_direct", "noback.mu_coulomb_neg")
    assert jb["judge"] == {"noback.mu_coulomb_neg": pytest.approx(abs(params.value("noback.mu_coulomb_neg")))}
    assert jb["hold_at"] == {"noback.mu_coulomb_neg": params.value("noback.mu_coulomb_neg")}
    assert "initial_states" not in jb and "custom_states" not in jb
    rec, f = out
    assert f is not None and rec["adopted"] and set(rec["starts"]) == {"current_states", "own_states"}
    assert rec["given"] == "noback_backlash" and rec["tried"] == ["noback.mu_coulomb_neg"]
    assert rec["determined"]["noback.mu_coulomb_neg"]["value"] == pytest.approx(0.00466)
    nb = setting[1][0]
    # moved from not_determined to determined_later, the other holds untouched
    assert [h["parameter"] for h in nb["not_determined"]] == ["noback.mu_coulomb_pos", "noback.load_share"]
    (later,) = nb["determined_later"]
    assert later["parameter"] == "noback.mu_coulomb_neg" and later["determined_given"] == "noback_backlash"
    assert later["held_at"] == 0.0043 and later["value"] == pytest.approx(0.00466)


def test_a_refit_that_holds_it_again_or_fits_worse_is_not_adopted(setting, monkeypatch):
    def held_again(jb):
        return {"chisqr": 99.0, "free": [n for n in jb["free"] if n != "noback.mu_coulomb_neg"],
                "estimates": {"noback.mu_coulomb_neg": _est(0.0043, held=True)},
                "held": {"noback.mu_coulomb_neg": {"reason": "still undecided", "held_at": 0.0043}}}

    out, _ = _call(setting, monkeypatch, held_again)
    rec, f = out
    assert f is None and not rec["adopted"] and rec["why_not"] == "none determined"
    assert rec["still_held"] == {"noback.mu_coulomb_neg": "still undecided"}
    assert "determined_later" not in setting[1][0]
    assert "noback.mu_coulomb_neg" in [h["parameter"] for h in setting[1][0]["not_determined"]]

    def worse(jb):
        return {"chisqr": 100.5, "free": list(jb["free"]),
                "estimates": {"noback.mu_coulomb_neg": _est(0.0049, 3e-5)}, "held": {}}

    out, _ = _call(setting, monkeypatch, worse)
    assert out[1] is None and out[0]["why_not"] == "the refit fits the training samples worse"
    assert "determined_later" not in setting[1][0]

    out, _ = _call(setting, monkeypatch, lambda jb: {"error": "solver failed"})
    assert out[1] is None and "solver failed" in out[0]["why_not"] and "determined_later" not in setting[1][0]


def test_holds_of_an_effect_defined_at_a_reference_the_runs_never_reach_are_not_tried(setting, monkeypatch):
    """The cold drag on a cold-only record: only ``b_25 exp(a_v dT)`` shows, a later effect does not change that
    (its reference parameter was held by the declared rule, ``reference_not_determined``)."""
    params, added, current, jobs, job = setting
    spec = engine.CANDIDATES["temperature_friction"]
    assert spec.reference, "temperature_friction reads a declared reference parameter"
    added.insert(0, {"name": "temperature_friction", "parameters": {},
                     "not_determined": [_held("friction.viscous_temperature_coefficient", 0.01, 0.05)]})
    added[1]["not_determined"] = []  # only the cold drag's hold is left to try
    calls = []
    out, seen = _call(setting, monkeypatch, lambda jb: calls.append(jb) or {"error": "not expected"},
                      ref_held={spec.reference[0]: "the runs never reach 25 degC"})
    assert out is None and seen == []
    out, seen = _call(setting, monkeypatch, lambda jb: {"error": "fitted"}, ref_held={})
    assert out[1] is None
    assert [n for n in seen[0]["free"] if n.startswith("friction.")] == ["friction.viscous_temperature_coefficient"]


def test_a_refit_that_leaves_it_free_but_undecided_is_not_a_determination(setting, monkeypatch):
    """A fit whose every freed parameter is undecided keeps them free, marked ``undetermined`` with no held value
    (:func:`scoring._hold_undetermined`); and a finite estimate within two standard errors of both zero and the
    reference is the rule that held it.  Neither is adopted (measured on rig_cogging_steps before the rule was
    applied to the refit: 0.030 with a standard error of 142 on a 0.0048 coefficient, reported determined)."""
    def marked(jb):
        e = {**_est(0.0048, None), "undetermined": {"reason": "undetermined standard error", "held_at": None}}
        e.pop("determination")  # the fit job gives no verdict on a parameter it marked undetermined
        return {"chisqr": 99.0, "free": list(jb["free"]), "estimates": {"noback.mu_coulomb_neg": e}, "held": {}}

    def wide(jb):
        return {"chisqr": 99.0, "free": list(jb["free"]),
                "estimates": {"noback.mu_coulomb_neg": _est(0.030, 142.0)}, "held": {}}

    for fit in (marked, wide):
        out, _ = _call(setting, monkeypatch, fit)
        assert out[1] is None and not out[0]["adopted"], fit.__name__
        assert "determined_later" not in setting[1][0]
        assert "noback.mu_coulomb_neg" in [h["parameter"] for h in setting[1][0]["not_determined"]]

    def near(jb):  # determined: far from zero in its standard errors
        return {"chisqr": 99.0, "free": list(jb["free"]),
                "estimates": {"noback.mu_coulomb_neg": _est(0.0046, 2e-4)}, "held": {}}

    rec, _ = _call(setting, monkeypatch, near)[0]
    assert rec["determined"]["noback.mu_coulomb_neg"]["determination"] == "determined"


def test_a_refit_that_never_left_its_start_is_not_adopted(setting, monkeypatch):
    """Every parameter at its start (the trust region shrank to nothing, status xtol): the standard error there is
    the curvature at the start, not at an optimum; held as before (measured: 0.0043 "determined" at the file value
    on rig_ratchet_backlash_lowgain when the refit was started from the current fit's segment states)."""
    def stalled(jb):
        return {"chisqr": 99.0, "free": list(jb["free"]), "status": "status 3: xtol",
                "estimates": {"noback.mu_coulomb_neg": _est(0.0043, 3.4e-5, init=0.0043),
                              "screw.efficiency_direct": _est(0.915, 0.01, init=0.915)}, "held": {}}

    out, _ = _call(setting, monkeypatch, stalled)
    assert out[1] is None and "moved" in out[0]["why_not"] and "determined_later" not in setting[1][0]


def test_of_two_starts_the_one_that_moved_is_judged(setting, monkeypatch):
    """From the current states the fit stalls at its start with the lower training error (the states alone
    improved); from its own states it moves: that one is judged and kept."""
    def two(jb):
        if jb.get("initial_states"):
            return {"chisqr": 90.0, "free": list(jb["free"]), "status": "status 3: xtol",
                    "estimates": {"noback.mu_coulomb_neg": _est(0.0043, 3.4e-5, init=0.0043)}, "held": {}}
        return {"chisqr": 95.0, "free": list(jb["free"]),
                "estimates": {"noback.mu_coulomb_neg": _est(0.00466, 3.4e-5)}, "held": {}}

    rec, f = _call(setting, monkeypatch, two)[0]
    assert rec["adopted"] and rec["start"] == "own_states"
    assert rec["starts"]["current_states"]["moved"] is False
    assert rec["determined"]["noback.mu_coulomb_neg"]["value"] == pytest.approx(0.00466)
