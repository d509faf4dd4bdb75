"""Constant-torque library effects on records that hold them: rig-sim run sets traced together (issue #21).

On one load a Coulomb drag, a direction drag, an axial force, the screw's efficiencies and the no-back disk's
coefficient give the same two torques per direction (tests/test_trace_foreign.py, KNOWN_FAILING of rig_coulomb,
rig_direction_friction, rig_axial_offset).  An engineer who wants to tell them apart runs both directions at two
loads of opposite sign: the sets in tests/data/rigsim/sets (``make_runs.py`` SETS: rig base + one effect, the same
parameters, reversals under 25 kN compressive + ramps under 20 kN tensile, other seeds; and the same pair with
nothing planted) are traced together as a user does (``thsa trace SET_1.csv SET_2.csv --model A``).

The campaign cases (``-m campaign``) read ``THSA_TRACED_SETS_DIR`` (``tests/data/rigsim/trace_sets.sh DIR``) or trace
the sets here.  The fast tests check the separability diagnostic (:mod:`thsa_control.trace.separability`) on
analytic cases: a constant torque against load-proportional ones.
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

import numpy as np
import pytest

from thsa_control.data.rigdata import read_run
from thsa_control.fit.kinematics import run_kinematics
from thsa_control.trace import TraceSettings, trace
from thsa_control.trace.engine import CANDIDATES
from thsa_control.trace.separability import (
    VIF_LIMIT,
    collinearity,
    explainer_steps,
    separability,
    separability_sentences,
    current_offset_torque,
    torque_sensitivities,
)

DATA = Path(__file__).resolve().parent / "data" / "rigsim"
SETS = DATA / "sets"
CATALOGUE = json.loads((DATA / "catalogue.json").read_text())
LIBRARY = CATALOGUE["library"]
INVENTED = set(CATALOGUE["invented"])
BASE_CONTENT = set(CATALOGUE["base_content"]) | set(CATALOGUE["base_compliance"])


def _set_csvs(name: str) -> list[Path]:
    return sorted(SETS.glob(f"{name}_[0-9].csv"))


def _truth_effects(csv: Path) -> list[str]:
    eff = json.loads(csv.with_suffix("").with_suffix(".truth.json").read_text()).get("effects") or {}
    return list(eff) if isinstance(eff, dict) else [e["name"] if isinstance(e, dict) else str(e) for e in eff]


@pytest.fixture(scope="session")
def traced_set(params):
    """``traced_set(name)`` -> trace.json of ``thsa trace SET_1.csv SET_2.csv --model A`` (memoised per session)."""
    cache: dict = {}
    folder = os.environ.get("THSA_TRACED_SETS_DIR")

    def _go(name: str) -> dict:
        if folder and (Path(folder) / name / "trace.json").is_file():
            return json.loads((Path(folder) / name / "trace.json").read_text())
        if name not in cache:
            runs = [run_kinematics(read_run(c), params) for c in _set_csvs(name)]
            cache[name] = trace(runs, "A", params=params, settings=TraceSettings(workers=2)).to_dict()
        return cache[name]

    return _go


#: sets measured to fail (docs/trace_notes.md, "Constant torques on run sets"); the assertion stays
KNOWN_FAILING = {
    "set_coulomb": "nothing named beyond the base corrections: the Coulomb correction at its bound (0.057 N m) with "
                   "the "
                   "direct efficiency at its; beyond it coulomb_friction drops the held-out chi2 by 203 but improves "
                   "36 of 51 held-out segments of its window (sign test p 0.0023 > 1e-3).  On a fresh set (seeds "
                   "981/475) it is named first beyond its base correction (0.105 N m at the motor: planted 4 N m at "
                   "the screw = 0.066, plus the base's own ~0.03) with a window RMS drop of 8 % (24 % beyond the "
                   "noise): the window error left after the base step is mostly the base's mismatch (Stribeck, the "
                   "no-back's law), which no constant torque removes.  Separability on this set: the Coulomb drag's "
                   "torque is reproduced by the efficiencies and the no-back disks (variance inflation 1.2e6): "
                   "25 kN and 20 kN are one load magnitude for the load-proportional explainers" +
                   ".  trace-lift (joint lift of the base corrections): coulomb_friction beyond its bound now passes "
                   "the sign test (drop 171, window 5 %, 0.103 N m) and carries the joint lift, but the base's "
                   "efficiencies lifted beyond their catalogue spread explain as much (drop 171.5, carry gap 28): at "
                   "25 kN and 20 kN a constant drag and a load-proportional loss are one torque, so it is refused as "
                   "'a lossier base explains as much' (the fresh set 981/475 the same: 254.4 against the efficiencies' "
                   "248.3, gap 26.3; named there before with a window drop of 7-8 %, no longer)" +
                   ".  Traced with its own two runs (trace_sets.sh took set_coulomb_loads' three too before 1f7eb00), "
                   "before and after the flange-balanced no-back: nothing named beyond the base corrections",
    "set_axial_offset": "the bases' load-path compliance first, then force_offset and direction_friction ambiguous "
                        "(held-out drops 20557 / 20555, indistinct below 18): on two load magnitudes of opposite sign, "
                        "both directions, the per-(load sign, direction) constants are spanned by the Coulomb drag, "
                        "both efficiencies and the two disks, so an axial force and an extension-only drag differ "
                        "only through the bounds (separability: force variance inflation 2.0e4; a second load level "
                        "would separate it).  Before the rival rule of this branch direction_friction was named.  A "
                        "fresh set with a load sweep added (seeds 613/614/615) is worse: screw_friction_ripple "
                        "(window 8 %) then direction_friction (0.108 N m) named, the axial force correction at 351 of "
                        "its 390 N bound and never offered beyond it; with position_steps (10 kN) added instead "
                        "(seed 619), where "
                        "the separability has the force determined (inflation 5.2), direction_friction is named "
                        "(0.116 N m) and the force beyond its bound reaches 1080 N of 1500 with both efficiencies "
                        "pinned at their bounds" +
                        ".  trace-lift: force_offset and direction_friction both miss the sign test now (drops 16546 / "
                        "16541, not robust) and the joint lift of the base corrections says it (drop 16546, carried by "
                        "each of force_offset and direction_friction: the record does not tell them apart)" +
                        ".  Traced with its own two runs (trace_sets.sh took set_axial_offset_loads' three too before "
                        "1f7eb00) and with the flange-balanced no-back: the same ambiguity, drops 16484 / 16483, "
                        "indistinct below 14",
    "set_coulomb_loads": "named first beyond its base correction since the no-back's flange balance (ac18db0), 0.0986 "
                         "+- 0.0006 N m (planted 4 N m at the screw = 0.066 at the motor, plus the rig base's own "
                         "drags), held-out drop 9473, no ambiguity, but its window RMS drop beyond the base "
                         "correction's bound is 46 % (< 50 %): the whole drag drops the window by 93 %, of which the "
                         "bounded 0.057 N m correction carries 58 % (trace.json contribution); it explains the "
                         "opposing cells (56 % of their motor-speed error) and nothing of the aiding ones.  Before the"
                         " flange balance nothing was named: the old law's loaded disk carried preload + |F|, a "
                         "constant mu Fp / N = 0.19 N m in the aiding cells that two load magnitudes of one sign "
                         "exposed (docs/trace_notes.md \"Two load magnitudes of one sign\", \"The no-back's flange "
                         "balance\")",
}

LIB_SETS = [("set_coulomb", "coulomb_friction"), ("set_direction_friction", "direction_friction"),
            ("set_axial_offset", "force_offset"),
            # two load magnitudes of one sign (30 kN trim ramps, 10 kN position steps) + the 20 kN tensile ramps: the
            # records the separability names as separating a constant torque from the load-proportional explainers
            ("set_coulomb_loads", "coulomb_friction"), ("set_axial_offset_loads", "force_offset")]
NULL_SETS = ["set_null", "set_null_loads"]


def _cases(pairs):
    return [pytest.param(*c, id=c[0], marks=pytest.mark.xfail(reason=KNOWN_FAILING[c[0]], strict=False))
            if c[0] in KNOWN_FAILING else pytest.param(*c, id=c[0]) for c in pairs]


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name, expected", _cases(LIB_SETS))
def test_constant_torque_effect_named_on_a_set_that_holds_it(traced_set, name, expected):
    """rig base + one constant-torque library effect, both directions at two loads of opposite sign: the effect
    is named first among the found effects beyond the base corrections (as the one-run must-show asks) and its
    window error drops by half; the base corrections stay within their bounds."""
    csvs = _set_csvs(name)
    assert len(csvs) >= 2 and all(LIBRARY[_truth_effects(c)[0]] == expected for c in csvs)
    doc = traced_set(name)
    order = [e["name"] for e in doc["effects_added"] if not e.get("implied_by") and not e.get("refines_declared")]
    assert order and order[0] == expected, (order, doc["ambiguous"])
    step = next(e for e in doc["effects_added"] if e["name"] == expected)
    assert max(step["window_reduction"].values()) >= 0.5, step["window_reduction"]
    for c in doc["base_corrections"]["corrections"]:
        assert c["bound"][0] - 1e-9 <= c["value"] <= c["bound"][1] + 1e-9, c


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", NULL_SETS)
def test_null_set_adds_only_what_the_base_contains(traced_set, name):
    """The same scenarios with nothing planted, traced together: nothing beyond the base corrections and the
    detailed no-back (the bases' load-path compliance allowed), no constant torque beyond its base correction."""
    assert all(_truth_effects(c) == [] for c in _set_csvs(name))
    doc = traced_set(name)
    found = {e["name"] for e in doc["effects_added"] if not e.get("implied_by")}
    assert not found & INVENTED, doc["rounds"]
    assert found <= BASE_CONTENT, found
    assert not [e for e in doc["effects_added"] if e.get("beyond_base_correction")], doc["effects_added"]
    assert not doc["ambiguous"], doc["ambiguous"]


# ----------------------------------------------------------------------------- the separability diagnostic (fast)
def _points(speed, load):
    speed, load = np.asarray(speed, float), np.asarray(load, float)
    return {"speed": speed, "load": load, "position": np.zeros_like(speed), "temperature": np.full_like(speed, 25.0),
            "current": np.zeros_like(speed)}


EXPLAINERS = ["drive.coulomb_torque", "screw.efficiency_direct", "screw.efficiency_inverse", "drive.axial_force_offset"]


def _S(params, pts):
    steps = explainer_steps(params, EXPLAINERS, {}, {"drive.coulomb_torque": 0.057, "drive.axial_force_offset": 400.0,
                                                     "screw.efficiency_direct": 0.07, "screw.efficiency_inverse": 0.07})
    return torque_sensitivities(("coulomb_friction", "force_offset"), params, EXPLAINERS, pts, steps)


def test_a_current_offset_covers_a_constant_torque_beyond_its_bound_no_larger_than_twice_its_own(params):
    """A current-sensor offset I0 read with the drive off biases the motor torque by Kt I0 (0.081 N m at 0.25 A): a
    Coulomb drag found 0.033 N m beyond its 0.057 N m bound (its interval's near end) is within twice that, one found
    0.39 N m beyond is not, and one whose interval reaches the bound has no excess; an axial force 2594 N beyond its
    406 N bound costs that force times the nut travel per motor radian, through the screw's efficiency, at the
    motor (analytic: r = lead / (2 pi N) = 2.91e-5 m/rad, between r eta_i and r / eta_d, gearbox losses aside)."""
    from thsa_control.model.laws import kinematic_ratio, torque_constant

    run = run_kinematics(read_run(DATA / "rig_current_offset.csv"), params)
    kt, r = torque_constant(params), kinematic_ratio(params)
    test = {"offset": 0.25, "significant": True}
    effects = ("coulomb_friction", "force_offset")
    c_bound = {"drive.coulomb_torque": (0.0, 0.057)}

    def coulomb(value, ci):
        return current_offset_torque(test, effects, params, {"drive.coulomb_torque": {"value": value, "ci95": ci}},
                                     c_bound, [run], kt)

    near = coulomb(0.1, [0.09, 0.11])
    assert near["offset_torque"] == pytest.approx(kt * 0.25) and near["explained"], near
    assert near["parameters"]["drive.coulomb_torque"]["beyond_bound"] == pytest.approx(0.033)
    assert 0.9 * 0.033 < near["excess_torque"] < 1.1 * 0.033, near
    far = coulomb(0.5, [0.45, 0.55])
    assert not far["explained"] and far["excess_torque"] > 2 * far["offset_torque"], far
    inside = coulomb(0.1, [0.05, 0.2])
    assert inside["excess_torque"] == 0.0 and inside["explained"], inside
    # the estimate's own excess, 0.043 beyond the bound, for the text; the refusal then says the interval reaches it
    assert 0.9 * 0.043 < inside["estimate_excess_torque"] < 1.1 * 0.043, inside
    from thsa_control.trace.engine import current_offset_reason

    assert "not beyond its plausible bound at the 95 % level" in current_offset_reason(inside)
    assert "at least" in current_offset_reason(near) and "95 %" not in current_offset_reason(near)
    force = current_offset_torque(test, effects, params, {"drive.axial_force_offset": {"value": 3000.0}},
                                  {"drive.axial_force_offset": (-406.0, 406.0)}, [run], kt)
    per_newton = force["excess_torque"] / 2594.0
    eta_d, eta_i = params.value("screw.efficiency_direct"), params.value("screw.efficiency_inverse")
    assert 0.9 * r * eta_i < per_newton < 1.1 * r / eta_d, (per_newton, r)
    assert current_offset_torque(test, effects, params, {}, c_bound, [run], kt) is None


def test_coulomb_drag_is_a_constant_torque_against_the_direction(params):
    """The sensitivity of the motor torque to the Coulomb drag is sgn(speed) x about 1 N m per N m, through the
    gearbox (more while the motor drives the load, less while the load drives it back: retracting under a
    compressive load), the same at every load; the efficiencies' is proportional to the load, zero without it
    (analytic: the law's own structure, at the steady current of each point)."""
    pts = _points([50.0, -50.0, 50.0, -50.0, 50.0], [20e3, 20e3, 10e3, 10e3, 0.0])
    S = _S(params, pts)
    assert np.sign(S[:, 0]) == pytest.approx(np.sign(pts["speed"]))
    assert S[0, 0] == pytest.approx(S[2, 0], rel=1e-6) and S[1, 0] == pytest.approx(S[3, 0], rel=1e-6)
    assert 0.9 < -S[1, 0] < 1.0 < S[0, 0] < 1.1
    eff = S[:, 1] + S[:, 2]
    assert eff[0] == pytest.approx(2 * eff[2], rel=1e-3) and eff[4] == pytest.approx(0.0, abs=1e-9)


def test_one_load_cannot_tell_a_drag_from_the_efficiencies_and_a_second_load_can(params):
    """Both directions at one compressive load: extending drives the load (direct efficiency), retracting is driven
    by it (inverse efficiency), so the two efficiencies give any pair of per-direction torques and reproduce a
    Coulomb drag exactly (inflation above the limit); the same motion at a second load level separates them
    (a drag does not scale with the load)."""
    rng = np.random.default_rng(0)
    w = np.where(rng.random(400) < 0.5, 1.0, -1.0) * rng.uniform(40.0, 60.0, 400)
    one = _points(w, np.full(400, 25e3))
    names = EXPLAINERS[:3]
    S1 = _S(params, one)[:, :3]
    c1 = collinearity(S1, names, ["drive.coulomb_torque"])["drive.coulomb_torque"]
    assert c1["vif"] > VIF_LIMIT and set(c1["same_part_as"]) == {"screw.efficiency_direct", "screw.efficiency_inverse"}
    two = _points(np.concatenate([w, w]), np.concatenate([np.full(400, 25e3), np.full(400, 6.25e3)]))
    c2 = collinearity(_S(params, two)[:, :3], names, ["drive.coulomb_torque"])["drive.coulomb_torque"]
    assert c2["vif"] <= VIF_LIMIT and c2["same_part_as"] == []


def test_separability_of_a_one_load_record_names_the_record_that_separates(params):
    """On the committed one-load reversal run (rig_coulomb, 25 kN compressive, both directions), with the base
    corrections' Coulomb drag and efficiencies as what the model carries: the axial force is reproduced by them
    (the record cannot tell it), the other direction adds nothing the record lacks, and the sentences say which
    kind of record would separate it, read off the inflations."""
    run = run_kinematics(read_run(DATA / "rig_coulomb.csv"), params)
    base = {"drive.coulomb_torque": "coulomb_friction", "screw.efficiency_direct": "efficiency",
            "screw.efficiency_inverse": "efficiency"}
    targets = {"drive.axial_force_offset": "force_offset", "drive.coulomb_torque": "coulomb_friction"}
    steps = explainer_steps(params, list(base) + list(targets), {}, {"drive.axial_force_offset": 400.0,
                                                                     "drive.coulomb_torque": 0.057,
                                                                     "screw.efficiency_direct": 0.07,
                                                                     "screw.efficiency_inverse": 0.07})
    doc = separability([run], ("standby_motor",), params, base, targets, steps)
    f = doc["explainers"]["drive.axial_force_offset"]
    assert f["vif"] > VIF_LIMIT and "drive.coulomb_torque" in f["same_part_as"]
    assert f["separated_by"]["other_direction"] > VIF_LIMIT  # the record has both directions already
    c = doc["explainers"]["drive.coulomb_torque"]
    assert c["vif"] > VIF_LIMIT and c["separated_by"]["second_load_level"] <= VIF_LIMIT
    text = "\n".join(separability_sentences(doc))
    assert "drive.coulomb_torque (coulomb_friction) explains the same part of the residual as" in text
    assert doc["record_kinds"]["second_load_level"] in text
    assert set(doc["explainers"]) <= set(targets) and all(e["effect"] in CANDIDATES or e["effect"] == "efficiency"
                                                          for e in doc["explainers"].values())
    # the report's section: one row per explainer, the inflation on the record and with each kind of record
    from thsa_control.report.trace import separability_table_html

    page = separability_table_html({"separability": {**doc, "sentences": separability_sentences(doc)}})
    assert page.count("<tr>") == 1 + len(doc["explainers"]) and "force_offset: drive.axial_force_offset" in page
    assert all(html.escape(k) in page for k in doc["record_kinds"].values()) and "<b>" in page


@pytest.mark.slow
def test_a_second_load_magnitude_of_one_sign_separates_the_axial_force(params):
    """The separability on the committed run sets, with what a set trace carries (the base corrections, the detailed
    no-back's four disk coefficients, the declared viscous drag): on the two-sign sets (25 kN compressive, 20 kN
    tensile, one magnitude per load sign) the axial force and the Coulomb drag are reproduced by the efficiencies and
    the disk coefficients (inflation far above the limit); adding a second compressive magnitude (30 kN trim ramps and
    10 kN position steps with the tensile ramps) determines the axial force (at or below the limit) and brings the
    Coulomb drag's inflation down by more than four decades (a constant is told from a load-proportional torque within
    each compressive cell; the tensile aiding cell keeps one magnitude, which its own disk coefficient absorbs)."""
    base = {"drive.coulomb_torque": "coulomb_friction", "drive.axial_force_offset": "force_offset",
            "screw.efficiency_direct": "efficiency", "screw.efficiency_inverse": "efficiency",
            **{f"noback.{k}": "noback_quadrant_friction" for k in ("mu_coulomb_pos", "mu_coulomb_neg",
                                                                   "mu_static_pos", "mu_static_neg")},
            "gear.viscous_friction": "declared"}
    targets = {"drive.coulomb_torque": "coulomb_friction", "drive.axial_force_offset": "force_offset"}
    mags = {"drive.coulomb_torque": 0.057, "drive.axial_force_offset": 400.0, "screw.efficiency_direct": 0.07,
            "screw.efficiency_inverse": 0.07}
    steps = explainer_steps(params, list(base), {}, mags)
    vif = {}
    for name in ("set_null", "set_null_loads"):
        runs = [run_kinematics(read_run(c), params) for c in _set_csvs(name)]
        doc = separability(runs, ("standby_motor", "noback_quadrant_friction"), params, base, targets, steps)
        vif[name] = {t: e["vif"] for t, e in doc["explainers"].items()}
    assert vif["set_null"]["drive.axial_force_offset"] > VIF_LIMIT
    assert vif["set_null_loads"]["drive.axial_force_offset"] <= VIF_LIMIT
    assert vif["set_null"]["drive.coulomb_torque"] > 1e4 * vif["set_null_loads"]["drive.coulomb_torque"]
