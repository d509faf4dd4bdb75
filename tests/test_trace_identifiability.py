"""Identifiability before plausibility (issue #21, item 1): one rule decides whether a candidate's parameter is
not determined by the run (held at its file value, reported) or collapses to zero (the effect refused)."""

from __future__ import annotations

import json
import math
import pickle

import pytest

from thsa_control.trace import CANDIDATES
from thsa_control.trace.engine import parts_not_shown
from thsa_control.trace.scoring import (_amplitude_out, _ci95, _param_entry, _plausibility, determination,
                                         zero_is_absent)

Z = 2.0


@pytest.mark.parametrize("value, sd, ref, expected", [
    # one-temperature cold run: the viscous temperature coefficient, file value 0.02 1/K
    (0.00075, 0.0056, 0.02, "zero"),  # the data tell zero from 0.02 (3.6 sd apart) and say zero
    (0.00075, 0.05, 0.02, "not determined"),  # within 2 sd of zero and of 0.02: the run cannot tell
    (None, None, 0.02, "not determined"),  # a null direction of the Fisher information
    (0.05, 0.01, 0.02, "determined"),  # 5 sd from zero: present (larger than the file says)
    (0.5, 0.2, 0.02, "determined"),  # poorly known, but not zero
    (-0.03, 0.01, 0.02, "determined"),  # the sign is the data's
])
def test_one_rule_for_not_determined_and_collapses_to_zero(value, sd, ref, expected):
    assert determination(value if value is not None else 0.0, sd, ref, Z) == expected


def test_the_verdict_is_consistent_at_the_boundary():
    """Between the two verdicts nothing is left undecided: moving the estimate from zero to the reference
    magnitude goes zero -> not determined -> determined, never back."""
    ref, sd = 1.0, 0.3  # zero and ref 3.3 sd apart
    order = {"zero": 0, "not determined": 1, "determined": 2}
    seen = [order[determination(v, sd, ref, Z)] for v in [i / 100 for i in range(0, 150)]]
    assert seen == sorted(seen) and set(seen) == {0, 1, 2}
    ref, sd = 1.0, 0.6  # less than 2 x 2 sd apart: never "zero"
    assert {determination(v / 100, sd, ref, Z) for v in range(0, 150)} == {"not determined", "determined"}


def test_zero_collapses_only_what_zero_removes():
    """A friction coefficient at zero removes its effect; a compliance's stiffness, damping or a signed free play
    does not (its effect has no neutral value): there the rule is the standard error against the reference
    magnitude, and "collapses to zero" is never the verdict."""
    assert zero_is_absent("temperature_friction", "friction.viscous_temperature_coefficient")
    assert zero_is_absent("noback_quadrant_friction", "noback.mu_coulomb_neg")
    assert zero_is_absent("coulomb_friction", "drive.coulomb_torque")
    assert not zero_is_absent("drivetrain_compliance", "gear.torsional_damping")
    assert not zero_is_absent("loadpath_compliance", "loadpath.backlash")
    assert determination(0.1, 1.0, 20.0, Z, zero_is_absent=False) == "determined"
    assert determination(2.0, 25.0, 20.0, Z, zero_is_absent=False) == "not determined"


def test_drivetrain_damping_is_a_second_stage_parameter():
    """The damping of the drive-train mode is freed only once the stiffness is determined (freed from the
    start it stands in for a lag on rigid data)."""
    spec = CANDIDATES["drivetrain_compliance"]
    assert spec.free == ("gear.torsional_stiffness",)
    assert spec.second_stage == ("gear.torsional_damping",)


def test_noback_load_share_is_a_second_stage_parameter():
    """The no-back's load share is freed from the disk coefficients the run determines (freed with them, it traded
    with the light disk's coefficients where the band both sets share is thin), judged against its assumed spread."""
    spec = CANDIDATES["noback_quadrant_friction"]
    assert "noback.load_share" not in spec.free and "noback.load_share" in spec.second_stage
    assert 0 < spec.resolution["noback.load_share"] < 0.5


def test_noback_preload_is_a_second_stage_parameter_whose_zero_is_a_value():
    """The disk-spring preload is freed with the share from the coefficients the run determines (only a load
    crossing the band where both disk sets carry load shows it); its lower end, 0 N, is a no-back without preload
    springs, a physical value, so a fit there is kept (a share of 0 or 1 is not: one set infinitely stiffer)."""
    spec = CANDIDATES["noback_quadrant_friction"]
    assert spec.second_stage == ("noback.preload", "noback.load_share")
    assert "noback.preload" not in spec.free
    assert spec.second_stage_range_ends == ("noback.preload",)


def test_interval_of_a_positive_parameter_stays_positive():
    """A stiffness (search bound above zero) poorly determined: its 95 % interval is symmetric in the logarithm, so it
    never reaches zero, holds the estimate with the Wald interval's coverage in log space (sd(log v) = sd / v), and
    comes back to the Wald interval when the relative error is small; a parameter that may take either sign keeps
    the Wald interval."""
    v, sd = 1.983e7, 1.044e7  # a contact stiffness on a reversal null (Wald: -6.4e5 .. 4.0e7 N/m)
    (lo, hi), scale = _ci95(v, sd, 1e3)
    assert scale == "log" and 0 < lo < v < hi
    assert math.log(hi / v) == pytest.approx(math.log(v / lo)) == pytest.approx(1.96 * sd / v)
    (lo, hi), _ = _ci95(v, 1e-3 * v, 1e3)
    assert (lo, hi) == pytest.approx((v - 1.96e-3 * v, v + 1.96e-3 * v), rel=1e-5)
    (lo, hi), scale = _ci95(-300.0, 200.0, -1e4)  # an axial force offset: either sign
    assert scale == "wald" and (lo, hi) == pytest.approx((-692.0, 92.0))
    e = {"value": v, "stderr": sd, "unit": "N/m", "at_bound": None, "min": 1e3}
    assert _param_entry(e)["ci95_scale"] == "log" and _param_entry(e)["ci95"][0] > 0


@pytest.mark.parametrize("value, sd", [(2.5e-4, 1.2), (1e9, 3.55e11)])
def test_a_positive_parameter_the_run_does_not_bound_has_no_interval(value, sd):
    """A standard error hundreds of times the estimate: the log interval's factor exp(1.96 sd / v) is beyond the
    floating-point range (exp overflowed, or the upper end is infinite): no interval (null in trace.json), the
    estimate and its standard error still reported, and no internal error (measured on a 1.6 s cold check record
    with rig-sim's cold friction: the trace stopped with "OverflowError: math range error")."""
    assert _ci95(value, sd, 1e-9) == (None, None)
    entry = _param_entry({"value": value, "stderr": sd, "unit": "-", "at_bound": None, "min": 1e-9})
    assert entry["ci95"] is None and "ci95_scale" not in entry and entry["stderr"] == sd
    json.dumps(entry, allow_nan=False)  # a standard JSON document


def test_a_declared_components_coefficient_at_zero_is_a_part_not_shown_only_beside_one_that_shows():
    """The base step's rule for a declared component's detailed model (engine.parts_not_shown): the light disk's
    static coefficient determined at zero beside a loaded-disk coefficient determined away from zero is a part the
    run does not show (reported, no refusal); every determined coefficient at zero is a component without friction
    and stays refused; other reasons always stay."""
    spec = CANDIDATES["noback_quadrant_friction"]

    def fit(**det):
        # the fields _plausibility reads: a value, its standard errors, the run's verdict, a bound
        est = {n: {"value": 1e-4, "stderr": None, "stderr_data": None, "at_bound": None,
                   "determination": det.get(n.split(".")[1], "not determined")} for n in spec.free}
        est["noback.mu_static_pos"].update(value=0.000483, stderr=0.00037, stderr_data=0.00037)
        est["noback.mu_coulomb_neg"].update(value=0.02, stderr=0.001, stderr_data=0.001, at_bound="max")
        return {"estimates": est}

    f = fit(mu_static_pos="zero", mu_coulomb_neg="determined")
    why = _plausibility(f, spec)[1]
    assert [str(w) for w in why] == ["noback.mu_coulomb_neg at its max bound",
                                     "noback.mu_static_pos = 0.000483 collapses to zero (stderr 0.00037 from the run)"]
    kept, parts = parts_not_shown(f, spec, why)
    assert parts == why[1:] and kept == why[:1]
    # the rule reads the reason's kind and parameter, not its wording: a plain text saying the same is no reason
    # it moves (an admission test's failure is a plain text)
    assert parts_not_shown(f, spec, [str(w) for w in why]) == ([str(w) for w in why], [])
    # a reason keeps its kind through a worker's pickle
    assert pickle.loads(pickle.dumps(why[1])).kind == "zero" and pickle.loads(pickle.dumps(why[1])).param == \
        "noback.mu_static_pos"
    # nothing else shows: the collapse is a verdict on the detail
    assert parts_not_shown(fit(mu_static_pos="zero", mu_coulomb_neg="zero"), spec, why) == (why, [])
    assert parts_not_shown(fit(mu_static_pos="zero"), spec, why) == (why, [])
    # a held coefficient is no evidence either way
    held = fit(mu_static_pos="zero", mu_coulomb_neg="determined")
    held["estimates"]["noback.mu_coulomb_neg"]["held"] = True
    assert parts_not_shown(held, spec, why) == (why, [])


def test_a_coefficient_at_a_zero_bound_is_the_same_part_not_shown():
    """A coefficient whose search bound is its zero and which the fit puts there is "at its min bound" and "collapses
    to zero" at once: one statement, the part not shown (engine.parts_not_shown), not a refusal of its own (measured
    on a blind rig-sim position-loop record: the light disk's static coefficient at 1.9e-8 +- 0.001, bound 0,
    refused the detailed no-back and a pawl clearance was added for the no-back it brings).  A bound that is not the
    parameter's zero, or one at the other end, stays a reason; so does the bound where nothing else shows."""
    spec = CANDIDATES["noback_quadrant_friction"]

    def fit(lo=0.0, end="min", other="determined"):
        est = {n: {"value": 1e-4, "stderr": None, "stderr_data": None, "at_bound": None, "min": 0.0,
                   "determination": "not determined"} for n in spec.free}
        est["noback.mu_static_pos"].update(value=1.87e-8, stderr=0.00103, stderr_data=0.00103, at_bound=end, min=lo,
                                           determination="zero")
        est["noback.mu_coulomb_neg"].update(value=0.0046, stderr=1e-4, stderr_data=1e-4, determination=other)
        return {"estimates": est}

    f = fit()
    why = _plausibility(f, spec)[1]
    assert [w.kind for w in why] == ["bound", "zero"] and {w.param for w in why} == {"noback.mu_static_pos"}
    kept, parts = parts_not_shown(f, spec, why)
    assert kept == [] and parts == [why[1]] and "collapses to zero" in parts[0]
    for other_case in (fit(lo=1e-6), fit(end="max")):  # a bound that is not the zero, or the other end: a reason
        w2 = _plausibility(other_case, spec)[1]
        kept, parts = parts_not_shown(other_case, spec, w2)
        assert [w.kind for w in kept] == ["bound"] and [w.kind for w in parts] == ["zero"]
    nothing = fit(other="zero")  # nothing else shows: both stay
    w3 = _plausibility(nothing, spec)[1]
    assert parts_not_shown(nothing, spec, w3) == (w3, [])


def test_a_loaded_disk_set_that_cannot_hold_its_load_is_no_rigs_base():
    """The holding limit (trace/candidates._rule_holding): beyond twice the preload the loaded disk set carries the
    whole load, which back-drives the screw with ``lead x inverse efficiency / 2 pi`` N m per N; a static coefficient
    below that (95 % interval and all) is a no-back that does not hold, refused, and no part the run does not show.
    Measured on a blind rig-sim cold record whose ratchet's free travel let the screw slip back 0.24 mm while the
    load rose with the drive off: the detailed no-back took it as a compressive-side static coefficient of 0.0003
    (the papers' 0.0066) and a drive-train compliance was added after it.  The light set's coefficient is not judged
    (a run that never loads it says nothing about its holding), nor one whose interval reaches the limit."""
    from types import SimpleNamespace

    import numpy as np

    from thsa_control.model.params import default_parameters
    from thsa_control.trace.candidates import _rule_holding

    params = default_parameters()
    limit = 0.012 * 0.85 / (2 * math.pi)
    compressive = SimpleNamespace(signals={"load_force": np.r_[np.zeros(50), np.full(200, 10e3)]})
    tensile = SimpleNamespace(signals={"load_force": np.full(200, -8e3)})
    within = SimpleNamespace(signals={"load_force": np.full(200, 5.9e3)})  # both sets share it, the preload helps
    assert _rule_holding(params, [compressive])[0] == pytest.approx(limit)
    assert _rule_holding(params, [compressive])[2] == ("noback.mu_static_neg",)
    assert _rule_holding(params, [tensile])[2] == ("noback.mu_static_pos",)
    assert _rule_holding(params, [compressive, tensile])[2] == ("noback.mu_static_neg", "noback.mu_static_pos")
    assert _rule_holding(params, [within])[2] == ()
    assert _rule_holding(params, [SimpleNamespace(signals={"load_force": np.full(40, 10e3)})])[2] == ()  # too few
    spec = CANDIDATES["noback_quadrant_friction"]

    def fit(value, sd, verdict="determined", at_bound=None):
        est = {n: {"value": 0.0046, "stderr": 1e-4, "stderr_data": 1e-4, "at_bound": None, "min": 0.0,
                   "determination": "determined"} for n in spec.free}
        est["noback.mu_static_neg"].update(value=value, stderr=sd, stderr_data=sd, determination=verdict,
                                           at_bound=at_bound)
        return {"estimates": est}

    plaus = {"holding": _rule_holding(params, [compressive])}
    why = _plausibility(fit(3.03e-4, 1.1e-4), spec, plaus)[1]
    assert [(w.kind, w.param) for w in why] == [("holding", "noback.mu_static_neg")]
    assert "0.000303" in why[0] and f"{limit:.3g}" in why[0]
    assert parts_not_shown(fit(3.03e-4, 1.1e-4), spec, why) == (why, [])  # a refusal, not a part not shown
    # the light set: the same value is no verdict on holding
    assert _plausibility(fit(3.03e-4, 1.1e-4), spec, {"holding": _rule_holding(params, [tensile])})[1] == []
    # an interval that reaches the limit: the run does not say it cannot hold
    assert _plausibility(fit(0.0010, 0.0004), spec, plaus)[1] == []
    assert _plausibility(fit(0.0066, 1e-4), spec, plaus)[1] == []
    # determined at zero on the loaded set: the zero (a part not shown elsewhere) and the holding; the holding stays
    at_zero = fit(0.0, 1e-5, verdict="zero", at_bound="min")
    why0 = _plausibility(at_zero, spec, plaus)[1]
    assert [w.kind for w in why0] == ["bound", "zero", "holding"]
    kept, parts = parts_not_shown(at_zero, spec, why0)
    assert [w.kind for w in kept] == ["holding"] and [w.kind for w in parts] == ["zero"]
    # held at the file value: not judged
    held = fit(3.03e-4, 1.1e-4)
    held["estimates"]["noback.mu_static_neg"]["held"] = True
    assert _plausibility(held, spec, plaus)[1] == []


def test_the_drive_train_damping_ratio_is_the_twist_modes_and_an_overdamped_one_is_no_gear_train():
    """laws.drivetrain_damping_ratio against the eigenvalues of the two-mass drive train it describes (rotors and
    gear-output side, both at the motor shaft, on the series stiffness with the gearbox damping): ``-Re(s) / |s|``
    of the twist mode, lightly damped at the parameter file's values (about 0.2) and overdamped (real roots) beyond
    1.  A compliance fit whose twist mode is overdamped, its whole 95 % interval beyond critical damping, is
    refused (reason kind ``overdamped``): measured on a blind rig-sim load sweep with a 15 ms lag on the screw-speed
    sensor, where a compliance of 6.7e4 N m/rad with 187 N m s/rad (damping ratio 1.9) was added while the sensor
    test named the lag; rig-sim's own compliances were fitted at 0.01..0.37."""
    import numpy as np

    from thsa_control.model import build_plant
    from thsa_control.model.laws import drivetrain_damping_ratio, drivetrain_stiffness
    from thsa_control.model.params import default_parameters
    from thsa_control.trace.candidates import _rule_damping_ratio

    effects = ["standby_motor", "drivetrain_compliance"]
    for damping, ringing in ((20.0, True), (400.0, False)):
        p = default_parameters().replace({"gear.torsional_damping": damping})
        j_main, j_rot = build_plant(None, effects, params=p).inertia(p)
        k, d = drivetrain_stiffness(p), damping / p.value("gear.ratio") ** 2
        # twist q = rotor angle - output angle: J_eff q'' + d q' + k q = 0 with 1/J_eff = 1/J_rot + 1/J_main
        j = 1.0 / (1.0 / j_rot + 1.0 / j_main)
        s = np.roots([j, d, k])
        zeta = drivetrain_damping_ratio(p, j_main, j_rot)
        if ringing:
            assert np.iscomplex(s).all() and zeta == pytest.approx(-s[0].real / abs(s[0]), rel=1e-9)
            assert 0.1 < zeta < 0.3  # the file's "about 0.2"
        else:
            assert np.isreal(s).all() and zeta > 1
    spec = CANDIDATES["drivetrain_compliance"]
    plaus = {"damping_ratio": _rule_damping_ratio(default_parameters(), [])}

    def fit(damping, sd, held=False):
        p = default_parameters().replace({"gear.torsional_stiffness": 6.69e4, "gear.torsional_damping": damping})
        est = {"gear.torsional_stiffness": {"value": 6.69e4, "stderr": 4.6e3, "stderr_data": 4.6e3, "at_bound": None,
                                            "determination": "determined"},
               "gear.torsional_damping": {"value": damping, "stderr": sd, "stderr_data": sd, "at_bound": None,
                                          **({"held": True} if held else {})}}
        return {"estimates": est, "params_toml": p.to_toml(), "effects": effects}

    why = _plausibility(fit(186.9, 1.1), spec, plaus)[1]
    assert [(w.kind, w.param) for w in why] == [("overdamped", "gear.torsional_damping")], why
    assert "critical damping" in why[0]
    assert _plausibility(fit(20.0, 1.0), spec, plaus)[1] == []  # lightly damped: a gear train
    assert _plausibility(fit(186.9, 80.0), spec, plaus)[1] == []  # its interval reaches below critical damping
    assert _plausibility(fit(186.9, 1.1, held=True), spec, plaus)[1] == []  # held: not the run's value


def test_a_load_share_outside_its_assumed_range_is_said_not_refused():
    """A share the run determines beyond the assumed 0.4..0.6 (rig-sim's rig-base no-back, no disk pair, read 0.61
    on two run sets) is reported with the range it leaves, in trace.json and the report's line; inside the range and
    held, nothing is added."""
    from thsa_control.report.trace import _outside
    from thsa_control.trace.engine import _params_out

    spec = CANDIDATES["noback_quadrant_friction"]

    def fit(share, held=False):
        est = {n: {"value": 0.005, "stderr": 1e-5, "init": 0.005, "at_bound": None, "min": 0.0, "max": 1.0,
                   "unit": "N m/N"} for n in spec.free}
        est["noback.load_share"] = {"value": share, "stderr": None if held else 0.01, "init": 0.5, "at_bound": None,
                                    "min": 0.0, "max": 1.0, "unit": "-", **({"held": True} if held else {})}
        return {"estimates": est}

    out = _params_out(fit(0.61), spec)["noback.load_share"]
    assert out["assumed_range"] == pytest.approx([0.4, 0.6]) and out["outside_assumed_range"] is True
    assert "outside the assumed 0.4..0.6" in _outside(out)
    inside = _params_out(fit(0.483), spec)["noback.load_share"]
    assert inside["outside_assumed_range"] is False and _outside(inside) == ""
    held = _params_out(fit(0.5, held=True), spec)["noback.load_share"]
    assert "outside_assumed_range" not in held and _outside(held) == ""
    assert "assumed_range" not in _params_out(fit(0.61), spec)["noback.mu_coulomb_neg"]


# --- the hold, and the second stage, on fits whose information is set by hand -------------------------------------

def _est(name, value, sd, lo=-math.inf, hi=math.inf, at_bound=None, unit="-"):
    from thsa_control.fit.identify_result import ParameterEstimate

    return ParameterEstimate(name=name, unit=unit, value=value, stderr=sd, init=value, min=lo, max=hi,
                             at_bound=at_bound, at_initial=False, stderr_data=sd)


class _Fit:
    def __init__(self, est):
        self.estimates = {e.name: e for e in est}


def _job(free, judge, **kw):
    import dataclasses

    from thsa_control.fit.identify import IdentificationSettings

    return {"free": tuple(free), "judge": judge, "hold_at": {n: 1.0 for n in judge}, "determination_z": Z,
            "absent": {n: True for n in judge}, "settings": dataclasses.replace(IdentificationSettings()), **kw}


def _params(names):
    from thsa_control.model.params import default_parameters

    base = default_parameters()
    return base, [n for n in names if n in base]


def test_a_parameter_the_refit_leaves_undetermined_is_held_too():
    """Three coefficients a, b, c (reference 1): the first fit does not determine a; refitted with a held, b is left
    undetermined (it traded with a and now only with c): b is held too and the last fit frees c alone, which it
    determines.  The refits are told which parameters they free."""
    from thsa_control.trace.scoring import _hold_undetermined

    pset, (a, b, c) = _params(["noback.mu_static_pos", "noback.mu_static_neg", "noback.mu_coulomb_neg"])
    fits = {(a, b, c): _Fit([_est(a, 0.5, 2.0), _est(b, 1.0, 0.1), _est(c, 1.0, 0.1)]),
            (b, c): _Fit([_est(b, 0.5, 2.0), _est(c, 1.0, 0.1)]),
            (c,): _Fit([_est(c, 0.9, 0.1)])}
    calls = []

    def refit(p, keep, settings):
        calls.append(tuple(keep))
        assert p.value(a) == 1.0 and (len(keep) > 1 or p.value(b) == 1.0)  # held at hold_at
        return fits[tuple(keep)]

    res, job, params, held = _hold_undetermined(_job((a, b, c), {a: 1.0, b: 1.0, c: 1.0}), fits[(a, b, c)], pset,
                                                refit)
    assert calls == [(b, c), (c,)]
    assert job["free"] == (c,) and res is fits[(c,)]
    assert set(held) == {a, b} and held[a]["held_at"] == 1.0 and held[b]["held_at"] == 1.0
    assert "in the refit with " + a + " held" in held[b]["reason"]


def test_where_the_refit_determines_nothing_the_candidate_is_judged_undetermined():
    """a undetermined, then b (the only one left) too: nothing is determined, b is marked undetermined without a
    held value (the candidate is judged as such: "no parameter determined by the run"), no further fit."""
    from thsa_control.trace.scoring import _hold_undetermined

    pset, (a, b) = _params(["noback.mu_static_pos", "noback.mu_static_neg"])
    first = _Fit([_est(a, 0.5, 2.0), _est(b, 1.0, 0.1)])
    second = _Fit([_est(b, 0.5, 2.0)])
    calls = []
    res, job, params, held = _hold_undetermined(_job((a, b), {a: 1.0, b: 1.0}), first, pset,
                                                lambda p, keep, st: calls.append(keep) or second)
    assert calls == [(b,)] and res is second
    assert held[a]["held_at"] == 1.0 and held[b]["held_at"] is None


def test_the_hold_leaves_a_fit_that_determines_everything_alone():
    from thsa_control.trace.scoring import _hold_undetermined

    pset, (a, b) = _params(["noback.mu_static_pos", "noback.mu_static_neg"])
    first = _Fit([_est(a, 1.0, 0.1), _est(b, 1.0, 0.1)])
    res, job, params, held = _hold_undetermined(_job((a, b), {a: 1.0, b: 1.0}), first, pset,
                                                lambda *x: pytest.fail("refitted"))
    assert res is first and held == {} and job["free"] == (a, b)


def test_a_load_share_the_second_stage_puts_on_its_bound_is_held_at_its_file_value(monkeypatch):
    """A share of 1 (one disk set infinitely stiffer than the other) is no estimate: the first fit stands and the
    share is held at 0.5, the reason says the bound."""
    from thsa_control.trace import scoring

    pset, (a, share) = _params(["noback.mu_static_neg", "noback.load_share"])
    first = _Fit([_est(a, 1.0, 0.1)])
    second = _Fit([_est(a, 1.1, 0.1), _est(share, 1.0, 0.01, 0.0, 1.0, at_bound="max")])

    class FakeIdentifier:
        def __init__(self, _model, start, free, **kw):
            assert tuple(free) == (a, share)

        def fit(self, runs):
            return second

    monkeypatch.setattr(scoring, "Identifier", FakeIdentifier)
    job = _job((a,), {a: 1.0}, second_stage=(share,), effects=(), runs=[])
    res, job2, params, held = scoring._second_stage(job, first, pset, {})
    assert res is first and job2["free"] == (a,)
    assert held[share]["held_at"] == pset.value(share) == 0.5
    assert "max bound" in held[share]["reason"] and held[share]["value_if_free"] == 1.0
    # inside its range it is kept
    second.estimates[share] = _est(share, 0.45, 0.02, 0.0, 1.0)
    res, job2, params, held = scoring._second_stage(job, first, pset, {})
    assert res is second and job2["free"] == (a, share) and held == {}


def test_a_candidate_its_own_window_test_refuses_is_no_rival(monkeypatch):
    """The ambiguity rule names none of the candidates whose held-out drops the data cannot tell apart; one that
    explains less than ``min_window_reduction`` of its window (a screw ripple at 3.7 % of the motor speed on a load
    sweep, beside a load path at 46 % of the LVDT) would never be named in the best's place: no rival.  Between two
    constant-torque explainers (one window) the window decides nothing: still rivals."""
    from thsa_control.trace import engine

    monkeypatch.setattr(engine, "scaled_threshold", lambda *a, **k: (684.0, None, 4.9))

    def cand(name, drop, **kw):
        return {"name": name, "holdout_chi2_drop": drop, "plausible": True, "implausible_because": [],
                "_spec": CANDIDATES[name], "_fit": {}, "_noise": {}, "_mask": None, **kw}

    best = cand("loadpath_compliance", 4404.6)
    ripple = cand("screw_friction_ripple", 4567.6, window_too_small=True, periodicity={"repeats": True})
    assert engine._rivals(best, [best, ripple], 1e-3) == []
    ripple.pop("window_too_small")
    assert engine._rivals(best, [best, ripple], 1e-3) == [ripple]
    force = cand("force_offset", 300.0)
    drag = cand("coulomb_friction", 290.0, window_too_small=True)
    assert engine._rivals(force, [force, drag], 1e-3) == [drag]


def test_a_periodic_candidate_that_hurt_is_fitted_again_where_the_residual_now_shows_its_angle():
    """A candidate that made the held-out error worse is skipped in the next round, unless the current residual is
    structured in its own angle (the screw ripple beside a ratchet backlash that dominated round 1)."""
    from thsa_control.trace.engine import _shows_now

    sig = {"tests": [{"variable": "screw_angle", "significant": True, "remainder": "structured"},
                     {"variable": "motor_angle", "significant": False, "remainder": "structured"}]}
    assert _shows_now("screw_friction_ripple", sig)
    assert not _shows_now("cogging_torque", sig)  # its angle is not significant
    assert not _shows_now("coulomb_friction", sig)  # no angle of its own
    assert not _shows_now("screw_friction_ripple", None)
    base = {"tests": [{"variable": "screw_angle", "significant": True, "remainder": "base"}]}
    assert not _shows_now("screw_friction_ripple", base)  # a short stroke's angle is a position: the base's


def test_a_ripples_amplitude_is_judged_along_the_radius_not_over_its_phase():
    """A cosine and sine pair (cogging, screw ripple) collapses to zero only where its amplitude does: its standard
    error along the radius, with the pair's correlation.  Where the segments' free start angles take the phase
    (rig-sim's cogging on the position loop, fresh seed: +-0.14 / +-0.28 N m on the parts, correlated along the
    circle), an amplitude of 0.049 N m with a held-out drop of 409 is there; with equal uncorrelated errors the rule
    is the one the parts' errors in quadrature gave (2 x sqrt 2 standard errors)."""
    spec = CANDIDATES["cogging_torque"]
    cos_, sin_ = spec.free[:2] if "cos" in spec.free[0] else spec.free[1::-1]

    def fit(a, b, sa, sb, rho):
        est = {cos_: {"value": a, "stderr": sa, "at_bound": None, "corr": {sin_: rho}},
               sin_: {"value": b, "stderr": sb, "at_bound": None, "corr": {cos_: rho}}}
        return {"estimates": est}

    amp = math.hypot(-0.0442, 0.0218)
    # the uncertainty along the tangent (-0.0218, -0.0442) / amp: the parts move together (rho near +1)
    ok, why = _plausibility(fit(-0.0442, 0.0218, 0.1385, 0.2801, 0.999), spec)
    assert ok, why
    # the same parts' errors without that correlation: nothing says the amplitude is determined
    ok, why = _plausibility(fit(-0.0442, 0.0218, 0.1385, 0.2801, 0.0), spec)
    assert not ok and [w.kind for w in why] == ["zero"] and "along the radius" in why[0], why
    # what the report says: the amplitude with its interval, the phase not determined; the parts' own intervals
    # span zero
    a = _amplitude_out(fit(-0.0442, 0.0218, 0.1385, 0.2801, 0.999), spec)["amplitude"]
    assert a["value"] == pytest.approx(amp) and a["stderr"] < 0.15 * amp and a["ci95"][0] > 0.7 * amp
    assert a["phase_determined"] is False and a["parts"] == [cos_, sin_]
    from thsa_control.report.trace import _amplitude_text
    assert "phase not determined by this run" in _amplitude_text(a)
    # a phase the run determines (round 1 of the same record: -0.0053 +- 0.0022, 0.0512 +- 0.0012)
    a = _amplitude_out(fit(-0.0053, 0.0512, 0.0022, 0.0012, 0.0), spec)["amplitude"]
    assert a["phase_determined"] and a["phase_deg"] == pytest.approx(95.9, abs=0.1) and a["phase_stderr_deg"] < 5
    assert _amplitude_out(fit(-0.0053, 0.0512, 0.0022, 0.0012, 0.0), CANDIDATES["coulomb_friction"]) == {}
    # equal, uncorrelated errors: refused below 2 sqrt 2 of them, kept above
    for ratio, expected in ((2.7, False), (2.95, True)):
        sd = amp / ratio
        assert _plausibility(fit(-0.0442, 0.0218, sd, sd, 0.0), spec)[0] is expected, ratio


def test_a_reported_interval_stays_inside_the_physical_range():
    """An estimate's 95 % interval in trace.json (scoring._param_entry) stays where the parameter can be, as its
    interval over the segments does: the every-segment fit put a light disk's static coefficient at 0.0126 +- 0.108
    N m/N (range 0 .. 0.1), whose Wald interval reached -0.199 .. 0.225 while the segments' was cut to 0 .. 0.1
    (campaign: the segments' interval then looked narrower than the information's).  Inside the range an interval
    is untouched."""
    e = {"value": 0.0126, "stderr": 0.108, "unit": "N m/N", "at_bound": None, "min": 0.0, "max": 0.1,
         "stderr_segments": 0.1026}
    p = _param_entry(e)
    assert p["ci95"] == [0.0, 0.1] and p["ci95_segments"] == [0.0, 0.1]
    q = _param_entry({**e, "stderr": 0.001, "stderr_segments": 0.002})
    assert q["ci95"] == pytest.approx([0.0126 - 1.96 * 0.001, 0.0126 + 1.96 * 0.001])
    assert q["ci95_segments"] == pytest.approx([0.0126 - 1.96 * 0.002, 0.0126 + 1.96 * 0.002])
