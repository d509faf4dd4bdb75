"""The tracer on data it did not write: rig-sim runs on the ``rig`` and ``papers`` bases (issue #21).

The runs and their ``.truth.json`` are in tests/data/rigsim (``make_runs.py`` regenerates them); the
truth files are read by these tests only.

The must-show cases over the whole catalogue (marked ``campaign``: about 2 h on the 2-core machine, one
trace per run) are not part of the default run; ``python -m pytest -m campaign tests/test_trace_foreign.py``
runs them (``THSA_TRACED_DIR=DIR`` reads the traces of ``tests/data/rigsim/trace_all.sh DIR`` instead of tracing
again).  Cases measured to fail are marked xfail with what was measured.  Each run is traced as a user would (``thsa trace RUN.csv
--model A``: the default candidate pool, so with the base-correction step) once per session and
shared by the tests.  The base physics of rig-sim is never the declared level A: the base corrections
(constant-torque explainers, screw efficiencies) and, since the level's ideal no-back differs from
every real one, the detailed no-back friction are what the base itself contains.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from thsa_control.data.rigdata import read_run
from thsa_control.fit.kinematics import run_kinematics
from thsa_control.trace import TraceSettings, trace
from thsa_control.model import EFFECTS
from thsa_control.trace.engine import CANDIDATES, EFFICIENCY_LIFT

DATA = Path(__file__).resolve().parent / "data" / "rigsim"

#: how the results are judged: rig-sim effect -> library effect, what the bases contain, what a null must never
#: produce, the signatures of the out-of-library effects (one file, shared with bench/trace_rigsim_table.py)
CATALOGUE = json.loads((DATA / "catalogue.json").read_text())
LIBRARY = CATALOGUE["library"]
BASE_CONTENT = set(CATALOGUE["base_content"])
BASE_COMPLIANCE = set(CATALOGUE["base_compliance"])
INVENTED = set(CATALOGUE["invented"])


def _truth(name: str) -> dict:
    return json.loads((DATA / f"{name}.truth.json").read_text())


def _truth_effects(name: str) -> list[str]:
    eff = _truth(name).get("effects") or []
    if isinstance(eff, dict):
        return list(eff)
    return [e["name"] if isinstance(e, dict) else str(e) for e in eff]


@pytest.fixture(scope="session")
def traced_result(params):
    """``traced_result(name)`` -> TraceResult of ``thsa trace RUN.csv --model A`` (memoised per session)."""
    cache: dict = {}

    def _go(name: str):
        if name not in cache:
            run = run_kinematics(read_run(DATA / f"{name}.csv"), params)
            cache[name] = trace(run, "A", params=params, settings=TraceSettings(workers=2))
        return cache[name]

    return _go


@pytest.fixture(scope="session")
def traced(traced_result):
    """``traced(name)`` -> its trace.json document.

    With ``THSA_TRACED_DIR`` set, the document of ``thsa trace RUN.csv --model A --out $THSA_TRACED_DIR/RUN`` is
    read when that folder exists (a campaign traced beforehand, runs in parallel, exactly as a user runs them:
    ``tests/data/rigsim/trace_all.sh``); every other run is traced here.
    """
    import os

    folder = os.environ.get("THSA_TRACED_DIR")

    def _doc(name: str) -> dict:
        if folder and (Path(folder) / name / "trace.json").is_file():
            return json.loads((Path(folder) / name / "trace.json").read_text())
        return traced_result(name).to_dict()

    return _doc


def _found(doc: dict) -> list[str]:
    """Effects added, in order, implied ones excluded."""
    return [e["name"] for e in doc["effects_added"] if not e.get("implied_by")]


def _physical(doc: dict) -> list[dict]:
    """Added effects that are new physics: not constant-torque explainers, not the detailed model of a declared
    component (the no-back disks for level A's ideal no-back: every rig-sim base has a real no-back)."""
    return [e for e in doc["effects_added"] if not e.get("implied_by") and not e.get("refines_declared")
            and not CANDIDATES.get(e["name"], CANDIDATES["coulomb_friction"]).base_correction]


#: Cases measured to fail on this branch (docs/trace_notes.md, "Still failing"): the assertion stays, the case is
#: marked with what was measured so that a fix shows as XPASS.
KNOWN_FAILING = {
    "rig_friction_bump_spring": "not flagged: the pass-replicated test runs on the 0.4 s of each pass outside the "
                                "transients (the load's rate changes for 0.6 s around each acceleration), 5 bins of "
                                "1.18 mm on 2 passes, and finds the bump's bin (8.18 .. 9.37 mm, rig-sim's 8.76) at p "
                                "8.6e-4 against its level 1e-4: 3 denominator degrees of freedom (the spring nulls "
                                "and the spring's library record p 0.16 .. 0.95)",
    "rig_axial_offset_cold": "temperature_friction named first (window drop 60 %), not force_offset: a cold ramp "
                             "(-30 degC, +9 mm/s against 55 kN, one direction) at one temperature; the cold drag "
                             "0.046 N m at the motor with its low-speed rise against the planted 2.7 kN, and beyond "
                             "their bounds the Coulomb drag, the axial force, the one-direction drag and a lossier base "
                             "drop 1.105e4 .. 1.107e4 on the constant torques' samples against its 1.065e4 (carry gap "
                             "23), all refused because the lossier base explains as much.  Given the lifted set the "
                             "cold drag still adds 205 on its window (its low-speed rise: the rig base's Stribeck "
                             "drags), so it stays; the trace says what it does not rule out (``not_ruled_out``; "
                             "drawn blind in the ninth blind set).  Since the singular hold (thirtieth session) the "
                             "base's own load path is listed before the cold drag",
    "rig_drivetrain_compliance_rev": "drivetrain_compliance found first among the physical effects (by what it "
                                     "explains; the base's load path added before it), gearbox 9.8e3 N m/rad (series "
                                     "7.9e3, rig-sim 8e3), damping 0.42 in the search (the held-out segments hold "
                                     "each breakaway out; 1.62 in the final model, fitted on every segment): its "
                                     "window (every sample) drops by 22 % on the screw speed, 9 % on the motor speed "
                                     "with the search's values: the ringing after each reversal is a small part of a "
                                     "record whose motor-speed error the detailed no-back explains",
    "rig_drivetrain_compliance_exc": "drivetrain_compliance found first, its window drop when added 30 % on the motor "
                                     "speed (25 % on the screw speed; < 50 %): started at the record's 47 Hz mode.  "
                                     "When added its damping was 17.6 N m s/rad (rig-sim 2), gearbox 7.0e3: the "
                                     "drive-off stop at the end rings the rotors on the compliance, and level A's "
                                     "ideal no-back (no holding margin) let the screw slip back with each swing.  "
                                     "Since e12fb32 the detailed no-back is offered again and added in round 2 at the "
                                     "parameter file's coefficients (none determined): the final model has gearbox "
                                     "9757 N m/rad (series 7.8e3, rig-sim 8e3) and damping 2.73 +- 0.11, motor speed "
                                     "0.31 rad/s (1.35 x its noise), and the torque-constant flag is gone; the window "
                                     "bar is judged on the drop when the compliance was added "
                                     "(docs/trace_notes.md, \"A damping the stop chose\")",
    # measured on the committed runs with this tracer (the standby rotor declared from each run's rig.motors = 2),
    # `tests/data/rigsim/trace_all.sh DIR` then THSA_TRACED_DIR=DIR; the table is in docs/trace_notes.md
    # trace-drags (no-back static coefficients freed, sign test of constant torques); one-load reversal and trim runs:
    # the constant torques per direction are two numbers shared by the Coulomb drag, the axial force, both
    # efficiencies and the loaded disk's coefficient (docs/trace_notes.md, "Base drags against planted constant
    # torques")
    "rig_coulomb": "nothing named: the Coulomb base correction runs to its bound (0.057 N m; 0.041 on the same "
                   "scenario's null) with the axial force and the direct efficiency; beyond them a Coulomb drag, an "
                   "axial force and a direction drag explain the same 4 % of the window (held-out drops 51 / 47 / 50; "
                   "12 of 15 steady held-out segments improved, sign test p 0.018 > 1e-3): the planted 4 N m at the "
                   "screw (0.066 N m at the motor) is the size of the rig base's own plausible drag on one load. "
                   "trace-drags2: the run's torque sensitivities say the same (trace.json separability): the base's "
                   "explainers reproduce the Coulomb drag's torque over the run (variance inflation 2.6e7); traced "
                   "with a tensile ramp run of the same rig (tests/test_trace_sets.py) it is named beyond its base "
                   "correction on a fresh set but its window drop is 8 %" +
                   ".  trace-lift: the joint lift of the base corrections (Coulomb, axial force, both efficiencies freed "
                   "together, held-out likelihood ratio) passes in round 2 (drop 39.5, threshold 28.5) and is carried "
                   "by each of force_offset, coulomb_friction, direction_friction and the efficiencies lifted alone "
                   "(39.5 / 37.8 / 35.7 / 37.6, carry gap 25.1): the record does not tell them apart; none named",
    "rig_axial_offset": "nothing beyond the base corrections: the axial force correction at its bound (+406 N, the "
                        "planted 1500 N's sign) with the Coulomb drag and the direct efficiency at theirs; beyond "
                        "them an axial force, a Coulomb or a direction drag explain 1 % of the window: 1.5 kN on the "
                        "30 kN trim load is a 5 % load-proportional torque, inside the efficiencies' spread. "
                        "trace-drags2: the axial force's torque over the run is reproduced by the base's explainers "
                        "(variance inflation 1.8e8), and the loads of the other sign would separate it (with the other "
                        "direction: 4.3); on a set with both (tests/test_trace_sets.py) it is left ambiguous with "
                        "direction_friction" +
                        ".  trace-lift: the joint lift passes in round 2 only through the efficiencies lifted alone "
                        "(drop 47.5, threshold 33.9; the axial force beyond its bound 28.1, Coulomb 27.0, direction "
                        "24.4, all within the carry gap 29.8): a lossier base explains as much; none named.  Since "
                        "the axial force loads the load path's attachments (thirty-third session) the record's "
                        "answer beyond the base is 'present, not attributed' (round 3: drop 45.1 against 34.0), "
                        "carried by the axial force (5.3 kN [2.1, 8.5]) with the Coulomb drag, the direction drag "
                        "and the lossier base (45.1 / 44.6 / 43.6 / 42.7), each refused by the robustness test "
                        "(p 0.021 .. 0.035 over 34 .. 44 segments)",
    "rig_direction_friction": "before trace-drags2: the bases' load-path compliance came first, then "
                              "coulomb_friction beyond its base correction (0.104 N m, window 12 %) over "
                              "direction_friction (window 12 %, its torque "
                              "0.047 +- 0.048 N m 'collapses to zero'): on one load the rig base's no-back drag while "
                              "driving (0.5 N m + 0.15 N m/kN x 25 kN at the screw, extension only) has the shape and "
                              "size of the planted direction part (5 - 1 = 4 N m). trace-drags2: nothing named now "
                              "(load path first): coulomb_friction, force_offset and direction_friction ambiguous in "
                              "round 2 (held-out "
                              "drops 168.4 / 168.6 / 164.4, the force 'collapsing to zero' and the direction drag "
                              "'not determined' only through their collinearity with the base corrections; the run's "
                              "separability: variance inflation 2.5e9 / 2.6e9 / 1e12); traced with a tensile ramp "
                              "run of the same rig (tests/test_trace_sets.py) direction_friction is named first, "
                              "0.064 N m (planted 0.066 at the motor), window drop 53 %" +
                              ".  trace-lift: the joint lift passes (round 2: 133.0, threshold 36.4) and "
                              "is carried by each of force_offset, the efficiencies lifted alone, coulomb_friction and "
                              "direction_friction (133.0 / 127.5 / 126.2 / 125.2, gap 32.0); none named, no ambiguity "
                              "entry (all three constant torques miss the sign test)",
    "rig_drivetrain_compliance": "the compliance is fitted right since the base step reads the motor-side inertia "
                                 "(rig-sim's gear input stage, 4e-5 kg m^2 that level A lacks: it left 6-8 x the "
                                 "resolver noise on the motor speed) and the 1 ms resolver is read over 1 ms: gear "
                                 "1.01e4 N m/rad (series 8.0e3; rig-sim 8e3), damping 2.4 +- 0.3 (rig-sim 2), added "
                                 "with its window drop 46 % motor speed / 41 % screw speed (< 50 %: all samples 1.43 "
                                 "-> 0.28 and 0.043 -> 0.022 rad/s, at the noise, 0.23 and 0.021).  Since trace-"
                                 "backward it is reported first: the rig base's own load path (1.2e8 N/m; level A is "
                                 "rigid) still wins round 1 (held-out drop 1179 against 651, on different sample "
                                 "sets) and the backward check keeps it (given the compliance its drop is 3026, null "
                                 "-463), but given each other, on all held-out samples, the compliance explains 5446 "
                                 "and the load path 3026 (docs/trace_notes.md, 'Backward check and the order of what "
                                 "is explained'); only the 50 % window bar fails.  trace-window "
                                 "(bench/window_ceiling.py): the bar is beyond this record.  The compliance at "
                                 "rig-sim's own values (gear 1e4, series 8e3 N m/rad, damping 2) drops the window by "
                                 "the same 46 % (motor speed) / 41 % (screw speed) as the fit: the fit is at the "
                                 "ceiling.  The screw speed is at its sensor noise after it (0.58 x the weight's "
                                 "variance; the RVDT's specified 3e-5 rad over 2 ms, 0.021 rad/s, gives 0.62): a model "
                                 "leaving only that noise drops its window by 39 %.  The motor speed keeps 1.47 x: "
                                 "0.87 the resolver's noise, about 0.17 the logged current's 0.03 A noise the replay "
                                 "integrates, about 0.21 the one plant step per sample (1.26 at 4 steps, still 45 % "
                                 "against the model before it at 4 steps), 0.22 not identified; over all held-out "
                                 "samples (the window 'all' is scored outside the base's transients, 204 of 901) the "
                                 "true values give 48 % / 49 %" +
                                 ".  trace-ceiling: two further seeds of the scenario (rig, 601 / 602) give 34 / 25 % "
                                 "(motor speed) and 43 / 41 % (screw speed) at rig-sim's values, the fits the same: "
                                 "the chirp's record cannot show 50 %.  On the position loop's drive-off holds "
                                 "(rig_drivetrain_compliance_steps, seed 601; 602 not committed) the same compliance is "
                                 "found first with its window drop 69 % (65 %), rig-sim's values 69 % (65 %): passes",
    # the out-of-library effects (docs/trace_notes.md, "Out-of-library effects: what the remainder shows")
    "rig_kt_temperature": "not flagged, the run cannot tell it: housing temperature spans 0.7 K, the rotor's is not "
                          "measured, the voltage is not recorded; its 13 K cooling raises Kt 1.6 % in 10 s: per-pass drift "
                          "p 0.019 (2.8 standard errors while extending).  trace-drift: the measured current itself in "
                          "the steady passes (per pass a level and a slope in time) carries the same: relative slopes "
                          "-1.26e-3 +- 0.49e-3 /s extending, -0.46e-3 +- 0.39e-3 /s retracting (expected about -1.6e-3 on average), "
                          "p 0.019; a rate shared by the passes p 0.012; the level 1e-4 needs about 3.9 standard errors. "
                          "Two fresh runs of the same effect (seeds 412, 413) give p 2e-4 / 4.5e-4 (shared rate 8e-5 / 1e-4): "
                          "at the level's edge. "
                          "A constant Kt error at one load is what the efficiency corrections absorb" +
                          ".  trace-kt: from the truth's thermal model (rotor rise integrated from the true current) the "
                          "rotor cools 40 -> 30.3 K, the flux rises 1.20 % over the record, 0.27 % / 0.13 % inside the "
                          "two constant-speed passes (-1.25e-3 / -0.62e-3 /s of the current): 4.7 and 3.6 mA/s against a "
                          "slope standard error of 2.1 mA/s per pass (43 mA of current noise at 500 Hz), so at most "
                          "about 3 standard errors in one record; and one pass per direction never revisits an "
                          "operating point, so that slope is also what a drag along the stroke gives (a pass's time is "
                          "its position).  The torque constant's own test (current_drift_test: comparable passes at one "
                          "load, speed, direction and nut positions) needs two passes of one operating point and does "
                          "not run here; on 10 s of reversals (rig_kt_temperature_reversals) it names the torque "
                          "constant (p 1e-27, -1.38e-3 +- 0.13e-3 /s, the thermal model's -1.2e-3)",
    "rig_worn_spot_stiction": "not flagged, not separable on this run: the spot adds 0.25-0.47 A at the two events near "
                              "it where the declared model leaves up to 0.54 N m at every reversal, and each kind of "
                              "event (start, reversal to extension, to retraction) happens at one position only; "
                              "nothing invented.  trace-wornspot: the breakaway test (the drive's breakaway current "
                              "at a start or reversal against the same kind of event elsewhere) does not run here: "
                              "breakaway excess 2.41 A at the start (-0.29 mm; null_rig_reversals_s2 2.04), 2.56 A at "
                              "the reversal to extension (0.93 mm; null 2.35), 2.89 A at the reversal to retraction "
                              "(6.89 mm; null 3.13): three classes of one place each, no class seen at two places.  "
                              "The same spot where the scenario starts twice (rig_worn_spot_stiction_cold) is flagged",
    "rig_loadpath_preload": "loadpath_compliance found first among the physical effects after the detailed no-back, "
                            "its window RMS drop 43 % (< 50 %): the fit is right (contact stiffnesses 4.59e7 / 5.59e7"
                            " N/m = rig-sim's 5.32e7 / 6.65e7 in series with its 3e8 N/m ball-nut contact, soft zone "
                            "-0.02 mm against -0.03) and leaves the LVDT at its noise (2.18 um RMS, noise 2.12 um): "
                            "from 3.77 um no model drops the RMS by more than 44 %; beyond the noise the drop is "
                            "93-100 % (window_reduction_beyond_noise); the LVDT residual left has no load dependence "
                            "(10 load bins within +-0.05 um, ANOVA p 1) and is 1.035 x rig-sim's noise on the held-"
                            "out samples: 0.5 um RMS at 20-100 Hz beyond it, the size of the load cell's 25 N noise "
                            "through the contact stiffness (measured on this run and a fresh seed, "
                            "docs/trace_notes.md)" +
                            ".  trace-ceiling: the sweep changes the load within one replay segment by a few kN "
                            "only; on a static load reversal with the drive off (check_hold, "
                            "rig_loadpath_preload_hold, seed 601; 602 not committed) the same candidate is found "
                            "first with its window drop 87 % (88 %), the preload -0.032 mm (rig-sim -0.03), rig-sim's "
                            "values 87 % (88 %): passes",
}


#: runs whose KNOWN_FAILING entry is about the window drop only: the not-determined test passes on them
#: (rig_temp_friction was one: since the 25 degC drag is held on a cold-only record, docs/trace_notes.md "The cold
#: run", its window drop is 97 %)
HELD_PASSES: set[str] = set()


def _cases(pairs, passes=frozenset()):
    return [pytest.param(*c, id=c[0], marks=pytest.mark.xfail(reason=KNOWN_FAILING[c[0]], strict=False))
            if c[0] in KNOWN_FAILING and c[0] not in passes else pytest.param(*c, id=c[0]) for c in pairs]


LIB_RUNS = [(f"rig_{k}", v) for k, v in LIBRARY.items()]
#: library effects on the scenario that excites them, beside the catalogue's record of the same effect whose noise sets
#: a window ceiling below the 50 % bar (docs/trace_notes.md "Scenarios that excite the effect": bench/window_ceiling.py
#: at rig-sim's own values, two seeds): the preload on a static load reversal with the drive off (check_hold), the
#: drive-train compliance on the position loop, whose drive-off holds under load let the rotors ring on it
#: (position_steps)
LIB_RUNS_EXCITED = [("rig_loadpath_preload_hold", LIBRARY["loadpath_preload"]),
                    ("rig_drivetrain_compliance_steps", LIBRARY["drivetrain_compliance"])]


#: a library effect on a short check record: rig-sim's cold friction on its 1.6 s cold check, whose trace stopped with an
#: internal error before 332d930 (a parameter's interval overflowed)
LIB_RUNS_SHORT = [("rig_temp_friction_checkcold", LIBRARY["temp_friction"])]
#: a library effect on the whole of its scenario: rig-sim's drive-train compliance over the speed excitation's chirp and
#: PRBS (rig_drivetrain_compliance is cut to the chirp)
LIB_RUNS_WHOLE = [("rig_drivetrain_compliance_exc", LIBRARY["drivetrain_compliance"]),
                  ("rig_drivetrain_compliance_rev", LIBRARY["drivetrain_compliance"])]
#: a library effect drawn blind on another scenario: the axial force on the cold ramp (one temperature, one load, one
#: direction), where the cold drag is named in its place (KNOWN_FAILING; its not_ruled_out is tested); the pawl backlash
#: on the compressive trim under a softer velocity loop, where an axial force of 2 kN was named beyond the base before
#: fd1fc02 (a disk coefficient held undecided while the model lacked the pawl clearance); the quadrant no-back on the
#: check stop, where a chattering screw speed read as a sensor gain before 3238e79
LIB_RUNS_BLIND = [("rig_axial_offset_cold", LIBRARY["axial_offset"]),
                  ("rig_ratchet_backlash_lowgain", LIBRARY["ratchet_backlash"]),
                  ("rig_noback_quadrant_checkstop", LIBRARY["noback_quadrant"])]
#: a library effect as a fault: rig-sim's quadrant no-back with its compressive-side coefficients worn below the
#: holding limit, on the check stop and the drive-off load hold (the load back-drives the screw)
LIB_RUNS_FAULT = [("rig_noback_worn_stop", LIBRARY["noback_quadrant"]),
                  ("rig_noback_worn_hold", LIBRARY["noback_quadrant"])]


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name, expected", _cases(LIB_RUNS + LIB_RUNS_EXCITED + LIB_RUNS_SHORT + LIB_RUNS_WHOLE
                                                  + LIB_RUNS_BLIND + LIB_RUNS_FAULT))
def test_library_effect_on_the_rig_base_is_found_first(traced, name, expected):
    """rig base + one library effect: the effect is added, first among the physical effects (a constant-torque
    one first among the found effects), and the error inside its window drops by half."""
    assert _truth_effects(name) and LIBRARY[_truth_effects(name)[0]] == expected
    doc = traced(name)
    spec = CANDIDATES[expected]
    if expected in BASE_CONTENT:  # the detailed no-back: found, first among the found effects
        order = _found(doc)
    elif spec.base_correction:  # a constant-torque effect: first among those beyond a base correction
        order = [e["name"] for e in doc["effects_added"] if not e.get("implied_by") and not e.get("refines_declared")]
    else:
        order = [e["name"] for e in _physical(doc)]
    assert order and order[0] == expected, (_found(doc), doc["rounds"])
    step = next(e for e in doc["effects_added"] if e["name"] == expected)
    red = step["window_reduction"]
    assert max(red.values()) >= 0.5, red
    bc = doc["base_corrections"]
    if bc and bc["accepted"]:  # base corrections stay within their plausible bounds
        for c in bc["corrections"]:
            assert c["bound"][0] - 1e-9 <= c["value"] <= c["bound"][1] + 1e-9, c


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_cogging_steps", "rig_cogging_steps_s70495"])
def test_cogging_on_a_position_loop_record_is_found_first(traced, name):
    """rig base + cogging on a closed position loop logged at 500 Hz (rig_cogging_steps): its 18th harmonic is
    resolved only in the approach and the creep (a fifth of the record), aliased in the 15 mm/s travel.  The cogging
    is found first among the physical effects, with its count and its amplitude within 20 %.  (The 50 % bar of the
    library test is not asked here: measured 44 % of the window's RMS since its scoring mask leaves out the creep's
    stops (28 % before), where the same seed without the cogging leaves 45 %: the record's ceiling, the resolver's
    noise and what the rig base leaves at creep; docs/trace_notes.md "Cogging on records with little low-speed
    motion" and "What limits the window drop"; two more seeds of the scenario: ceiling 44 / 42 %, "Scenarios that excite
    the effect".  The record that shows the cogging beyond the bar is the slow check, rig_cogging, in the library
    test.)  rig_cogging_steps_s70495 (a blind set's seed): beside the rig's own load path, whose compliance lets each
    segment's start angle take the phase, the cogging was refused as "amplitude 0.0524 collapses to zero (stderr
    0.14)"; judged along the radius it is found, and reported with the phase not determined."""
    doc = traced(name)
    assert _truth_effects(name) == ["cogging"]
    phys = [e["name"] for e in _physical(doc)]
    assert phys and phys[0] == "cogging_torque", doc["rounds"]
    step = next(e for e in doc["effects_added"] if e["name"] == "cogging_torque")
    assert step["parameters"]["drive.cogging_periods"]["value"] == 18, step["parameters"]
    p = step["parameters"]
    amp = math.hypot(p["drive.cogging_torque_cos"]["value"], p["drive.cogging_torque_sin"]["value"])
    truth = _truth(name)["effects"]["cogging"]["params"]["A_Nm"]["si"]
    assert amp == pytest.approx(truth, rel=0.2), p
    a = step["amplitude"]  # what the report gives: the amplitude along the radius, its interval clear of zero
    assert a["value"] == pytest.approx(amp) and a["ci95"][0] > 0.5 * truth and a["ci95"][1] < 1.5 * truth, a
    if name == "rig_cogging_steps_s70495":
        assert not a["phase_determined"], a


@pytest.mark.campaign
@pytest.mark.slow
def test_a_preloaded_load_path_is_read_as_a_preload(traced):
    """rig base + loadpath_preload on a static load reversal with the drive off (check_hold: 40 kN compressive, then
    40 kN tensile): the load path is named with a preload (a negative soft zone, its 95 % interval below zero: a
    clearance would be positive) and its contact stiffnesses as the LVDT sees them, rig-sim's contacts in series with
    its ball-nut contact, within 20 % (the cogging test's bar on an amplitude).  On the same scenario's null
    (null_rig_hold_s603) the base's linear load path is no preload: nothing is named there."""
    name = "rig_loadpath_preload_hold"
    assert _truth_effects(name) == ["loadpath_preload"]
    doc = traced(name)
    step = next((e for e in doc["effects_added"] if e["name"] == "loadpath_compliance"), None)
    assert step is not None, doc["rounds"]
    p = step["parameters"]
    x0 = p["loadpath.backlash"]
    assert x0["value"] < 0 and x0["ci95"][1] < 0, x0
    truth = _truth(name)
    law = truth["effects"]["loadpath_preload"]["params"]
    k_nut = truth["parameters"]["k_ballscrew_N_m"]["value"]
    for ours, theirs in (("loadpath.contact_stiffness_upper", "k_upper_N_m"),
                         ("loadpath.contact_stiffness_lower", "k_lower_N_m")):
        series = 1.0 / (1.0 / law[theirs]["si"] + 1.0 / k_nut)
        assert p[ours]["value"] == pytest.approx(series, rel=0.2), (ours, p[ours], series)


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name, effect, parameter", _cases([
    ("rig_noback_quadrant", "noback_quadrant_friction", "noback.mu_coulomb_neg"),  # the light disk never loaded
    ("rig_temp_friction", "temperature_friction", "friction.viscous_temperature_coefficient"),  # one temperature
], HELD_PASSES))
def test_undetermined_parameter_is_held_and_reported(traced, params, name, effect, parameter):
    """A candidate with a parameter the run cannot determine is added with that parameter held at its file value,
    and trace.json says so."""
    doc = traced(name)
    step = next((e for e in doc["effects_added"] if e["name"] == effect), None)
    assert step is not None, doc["rounds"]
    held = {h["parameter"]: h for h in step["not_determined"]}
    if parameter in held:
        assert held[parameter]["held_at"] == pytest.approx(params.value(parameter))
    else:  # undetermined without a refit (the fit left it at its file value with no standard error)
        p = step["parameters"].get(parameter)
        assert p is not None and p["stderr"] is None and p["value"] == pytest.approx(params.value(parameter)), step


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_temp_friction", "null_rig_cold_s52"])
def test_a_cold_record_holds_the_25C_drag(traced, params, name):
    """A record that moves only at -30 degC does not determine the declared 25 degC viscous drag: held at its file
    value and said so (fitted, it took the cold drag: 9 x the file's on rig_temp_friction)."""
    doc = traced(name)
    held = {h["parameter"]: h for h in doc.get("declared_not_determined", [])}
    assert "gear.viscous_friction" in held, doc.get("declared_not_determined")
    assert held["gear.viscous_friction"]["held_at"] == pytest.approx(params.value("gear.viscous_friction"))
    assert "gear.viscous_friction" not in doc["uncertain_parameters"]


NULLS = sorted(p.stem for p in DATA.glob("null_*.csv"))


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", _cases([(n,) for n in NULLS]))
def test_nulls_add_only_what_the_base_contains(traced, name):
    """Nothing planted, rig and papers bases, several scenarios and seeds: nothing beyond the base corrections and
    the detailed no-back friction; no periodic, compliance, backlash or temperature effect is invented."""
    assert _truth_effects(name) == []
    doc = traced(name)
    found = set(_found(doc))
    assert not found & INVENTED, doc["rounds"]
    assert found <= BASE_CONTENT | BASE_COMPLIANCE | {e for e in found if CANDIDATES[e].base_correction}, found
    # a constant-torque effect named beyond its base correction would be a claim the base cannot make
    assert not [e for e in doc["effects_added"] if e.get("beyond_base_correction")], doc["effects_added"]


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", _cases([(n,) for n in NULLS]))
def test_nulls_leave_no_structured_remainder(traced, name):
    """Nothing planted: what the base leaves is its regime dependences (starts, stops, reversals, quadrant), never a
    structure an unmodelled effect would leave (periodic in angle, local in position over passes, a drift, a sensor):
    ``unexplained`` on a null is a false alarm the user chases (a reversal run's transients at the same motor angles
    once read as a motor-angle harmonic, docs/trace_notes.md "The motor-angle flag on reversal nulls")."""
    doc = traced(name)
    assert not doc["unexplained"], doc["residual_signature"]["structured"]


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ["null_rig_trim_s1", "rig_noback_quadrant"])
def test_base_step_details_the_declared_no_back(traced, name):
    """Level A's ideal no-back is no real one: the base step fits the no-back's disks jointly with the base
    corrections, keeps them as the declared component detailed (what the base contains, not a found effect), with
    a disk coefficient the run does not load held at its file value, and the corrections stay inside their
    bounds, each with its source."""
    doc = traced(name)
    bc = doc["base_corrections"]
    det = {d["name"]: d for d in bc["declared_components_detailed"]}
    assert det["noback_quadrant_friction"]["accepted"], det
    step = doc["effects_added"][0]
    assert step["name"] == "noback_quadrant_friction" and step["refines_declared"] == ["noback_ideal"]
    assert step["base_step"] == "declared component detailed" and step not in _physical(doc)
    assert step["not_determined"], step  # one disk is never loaded on these one-signed loads
    for c in bc["corrections"]:
        assert c["bound"][0] - 1e-9 <= c["value"] <= c["bound"][1] + 1e-9 and c["bound_source"], c


@pytest.mark.slow
def test_the_no_back_load_share_is_read_from_a_load_sweep_through_zero(traced):
    """rig base + rig-sim's no-back (disk normal forces Fp +- F/2: a share of 0.5) on the load sweep of +-29 kN at
    -10 mm/s: the load crosses the band where both disk sets carry load (|F| < 6 kN) twice, and the slipping set's
    drag there changes with the load at the share's slope.  The base step's detailed no-back reads the share off
    the run (not held, within 0.05 of rig-sim's 0.5, its interval narrower than the assumed 0.4..0.6); on the
    committed records whose load never enters the band it is held at 0.5 and reported (rig_noback_quadrant below,
    20 kN tensile throughout).  Not a campaign case: traced here in the default run (about 45 s)."""
    doc = traced("rig_noback_quadrant_sweep")
    step = doc["effects_added"][0]
    assert step["name"] == "noback_quadrant_friction" and step["base_step"] == "declared component detailed", step
    share = step["parameters"]["noback.load_share"]
    assert not share.get("held"), share
    assert abs(share["value"] - 0.5) < 0.05, share
    lo, hi = share["ci95"]
    assert 0.4 < lo <= share["value"] <= hi < 0.6, share
    assert share["assumed_range"] == pytest.approx([0.4, 0.6]) and share["outside_assumed_range"] is False, share
    # rig-sim's planted no-back has the papers' 3 kN preload, which the same band shows
    pre = step["parameters"]["noback.preload"]
    assert not pre.get("held") and pre["value"] == pytest.approx(3000.0, rel=0.05), pre


@pytest.mark.campaign
@pytest.mark.slow
def test_the_rig_bases_no_back_is_read_without_a_preload_on_a_load_sweep(traced, params):
    """null_rig_sweep_s65153: the rig base alone on the +-29 kN load sweep at -10 mm/s.  rig-sim's base no-back is
    the papers' level-B Coulomb disk on the loaded brake, with no preload (its README), where the file says 3 kN.
    The sweep crosses the band where a preloaded pair would share the load twice, so the base step reads the
    preload there: at its range end, 0 N within 1 % of the file's 3 kN (no first-order information there: the band
    has no width), the file's value rejected by the profile.  Held at 3 kN (0df431e), the detailed no-back left 1.40
    rad/s of motor speed and a base mismatch the plausible corrections could not hold (the answer beyond the base
    ``no_carrier``: "beyond the plausible set, no constant torque"); read, the motor speed goes to 0.36 rad/s and
    the plausible base holds the record (``not_fitted``: no correction at its bound, or ``within``)."""
    doc = traced("null_rig_sweep_s65153")
    step = doc["effects_added"][0]
    assert step["name"] == "noback_quadrant_friction" and step["base_step"], step
    pre = step["parameters"]["noback.preload"]
    assert not pre.get("held") and pre["value"] < 0.01 * params.value("noback.preload"), pre
    assert pre["range_end"]["range_end"] == "min" and pre["range_end"]["training_chi2_drop"] > pre["range_end"]["gap"]
    assert doc["error_after"]["motor_speed"]["rms"] < 0.6, doc["error_after"]
    assert (doc.get("beyond_plausible_base") or {}).get("status") in ("not_fitted", "within"), \
        doc.get("beyond_plausible_base")
    assert not doc["unexplained"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_one_signed_load_holds_the_no_back_load_share(traced, params):
    """rig_noback_quadrant: 20 kN tensile throughout the moves, beyond the band both disk sets share: the share is
    not determined by the run, held at the file's value and listed as such."""
    doc = traced("rig_noback_quadrant")
    step = doc["effects_added"][0]
    assert step["name"] == "noback_quadrant_friction", step
    share = step["parameters"]["noback.load_share"]
    assert share.get("held") and share["value"] == params.value("noback.load_share"), share
    assert "noback.load_share" in {h["parameter"] for h in step["not_determined"]}, step["not_determined"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_detailed_no_back_that_is_the_ideal_one_on_its_record_does_not_worsen_the_speed(traced, params):
    """rig_temp_friction_checkcold (check_cold: +10 mm/s against 10 kN, extension only): while the motor turns the
    load stays above twice the file's preload, so the light (tensile) disk set carries nothing and the loaded
    (compressive) set, which slips only in retraction, does not slip: the detailed no-back's torque is the ideal
    one's at any coefficient, and its joint fit with the corrections explains what the corrections' own fit does.
    The fit from the file's values stopped at its evaluation limit far above it (training chi2 146251 against
    20618 on 348af60), and "motor_speed error grows by 126 %" was given as the detail's verdict; it is fitted
    again from the corrections' optimum, reported, and the better fit judged."""
    run = run_kinematics(read_run(DATA / "rig_temp_friction_checkcold.csv"), params)
    moving = np.abs(run.signals["motor_speed"]) > 10.0  # rad/s, beyond the resolver speed's noise
    assert moving.sum() > 200 and np.all(run.signals["motor_speed"][moving] > 0)  # the premise, from the data
    assert np.min(run.signals["load_force"][moving]) > 2.0 * params.value("noback.preload")
    doc = traced("rig_temp_friction_checkcold")
    det = {d["name"]: d for d in doc["base_corrections"]["declared_components_detailed"]}["noback_quadrant_friction"]
    assert not any("grows" in w for w in det["implausible_because"]), det["implausible_because"]
    assert abs(det["window_reduction"]["motor_speed"]) < 0.05, det["window_reduction"]
    r = det.get("restart")
    if r is not None:  # restarted: the better of the two fits is the one judged, both objectives reported
        kept = r["training_chi2_restart"] if r["kept"] == "restart" else r["training_chi2_first"]
        assert kept == min(r["training_chi2_first"], r.get("training_chi2_restart", math.inf)), r


@pytest.mark.campaign
@pytest.mark.slow
def test_a_part_of_the_declared_no_back_the_run_finds_at_zero_is_reported_not_refused(traced):
    """rig base + load-path backlash against an elastic surface (spring_load_ramp, 5-50 kN compressive): below twice
    the preload the no-back's light (+) disk set carries a few hundred newtons, where rig-sim's rig base has no disk
    hump (its light disk drags through the pawls, a constant), so the run determines ``noback.mu_static_pos`` at zero.
    The no-back is declared: the base step keeps its detailed model and reports that part as not shown by the run.
    Refused as implausible ("collapses to zero"), the disks came in through ``noback_backlash`` instead (a ratchet
    backlash invented, the load path lost: measured on ac18db0)."""
    doc = traced("rig_loadpath_backlash_spring")
    det = {d["name"]: d for d in doc["base_corrections"]["declared_components_detailed"]}["noback_quadrant_friction"]
    assert det["accepted"], det
    assert [w for w in det["parts_not_shown"] if w.startswith("noback.mu_static_pos") and "collapses to zero" in w], det
    step = doc["effects_added"][0]
    assert step["base_step"] == "declared component detailed" and step["parts_not_shown"] == det["parts_not_shown"]
    assert "noback_backlash" not in {e["name"] for e in doc["effects_added"]}, doc["effects_added"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_pitch_one_loaded_stop_cannot_fix_is_reported_not_determined(traced, params):
    """rig_ratchet_backlash: one stop under load after one long extension shows the pawl pitch only through the
    stop's depth, the extension's travel modulo the pitch (a comb of pitches).  The backlash is added (its window
    drop is the library test's), and its pitch is reported not determined with the profile's set (several
    ranges), the interval shown being that set's hull, not a local one; held at the file value where the set and
    the profile fits' training errors keep it, else at the best profile fit's (chosen by its training error: the
    held-out samples judge the candidate)."""
    doc = traced("rig_ratchet_backlash")
    step = next((e for e in doc["effects_added"] if e["name"] == "noback_backlash"), None)
    assert step is not None, doc["rounds"]
    held = {h["parameter"]: h for h in step["not_determined"]}
    assert "noback.pawl_pitch" in held, step["not_determined"]
    h = held["noback.pawl_pitch"]
    assert len(h["profile_set"]) >= 2, h
    p = step["parameters"]["noback.pawl_pitch"]
    assert p["ci95"] == pytest.approx([h["profile_set"][0][0], h["profile_set"][-1][1]])
    assert p["value"] == pytest.approx(h["held_at"])
    assert h["held_at"] in (pytest.approx(params.value("noback.pawl_pitch")), pytest.approx(h["value_if_free"]))


FOREIGN = {f"rig_{k}": tuple(v) for k, v in CATALOGUE["foreign"].items()}
#: a sensor effect planted on another channel than rig_sensor_gain's: its signature follows the truth's channel
#: (catalogue ``foreign_sensor_channel``)
FOREIGN["rig_sensor_gain_lvdt"] = tuple(CATALOGUE["foreign_sensor_channel"]["nut_position"])
#: the worn spot where the scenario starts twice in one direction under one load (cold_ramp): the same signatures
FOREIGN["rig_worn_spot_stiction_cold"] = FOREIGN["rig_worn_spot_stiction"]

#: the torque constant drifting with the rotor's temperature on a record of comparable passes (10 s of reversals)
FOREIGN["rig_kt_temperature_reversals"] = tuple(CATALOGUE["foreign"]["kt_temperature"])
#: the friction bump on the reversal scenario (3 mm of steady travel a pass: the position test's bins narrowed)
FOREIGN["rig_friction_bump_reversals"] = FOREIGN["rig_friction_bump"]
#: a lag on the screw-speed sensor on the load sweep, where an overdamped drive-train compliance stood in for it
FOREIGN["rig_sensor_lag_screw_sweep"] = tuple(CATALOGUE["foreign_sensor_channel"]["screw_speed"])
#: the friction bump crossed once, on the excitation around one speed (the one-pass test's signature)
FOREIGN["rig_friction_bump_excitation"] = FOREIGN["rig_friction_bump"]
#: a second current-sensor offset (-0.33 A, drawn) on the cold ramp, with the drive off in its stops
FOREIGN["rig_current_offset_cold"] = FOREIGN["rig_current_offset"]
#: the friction bump on the load sweep (one pass) and on the elastic surface (two), where the load ramps through the
#: motion (the position tests' load-ramp samples)
FOREIGN["rig_friction_bump_sweep"] = FOREIGN["rig_friction_bump"]
FOREIGN["rig_friction_bump_spring"] = FOREIGN["rig_friction_bump"]


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", _cases([(n,) for n in sorted(FOREIGN)]))
def test_out_of_library_effect_is_unexplained_with_its_signature(traced, name):
    """Each out-of-library effect: ``unexplained: true`` with the signature that names it, also after explainers
    were added, and no physical effect invented."""
    doc = traced(name)
    assert doc["unexplained"], doc["residual_signature"]["structured"]
    structured = doc["residual_signature"]["structured"]
    assert any(v in s for v in FOREIGN[name] for s in structured), structured
    assert not set(_found(doc)) & INVENTED, doc["rounds"]


#: library runs whose sensors are right: no redundant pair may disagree on them (the effects act on the physics, not
#: on a sensor)
SENSOR_CLEAN = sorted([n for n, _ in LIB_RUNS + LIB_RUNS_EXCITED] + ["rig_cogging_steps", "rig_loadpath_backlash_spring",
                                                   "rig_pair_coulomb_ripple"])


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", SENSOR_CLEAN)
def test_a_library_effect_leaves_the_redundant_sensors_consistent(traced, name):
    """A library effect on the rig base: no redundant-sensor pair is flagged (gain or lag).  rig_cogging (check_slow,
    0.15 mm/s) was ``unexplained`` through a lag of 14 ms that was the noise's cross-correlation peak and a motor-vs-
    screw gain of 0.92 that was the screw speed's noise attenuating a rate regression (docs/trace_notes.md, "A noise
    test for the redundant sensors' lag"); rig_drivetrain_compliance's motor-vs-screw pair must not read its
    compliance as a sensor fault."""
    doc = traced(name)
    bad = [d["variable"] for d in doc["residual_signature"]["sensors"]
           if d.get("kind") == "redundant_sensors" and d["significant"]]
    assert not bad, [d for d in doc["residual_signature"]["sensors"] if d.get("kind") == "redundant_sensors"]
    if name == "rig_cogging":  # nothing else was left on it
        assert not doc["unexplained"], doc["residual_signature"]["structured"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_torque_constant_drifting_with_the_rotor_temperature_is_named(traced):
    """rig base + kt_temperature on 10 s of reversals (4 extending and 3 retracting passes at one load, speed and
    stroke): the current of each operating point falls in proportion to itself as the rotor cools, and the trace
    names it by the torque constant's own test (not only as a slow drift), with the current falling."""
    from thsa_control.trace.signature import TORQUE_CONSTANT_DRIFT

    doc = traced("rig_kt_temperature_reversals")
    assert doc["unexplained"] and TORQUE_CONSTANT_DRIFT in doc["residual_signature"]["structured"], \
        doc["residual_signature"]["structured"]
    t = next(x for x in doc["residual_signature"]["tests"] if x["variable"] == TORQUE_CONSTANT_DRIFT)
    assert t["relative_rate"] < 0 and t["verdict"] == "torque constant", t
    assert not set(_found(doc)) & INVENTED, doc["rounds"]


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_loadcell_drift", "rig_temp_friction", "rig_current_offset", "null_rig_cold_s52",
                                  "null_rig_reversals_s303", "rig_worn_spot_stiction"])
def test_no_torque_constant_drift_where_the_current_does_not_scale(traced, name):
    """A load reading that drifts (the current does not), a friction that changes with the cold (one pass), a current
    sensor's offset, the reversal and cold nulls: the torque-constant drift is not named."""
    from thsa_control.trace.signature import TORQUE_CONSTANT_DRIFT

    doc = traced(name)
    assert TORQUE_CONSTANT_DRIFT not in doc["residual_signature"]["structured"], doc["residual_signature"]["structured"]


#: the friction bumps crossed once: on the excitation around one speed and on the load sweep
ONE_PASS_BUMPS = {"rig_friction_bump_excitation", "rig_friction_bump_sweep"}


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(p.stem for p in DATA.glob("*.csv")))
def test_a_bump_crossed_once_is_flagged_where_one_is_and_nowhere_else(traced, name):
    """Records whose positions are crossed once (no bin visited by two passes): the one-pass test compares each bin
    of a pass with the record's own other bins.  On the friction bumps crossed once (rig_friction_bump_excitation,
    5.2 N m at the screw at 7.82 mm; rig_friction_bump_sweep, 6 N m at -43.1 mm) it is flagged in the bump's bin,
    opposing the motion; on every other record it
    ran on (nulls, library effects, the other out-of-library effects) it is not significant.  Where it did not run
    the record has no such pass (or revisits its positions), which the pass-replicated test covers."""
    from thsa_control.trace.signature import ONE_PASS_VARIABLE

    doc = traced(name)
    one = [t for t in doc["residual_signature"]["tests"] if t["variable"] == ONE_PASS_VARIABLE]
    truth = _truth(name).get("effects") or {}
    if name in ONE_PASS_BUMPS:
        assert one and one[0]["significant"], one
        x_c = truth["friction_bump"]["params"]["x_c_mm"]["si"]
        lo, hi = one[0]["peak_bin"]
        assert lo - one[0]["bin_width"] <= x_c <= hi + one[0]["bin_width"], (one[0], x_c)
        assert one[0]["law"].startswith("dissipative"), one[0]
        assert ONE_PASS_VARIABLE in doc["residual_signature"]["structured"], doc["residual_signature"]["structured"]
    elif "friction_bump" not in truth:
        assert not any(t["significant"] for t in one), one


#: the committed records of rig-sim's position_steps (a proportional position loop: its speed command decays)
STEPS_RUNS = ["null_rig_steps_s252", "rig_cogging_steps", "rig_cogging_steps_s70495", "rig_drivetrain_compliance_steps",
              "rig_pair_cogging_compliance", "rig_pair_direction_loadpath_steps"]


#: the committed records of the load-ramp scenarios: rig-sim's load sweep (one pass, the load a +-29 kN triangle) and
#: its elastic surface (2.5 MN/m: the load follows the travel)
LOAD_RAMP_RUNS = ["null_rig_sweep_s65153", "rig_loadpath_backlash", "rig_loadpath_preload", "rig_noback_quadrant_sweep",
                  "rig_sensor_lag_screw_sweep", "rig_friction_bump_sweep", "rig_loadpath_backlash_spring",
                  "rig_friction_bump_spring"]


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.xfail(reason=KNOWN_FAILING[n], strict=False))
                                  if n == "rig_friction_bump_spring" else n for n in LOAD_RAMP_RUNS])
def test_the_position_tests_run_where_the_load_ramps_through_the_motion_and_flag_a_bump_only(traced, name):
    """A load that ramps through the motion is no transient, a change of its rate is: on each load-ramp record a
    position test runs (on the sweep the one-pass test, on the spring the pass-replicated one), it is flagged on the
    friction bump, in its bin, and on no other record.  Before the load-ramp samples neither test ran on any of them,
    and nothing said so."""
    doc = traced(name)
    sig = doc["residual_signature"]
    pos = [t for t in sig["tests"] if t["variable"].startswith("nut_position (")]
    assert pos, (sig["tests"], sig["not_tested"])
    truth = _truth(name).get("effects") or {}
    if "friction_bump" in truth:
        hit = [t for t in pos if t["significant"]]
        assert hit, pos
        x_c = truth["friction_bump"]["params"]["x_c_mm"]["si"]
        lo, hi = hit[0]["peak_bin"]
        assert lo - hit[0]["bin_width"] <= x_c <= hi + hit[0]["bin_width"], (hit[0], x_c)
    else:
        assert not any(t["significant"] for t in pos), pos


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", STEPS_RUNS)
def test_no_slow_drift_read_from_a_position_loops_decaying_command(traced, name):
    """Position steps (a position loop of 1.8 1/s under 10 kN: each move's speed command decays over seconds): the
    declared base's speed-dependent remainder trended in time within each move, and the per-pass drift test called
    it a slow drift on the declared model's residual of every record here (p 1e-8 .. 4e-14, the null's 7e-11; on a
    blind axial-force record, after the explainers, p 8.4e-5).  The drift tests compare segments at one constant
    speed command: here there are none, no drift is reported and the signature says why."""
    assert _truth(name)["scenario"] == "position_steps"
    doc = traced(name)
    for key in ("residual_signature_before", "residual_signature"):
        sig = doc[key]
        drift = [t for t in sig["tests"] if t["variable"] == "time (slow drift)"]
        assert not any(t["significant"] for t in drift), (key, drift)
        why = [n for n in sig.get("not_tested") or [] if n["test"] == "time (slow drift)"]
        assert drift or (why and "speed command" in why[0]["why"]), (key, sig.get("not_tested"))
    assert "time (slow drift)" not in doc["residual_signature"]["structured"], doc["residual_signature"]["structured"]


@pytest.mark.campaign
@pytest.mark.slow
def test_no_ratchet_backlash_invented_beside_a_load_path_backlash(traced):
    """rig base + load-path backlash on an elastic surface (spring_load_ramp): the load path is found; no other
    physical effect is added, and every effect added lowers the error on the samples it was fitted to (its AIC
    drop is positive: a pitch chosen on the held-out segments once bought a ratchet backlash whose training
    error was higher than without it; the profile fits are now chosen on their training error, the AIC rule
    stays as the guard)."""
    name = "rig_loadpath_backlash_spring"
    assert _truth_effects(name) == ["loadpath_backlash"]
    doc = traced(name)
    phys = [e["name"] for e in _physical(doc)]
    assert phys == [LIBRARY["loadpath_backlash"]], doc["rounds"]
    for e in doc["effects_added"]:
        assert e.get("aic_drop") is None or e["aic_drop"] > 0, e


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.xfail(strict=False, reason="measured (trace-drags): after the detailed no-back, screw_friction_ripple "
                                        "is added first (window drop 76 %), then the load-path compliance; the "
                                        "Coulomb part stays in the base correction at its bound (0.057 N m, with the "
                                        "axial force and the direct efficiency at theirs): beyond them a Coulomb "
                                        "drag, an axial force and a direction drag explain the same 10 % of the "
                                        "window (held-out drops 288 / 290 / 291; 24 of 34 steady held-out segments "
                                        "improved, sign test p 0.012): on one trim load the planted 4 N m at the "
                                        "screw is the size of the rig base's plausible drag.  trace-lift: the joint "
                                        "lift of the base corrections in round 2 (drop 284.3) is carried by each of "
                                        "the efficiencies lifted alone, direction_friction, coulomb_friction and "
                                        "force_offset: a lossier base explains as much on one trim load")
def test_pair_of_library_effects_found_in_the_order_of_what_they_explain(traced):
    """Coulomb friction and screw ripple planted together: both found, the one with the larger held-out drop
    first."""
    name = "rig_pair_coulomb_ripple"
    assert set(_truth_effects(name)) == {"coulomb", "screw_ripple"}
    doc = traced(name)
    found = _found(doc)
    assert {"coulomb_friction", "screw_friction_ripple"} <= set(found), doc["rounds"]
    r1 = {c["name"]: c.get("holdout_chi2_drop") or 0.0 for c in doc["rounds"][0]["candidates"]}
    a, b = found.index("coulomb_friction"), found.index("screw_friction_ripple")
    first, second = ("coulomb_friction", "screw_friction_ripple") if a < b else ("screw_friction_ripple",
                                                                              "coulomb_friction")
    assert r1[first] >= r1[second], r1


@pytest.mark.campaign
@pytest.mark.slow
def test_a_ripple_fitted_short_is_reported_as_its_size_not_as_an_unexplained_local_effect(traced):
    """rig-sim's disk-pair no-back and a screw ripple on the trim record: both found; the ripple is fitted short (the
    rig's 3 N m at the screw is 0.0425 N m at the motor when the load drives, 0.0492 when the motor drives: the
    gearbox's 0.93 either way), and the once-per-lead friction it leaves, repeated over both passes, once set
    ``unexplained`` as a local effect (nut position repeated over passes, p 2e-5).  Tested beyond the added ripple's
    shape, the position test finds nothing; along the shape the residual holds the rest, in phase with the fit, and
    the fit plus it lands within the rig's two reflections."""
    name = "rig_pair_noback_ripple"
    assert set(_truth_effects(name)) == {"noback_quadrant", "screw_ripple"}
    doc = traced(name)
    assert {"noback_quadrant_friction", "screw_friction_ripple"} <= set(_found(doc)), doc["rounds"]
    sig = doc["residual_signature"]
    assert "nut_position (repeated over passes)" not in sig["structured"], sig["structured"]
    loc = next(t for t in sig["tests"] if t["variable"] == "nut_position (repeated over passes)")
    along = loc["added_shapes"]["screw_friction_ripple"]
    t = _truth(name)
    n, eta = t["kinematics"]["gear_ratio"], t["parameters"]["eta_gear_drive"]["value"]
    amp = t["effects"]["screw_ripple"]["params"]["T_amp_Nm"]["si"]
    lo, hi = amp * eta / n, amp / (n * eta)
    if along["fitted_amplitude"] < lo:  # fitted short of either reflection: the residual must say so
        assert along["significant"] and along["in_phase"] > 0, along
        assert lo - 0.003 <= along["fitted_amplitude"] + along["in_phase"] <= hi + 0.003, (along, lo, hi)


@pytest.mark.campaign
@pytest.mark.slow
def test_a_clearance_crossed_only_in_training_segments_is_judged_where_it_acts(traced):
    """rig-sim's pawl clearance beside its disk-pair no-back on the trim record: the load back-drives the screw through
    the clearance once, at the first stop (about 0.1 s, two 50 ms segments, both training ones: the held-out segments
    are every third whatever the record).  The held-out samples of the clearance window are then motion starts, where
    the clearance changes nothing, and the backlash, which explains the jump, was refused for a window drop of -7 %
    (fresh rig-sim record, seed 1213).  The window is judged over all its samples when its held-out samples carry
    under a fifth of its mean error, and says so: the no-back (the base step) and the backlash are both found."""
    name = "rig_pair_ratchet_noback"
    assert set(_truth_effects(name)) == {"ratchet_backlash", "noback_quadrant"}
    doc = traced(name)
    found = _found(doc)
    assert found[:2] == ["noback_quadrant_friction", "noback_backlash"], doc["rounds"]
    step = next(e for e in doc["effects_added"] if e["name"] == "noback_backlash")
    on_all = step["window_on_all_samples"]["motor_speed"]
    assert on_all["heldout_error_ratio"] < 0.2 and on_all["holdout_reduction"] < 0.05, on_all
    assert step["window_reduction"]["motor_speed"] >= 0.5, step["window_reduction"]
    assert step["aic_drop"] > 0 and step["error_reduction"]["motor_speed"] > 0.5, step
    assert set(found) & INVENTED == {"noback_backlash"}, found  # nothing else a rig-sim base lacks


@pytest.mark.campaign
@pytest.mark.slow
def test_a_cogging_beside_a_soft_compliance_both_found_and_no_backlash_invented(traced, params):
    """rig-sim's cogging (0.069 N m, 18 per revolution) beside a drive-train compliance of 5333 N m/rad on the position
    loop, 1 kHz (rig_pair_cogging_compliance, a blind set's draw).  Before: the base step refused the detailed no-back
    for a disk coefficient at its zero bound ("at its min bound" beside "collapses to zero"), a pawl clearance whose
    pitch the record did not determine was added for the no-back it brings, and beside the compliance the cogging's
    period screen was flat (it predicted the gear output's speed) and held the count at 6.  Now the no-back in the
    base step, then the compliance, then the cogging at its own count and size; no backlash."""
    name = "rig_pair_cogging_compliance"
    assert set(_truth_effects(name)) == {"cogging", "drivetrain_compliance"}
    doc = traced(name)
    found = _found(doc)
    assert {"drivetrain_compliance", "cogging_torque"} <= set(found), doc["rounds"]
    assert set(found) & INVENTED == {"drivetrain_compliance", "cogging_torque"}, found
    assert found.index("drivetrain_compliance") < found.index("cogging_torque")  # in the order of what they explain
    truth = _truth(name)["effects"]
    cog = next(e for e in doc["effects_added"] if e["name"] == "cogging_torque")
    assert cog["parameters_final"]["drive.cogging_periods"]["value"] == truth["cogging"]["params"]["n_per_rev"]["si"]
    assert cog["amplitude_final"]["value"] == pytest.approx(truth["cogging"]["params"]["A_Nm"]["si"], rel=0.2)
    dtc = next(e for e in doc["effects_added"] if e["name"] == "drivetrain_compliance")
    kg = dtc["parameters_final"]["gear.torsional_stiffness"]["value"]
    series = 1.0 / (1.0 / kg + 1.0 / params.value("screw.torsional_stiffness"))  # what the record determines
    assert series == pytest.approx(truth["drivetrain_compliance"]["params"]["k_Nm_rad"]["si"], rel=0.2), (kg, series)
    assert not doc["unexplained"], doc["residual_signature"]["structured"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_ripple_fitted_a_little_off_on_a_cold_ramp_is_its_size_not_an_unexplained_angle(traced):
    """rig-sim's cold friction and screw ripple (3 N m at the screw) on the whole cold ramp at -40 degC, 1 kHz
    (rig_pair_cold_ripple, a blind set's pair drawn again): both are found, the cold friction first; the ripple is
    fitted within 20 % of the rig's (3 N m over the gear ratio, either efficiency), and what it leaves at its own
    harmonic (a few per cent of it) once set ``unexplained`` on the screw angle (p 1e-20 on cc81cc4's trace).  The
    angle test is now made beyond that harmonic, and the leftover is reported along the ripple."""
    name = "rig_pair_cold_ripple"
    assert set(_truth_effects(name)) == {"temp_friction", "screw_ripple"}
    doc = traced(name)
    found = _found(doc)
    assert {"temperature_friction", "screw_friction_ripple"} <= set(found), doc["rounds"]
    assert found.index("temperature_friction") < found.index("screw_friction_ripple")
    assert not set(found) & (INVENTED - {"temperature_friction", "screw_friction_ripple"}), found  # no backlash
    t = _truth(name)
    amp = t["effects"]["screw_ripple"]["params"]["T_amp_Nm"]["si"] / t["kinematics"]["gear_ratio"]
    rip = next(e for e in doc["effects_added"] if e["name"] == "screw_friction_ripple")
    assert rip["amplitude_final"]["value"] == pytest.approx(amp, rel=0.2), (rip["amplitude_final"], amp)
    test = next(d for d in doc["residual_signature"]["tests"] if d["variable"] == "screw_angle")
    assert test.get("beyond_added") == [1] and not test["significant"], test
    along = test["added_shapes"]["screw_friction_ripple"]
    assert along["amplitude"] < 0.2 * along["fitted_amplitude"], along
    assert not doc["unexplained"], doc["residual_signature"]["structured"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_ripple_whose_one_part_is_near_zero_is_not_taken_out_by_the_backward_check(traced):
    """The same pair from a blind set (rig_pair_cold_ripple_phase: one motor, other velocity-loop gains, a 3.5 N m
    ripple at 333 deg): the ripple, found in round 2, was taken out after the load path's compliance came in round 3
    because its cosine part alone (-0.0197 N m) fell within two standard errors of zero, while given the others it
    still explained 86 % of its window with all 36 held-out segments better; the record then ended ``unexplained`` on
    the screw angle.  The backward check now judges the amplitude along the radius, as the forward rule does."""
    name = "rig_pair_cold_ripple_phase"
    assert set(_truth_effects(name)) == {"temp_friction", "screw_ripple"}
    doc = traced(name)
    found = _found(doc)
    assert {"temperature_friction", "screw_friction_ripple"} <= set(found), (found, doc["effects_removed"])
    assert found.index("temperature_friction") < found.index("screw_friction_ripple")
    assert "screw_friction_ripple" not in {r["name"] for r in doc["effects_removed"]}, doc["effects_removed"]
    t = _truth(name)
    amp = t["effects"]["screw_ripple"]["params"]["T_amp_Nm"]["si"] / t["kinematics"]["gear_ratio"]
    rip = next(e for e in doc["effects_added"] if e["name"] == "screw_friction_ripple")
    assert rip["amplitude_final"]["value"] == pytest.approx(amp, rel=0.2), (rip["amplitude_final"], amp)
    assert not doc["unexplained"], doc["residual_signature"]["structured"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_lossier_base_is_not_read_as_a_torque_constant_error(traced):
    """rig-sim's direction drag (2.45 / 1.29 N m at the screw) beside the load path's clearance on the position loop at
    10 kN, 1 kHz (rig_pair_direction_loadpath_steps, the twelfth blind set's draw): the clearance is found; the drag,
    a constant torque on one load, is not named, and the record's answer beyond a plausible base lists it among the
    explanations, with the efficiencies lifted beyond their catalogue spread.  The residual's torque proportional to
    the current (r2 0.08, p 7e-10) is that lossier base's, one column with it at one temperature: it had set
    ``unexplained`` as a torque-constant error on a record with nothing out of the library.  It is reported as the
    base's, and no physical effect the rig lacks is invented."""
    from thsa_control.trace.signature import TORQUE_CONSTANT

    name = "rig_pair_direction_loadpath_steps"
    assert set(_truth_effects(name)) == {"direction_friction", "loadpath_backlash"}
    doc = traced(name)
    found = _found(doc)
    assert "loadpath_compliance" in found, doc["rounds"]
    assert not set(found) & INVENTED, found
    beyond = doc["beyond_plausible_base"]
    carriers = {c["name"]: c for c in beyond.get("carriers") or []}
    if "direction_friction" not in found:  # not named: the record says a constant torque is there and what it may be
        assert beyond["status"] == "not_named" and "direction_friction" in carriers, beyond
    sig = doc["residual_signature"]
    kt = next(t for t in sig["tests"] if t["variable"] == TORQUE_CONSTANT)
    if kt["significant"] and any(c["base"] for c in carriers.values()):
        assert kt["remainder"] == "base" and "one column" in kt["why_base"], kt
    assert TORQUE_CONSTANT not in sig["structured"], sig["structured"]
    assert not doc["unexplained"], sig["structured"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_no_back_that_would_not_hold_is_no_base_and_the_ratchet_is_found(traced):
    """rig-sim's ratchet backlash (9.02 deg) beside a cogging (0.062 N m) on the cold check at 500 Hz
    (rig_pair_cogging_ratchet_cold, the thirteenth blind set's draw): while the load rises to 10 kN with the drive
    off, the screw slips back through the pawl's initial free travel.  The base step's detailed no-back took that
    slip as a compressive-side static coefficient of 0.0003 N m/N, a no-back that cannot hold the 10 kN it then
    carries, and a drive-train compliance the rig lacks was added after it.  The detail is refused at the holding
    limit, and the ratchet's clearance is the first physical effect, with the disks it needs; the cogging's harmonic
    is beyond the record's Nyquist frequency and is not asked for."""
    from thsa_control.trace.candidates import HOLDING_COEFFICIENTS

    name = "rig_pair_cogging_ratchet_cold"
    assert set(_truth_effects(name)) == {"cogging", "ratchet_backlash"}
    doc = traced(name)
    nb = next(d for d in doc["base_corrections"]["declared_components_detailed"]
              if d["name"] == "noback_quadrant_friction")
    assert not nb["accepted"] and "holding limit" in nb["reason"], nb["reason"]
    low = [n for n in HOLDING_COEFFICIENTS if n in nb["parameters"] and not nb["parameters"][n].get("held")
           and nb["parameters"][n]["ci95"][1] < 0.012 * 0.85 / (2 * math.pi)]
    assert low == ["noback.mu_static_neg"], nb["parameters"]  # the compressive side, the set the 10 kN loads
    phys = _physical(doc)
    assert [e["name"] for e in phys][:1] == ["noback_backlash"], doc["rounds"]
    assert max(phys[0]["window_reduction"].values()) >= 0.5, phys[0]["window_reduction"]
    assert any(e["name"] == "noback_quadrant_friction" and e.get("implied_by") == "noback_backlash"
               for e in doc["effects_added"]), doc["effects_added"]
    assert set(_found(doc)) & INVENTED == {"noback_backlash"}, _found(doc)  # no compliance, nothing else


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_noback_worn_stop",
                                  pytest.param("rig_noback_worn_hold", marks=pytest.mark.campaign)])
def test_a_no_back_that_does_not_hold_is_found_as_a_fault(traced, params, name):
    """rig-sim's quadrant no-back with the compressive-side disks worn below the holding limit 0.0016 N m/N (static
    0.001 and Coulomb 0.0008 on the check stop at 20 kN, rig_noback_worn_stop; 0.0012 and 0.0009 on the drive-off
    load hold to 40 kN, rig_noback_worn_hold): with the drive off the load back-drives the screw, and it is still
    turning back when the load or the record ends, where a pawl's free travel would have been taken up.  The base
    step's detailed no-back reads the worn coefficients and is refused as the rig's base (a no-back that cannot hold
    is none); before this the trace stopped there on the stop, "nothing significant", ``unexplained`` false, the
    motor-speed residual 16 times its noise.  The detail is offered in the rounds as a finding, judged on every
    sample as in the base step (on the hold every slipping sample is a transient of the base: scored outside them
    its held-out drop was 0): it is the first found effect, reported as a fault, its coefficients of the size
    rig-sim planted.  A safety finding: the stop is traced in the default run too (about 45 s)."""
    from thsa_control.trace.candidates import _rule_holding

    truth = _truth(name)["effects"]["noback_quadrant"]["params"]
    limit = 0.012 * 0.85 / (2 * math.pi)
    assert truth["mu_s_neg"]["si"] < limit  # the premise: planted below the limit
    run = run_kinematics(read_run(DATA / f"{name}.csv"), params)
    s, t = run.signals, np.asarray(run.time, float)
    off = (np.asarray(s["primary_enable"]) == 0) & (np.asarray(s["standby_enable"]) == 0)
    held = off & (np.asarray(s["load_force"], float) > 15e3)  # the drive off, a compressive load on
    ends = np.flatnonzero(held & ~np.r_[held[1:], False])  # the last sample of each such stretch
    assert any(np.max(s["screw_speed"][(t > t[i] - 0.1) & (t <= t[i])]) < -0.3 for i in ends)  # [rad/s]: slipping
    doc = traced(name)
    nb = next(d for d in doc["base_corrections"]["declared_components_detailed"]
              if d["name"] == "noback_quadrant_friction")
    assert not nb["accepted"] and nb.get("offered_as_finding"), nb
    found = [e for e in doc["effects_added"] if not e.get("implied_by")]
    assert found and found[0]["name"] == "noback_quadrant_friction" and not found[0].get("base_step"), found
    step = found[0]
    assert step["fault"]["kind"] == "no_back_does_not_hold", step
    assert step["window_reduction"]["motor_speed"] >= 0.5, step["window_reduction"]
    assert _rule_holding(params, [run])[0] == pytest.approx(limit)
    p = step["parameters"]["noback.mu_static_neg"]
    assert not p.get("held") and p["ci95"][1] < limit, p
    assert abs(math.log(p["value"] / truth["mu_s_neg"]["si"])) < math.log(1.5), (p, truth["mu_s_neg"])
    assert "noback_backlash" not in _found(doc) and not set(_found(doc)) & INVENTED, _found(doc)
    # the record's own stops say the same without the model, and the final model's margin is below 1 over the
    # whole inverse-efficiency range
    h = doc["no_back_holding"]
    assert h["observed"]["verdict"] == "slips" and h["fault_found"] and h["remainder"] is None, h
    m = next(x for x in h["margin"] if x["side"] == "compressive")
    assert m["determined"] and m["shown"] == "does not hold" and m["margin_range"][1] < 1, m


@pytest.mark.campaign
@pytest.mark.slow
def test_a_chattering_screw_speed_is_no_sensor_gain(traced):
    """rig-sim's quadrant no-back on the check stop at 20 kN (rig_noback_quadrant_checkstop, the thirteenth blind
    set's draw): in the retraction under the aiding load the loaded disk slips and the screw speed chatters (20 rpm at
    the screw), and no steady pass qualifies for the speeds' travel gain.  Least squares of the motor speed on that
    screw speed is attenuated (0.964) and had set ``unexplained`` as a sensor gain on a record with nothing out of the
    library; the fit with errors in both reads the sensors as agreeing, and the record is explained."""
    from thsa_control.trace.signature import GAIN_TOLERANCE

    name = "rig_noback_quadrant_checkstop"
    assert set(_truth_effects(name)) == {"noback_quadrant"}
    doc = traced(name)
    sig = doc["residual_signature"]
    pair = next(s for s in sig["sensors"] if s["variable"] == "motor_speed vs gear_ratio x screw_speed")
    assert "travel_test" not in pair and pair["gain_method"].startswith("errors in both"), pair
    assert pair["ols_gain"] < 1 - 2 * GAIN_TOLERANCE, pair  # what least squares read
    assert abs(pair["gain"] - 1) < 2 * GAIN_TOLERANCE and not pair["gain_significant"], pair
    assert pair["variable"] not in sig["structured"] and not doc["unexplained"], sig["structured"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_current_offset_on_a_drive_never_off_is_said_not_tested(traced):
    """rig-sim's current-sensor offset (0.25 A) on a rig that keeps its drive energised at zero command
    (rig_current_offset_nogating): with no drive-off sample the offset reads as a constant torque at the motor,
    which the constant-torque explainers share (one load, both directions), so the record cannot flag it; the trace
    says the test was not made, for that run, and invents no physical effect for the offset."""
    name = "rig_current_offset_nogating"
    assert set(_truth_effects(name)) == {"current_offset"}
    assert json.loads((DATA / f"{name}.json").read_text())["motor_disabled_when_cmd_zero"] is False
    doc = traced(name)
    sig = doc["residual_signature"]
    assert not any(d.get("kind") == "sensor_offset" for d in sig["sensors"]), sig["sensors"]
    nt = [d for d in sig["not_tested"] if d["test"] == "motor_current with the drive off"]
    assert len(nt) == 1 and nt[0]["run"] == name and nt[0]["would_show"] == "a current-sensor offset", sig["not_tested"]
    assert not set(_found(doc)) & INVENTED, doc["rounds"]


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_current_offset", "rig_current_offset_cold"])
def test_a_constant_torque_a_current_offset_covers_is_not_named_as_a_drag_or_a_force(traced, name):
    """rig-sim's offset on the primary current sensor, with the drive off in the stops: 0.25 A on a trim record
    (rig_current_offset), -0.33 A drawn on a cold ramp (rig_current_offset_cold).  The offset is flagged with the
    drive off, and with the drive on it is a constant torque of one sign that the constant torques beyond the base
    share.  Since an axial force loads the load path's attachments (its LVDT term) the force offset explained most
    of it on the trim record and was named at 6.1 kN; now each constant torque beyond its bound whose excess the
    offset's torque covers (Kt I0 = 0.081 N m there) is refused as the offset's, and none is named.  On the trim
    record the force offset's excess is the offset's torque within a factor of 1.5 (0.089 N m); on the cold ramp the
    joint lift is carried by the Coulomb drag alone, whose interval reaches back inside its bound (an excess of 0 at
    its near end), refused with the offset's reason too."""
    doc = traced(name)
    planted = _truth(name)["effects"]["current_offset"]["params"]
    planted = planted["offset_A"]["si"] if "offset_A" in planted else 0.25  # rig-sim's default
    sig = doc["residual_signature"]
    off = next(d for d in sig["sensors"] if d.get("kind") == "sensor_offset")
    assert off["significant"] and abs(off["offset"] - planted) < 0.02, off
    assert not set(_found(doc)) & CONSTANT_TORQUES, _found(doc)
    assert doc["beyond_plausible_base"]["status"] != "named", doc["beyond_plausible_base"]
    checks = [c for r in doc["rounds"] for c in r["candidates"]
              if c["name"] in CONSTANT_TORQUES and c.get("beyond_base_correction") and c.get("current_offset")]
    assert checks, [(r["round"], [c["name"] for c in r["candidates"]]) for r in doc["rounds"]]
    for c in checks:
        co = c["current_offset"]
        assert co["explained"], co
        assert any("current-sensor offset" in w for w in c["implausible_because"]), c["implausible_because"]
        if name == "rig_current_offset" and c["name"] == "force_offset":
            assert 1 / 1.5 < co["excess_torque"] / co["offset_torque"] < 1.5, co


#: one-load records of a constant-torque library effect (one load magnitude and sign, both directions or a trim):
#: the per-(load sign, direction) constants are spanned by the base's explainers (trace.json ``separability``), so
#: the planted effect may be named, left ambiguous with others, or not named; never another constant torque alone
ONE_LOAD_CONSTANT_TORQUE = [("rig_coulomb", "coulomb_friction"), ("rig_axial_offset", "force_offset"),
                            ("rig_direction_friction", "direction_friction"),
                            ("rig_pair_coulomb_ripple", "coulomb_friction")]
CONSTANT_TORQUES = {"coulomb_friction", "force_offset", "direction_friction"}


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name, planted", ONE_LOAD_CONSTANT_TORQUE)
def test_nothing_wrong_is_named_where_one_load_cannot_separate_the_constant_torques(traced, name, planted):
    """On a one-load record the planted constant torque, an ambiguity that includes it, or nothing: no other
    constant torque is named, no ambiguity or joint lift's carriers leave the planted one out, and a joint lift
    verdict is reported in every round where a base correction sat at its bound."""
    doc = traced(name)
    named = [e["name"] for e in doc["effects_added"] if not e.get("implied_by") and not e.get("refines_declared")
             and e["name"] in CONSTANT_TORQUES]
    assert set(named) <= {planted}, (named, doc["rounds"])
    for a in doc["ambiguous"]:
        if set(a["candidates"]) & CONSTANT_TORQUES:
            assert planted in a["candidates"], a
    for r in doc["rounds"]:
        j = r.get("joint_lift")
        if j and "error" not in j and j["significant"]:  # the base's own efficiencies alone are no wrong name
            named_alone = [c for c in j["carriers"] if c in CONSTANT_TORQUES] if len(j["carriers"]) == 1 else []
            assert named_alone in ([], [planted]), j


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name, planted", ONE_LOAD_CONSTANT_TORQUE)
def test_a_constant_torque_beyond_the_base_that_one_load_cannot_attribute_is_said_with_the_planted_among_them(
        traced, name, planted):
    """The record's top-level answer (``beyond_plausible_base``): where it says a constant torque beyond a plausible
    base is present (named or not attributed), the planted torque is among its explanations (on a run with it alone);
    where it names one, that is the planted one; and its explanations are the last joint lift's carriers.  On the
    pair with rig-sim's screw ripple, T_a (1 + sin), the ripple's mean is a drag of its own beside the Coulomb drag,
    and the final joint lift leaves the Coulomb drag just outside the carriers (held-out drop 250.1 against the
    joint 279.8, carry gap 27.0; measured on 1c6f606): only the naming is checked there."""
    doc = traced(name)
    b = doc["beyond_plausible_base"]
    assert b["status"] != "failed", b
    if b["status"] in ("named", "not_named"):
        names = [c["name"] for c in b["carriers"]]
        assert planted in names or len(_truth_effects(name)) > 1, b
        assert [c["name"] for c in b["carriers"] if c["named"]] in ([], [planted]), b
        last = [r for r in doc["rounds"] if r.get("joint_lift")][-1]["joint_lift"]
        assert names == last["carriers"], (names, last)
        for c in b["carriers"]:  # an explainer lifted carries the drop with a size beyond its plausible bound
            for n, v in c["values"].items():
                if v.get("plausible_bound") and not c["base"]:
                    lo, hi = v["plausible_bound"]
                    edge = 0.02 * (hi - lo)
                    assert not lo + edge < v["value"] < hi - edge, (c["name"], n, v)


@pytest.mark.campaign
@pytest.mark.slow
def test_a_cold_drag_named_at_one_temperature_says_which_constant_torques_it_does_not_rule_out(traced):
    """rig_axial_offset_cold: on one temperature, one load and one direction the cold drag is one constant torque
    among the others; named as the physical effect, its step lists the planted axial force among what the record does
    not rule out in its place, with the lossier base beside it."""
    doc = traced("rig_axial_offset_cold")
    steps = [e for e in doc["effects_added"] if e.get("not_ruled_out")]
    assert steps, [(e["name"], e.get("round_added")) for e in doc["effects_added"]]
    for e in steps:
        names = [a["name"] for a in e["not_ruled_out"]["alternatives"]]
        assert "force_offset" in names and EFFICIENCY_LIFT in names, e["not_ruled_out"]
        n = e["not_ruled_out"]
        assert all(a["holdout_chi2_drop"] >= n["own_drop_on_constant_torque_samples"] - n["carry_gap"]
                   for a in n["alternatives"]), n


@pytest.mark.campaign
@pytest.mark.slow
def test_a_cold_drag_weaker_than_the_lift_is_not_named_in_its_place(traced):
    """rig_direction_friction_checkcold: a 4.9 / 0.7 N m direction drag on the check cold (one temperature): the cold
    drag explains less of the constant torques' samples than each constant torque lifted beyond its bound, and fitted
    with the joint lift it adds nothing; it is not named, and the record's answer beyond a plausible base is a
    constant torque present and not attributed, with the planted direction drag among its carriers."""
    doc = traced("rig_direction_friction_checkcold")
    assert "temperature_friction" not in _found(doc), _found(doc)
    checks = [c["given_the_lift"] for r in doc["rounds"] for c in r["candidates"]
              if c["name"] == "temperature_friction" and c.get("given_the_lift")]
    assert checks, [(r["round"], [c["name"] for c in r["candidates"]]) for r in doc["rounds"]]
    for g in checks:
        assert "error" not in g, g
        assert g["best_lift_drop"] - g["own_drop_on_constant_torque_samples"] > g["carry_gap"], g
        assert not g["adds"] and g["holdout_chi2_drop"] <= g["chi2_threshold"], g
    answer = doc["beyond_plausible_base"]
    assert answer["status"] == "not_named", answer
    assert "direction_friction" in [c["name"] for c in answer["carriers"]], answer["carriers"]
    # a 2.2 s record: its constant-torque window holds fewer held-out segments than the robustness test needs to pass
    # at all, and the answer says so (each drag improves every one of them)
    short = answer.get("too_few_segments")
    assert short and short["segments"] < short["needed"] == 10 and short["smallest_p"] >= 1e-3, answer
    seg = {c["name"]: c["window_segments"] for r in doc["rounds"] for c in r["candidates"]
           if c["name"] == "direction_friction" and c.get("window_segments")}
    assert seg["direction_friction"]["improved"] == seg["direction_friction"]["segments"] == short["segments"], seg


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_ratchet_backlash", "rig_ratchet_backlash_lowgain"])
def test_a_disk_coefficient_held_without_the_pawl_clearance_is_determined_once_the_clearance_is_in(traced, name):
    """The pawl clearance on the trim ramps (30 kN compressive, both directions): the base step's model lacks it and
    its fit leaves the no-back's retraction disk coefficient undecided (a standard error larger than the value), so it
    is held at the parameter file's 0.0043.  Once the clearance is added the coefficient is freed again and
    determined, within 10 % of the rig's loaded-disk coefficient (its truth file's ``mu_noback_coulomb``), and no
    constant torque is named beyond the base: held at the file's value it left 7.5 N m of loaded-disk drag at 30 kN
    that the blind record (rig_ratchet_backlash_lowgain, a softer velocity loop) named an axial force of 2 kN."""
    doc = traced(name)
    nb = next(e for e in doc["effects_added"] if e["name"] == "noback_quadrant_friction")
    later = {h["parameter"]: h for h in nb.get("determined_later", [])}
    assert "noback.mu_coulomb_neg" in later, (nb["not_determined"], [r.get("held_refreed") for r in doc["rounds"]])
    assert later["noback.mu_coulomb_neg"]["determined_given"] == "noback_backlash"
    assert "noback.mu_coulomb_neg" not in {h["parameter"] for h in nb["not_determined"]}
    truth = _truth(name)["parameters"]["mu_noback_coulomb"]["value"]
    final = doc["final_parameters"]["noback.mu_coulomb_neg"]
    final = final["value"] if isinstance(final, dict) else final
    assert abs(final - truth) <= 0.1 * truth, (final, truth)
    # read off the record, not the file: the refit moved it from the held value by more than two of its own standard
    # errors (a refit that never left its start had "determined" the file's 0.0043 itself, 5.5 % off, inside the
    # 10 % above), towards the rig's
    h = later["noback.mu_coulomb_neg"]
    assert abs(h["value"] - h["held_at"]) > 2 * h["stderr"], h
    assert abs(h["value"] - truth) < abs(h["held_at"] - truth), (h, truth)
    assert doc["beyond_plausible_base"]["status"] != "named", doc["beyond_plausible_base"]
    assert not any(e.get("beyond_base_correction") for e in doc["effects_added"]), _found(doc)


#: the committed records with rig-sim's pawl clearance planted
PAWL_RUNS = sorted(p.name[:-len(".truth.json")] for p in DATA.glob("*.truth.json")
                   if "ratchet_backlash" in (json.loads(p.read_text()).get("effects") or {}))


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", PAWL_RUNS)
def test_a_reported_pawl_pitch_holds_the_rigs_pitch(traced, name):
    """Wherever the trace profiles the pawl pitch on a record with rig-sim's clearance planted, the pitch is either
    determined with rig-sim's pitch inside its interval, or not determined with rig-sim's pitch inside the set's
    hull, the interval shown.  A loaded stop after a long travel sees the travel modulo the pitch: a comb of teeth
    narrower than the profile's grid step, which the grid samples at random; on the bipolar tensile ramps its 301
    values hit one tooth (0.1425 rad) and called the pitch determined within 0.14239..0.1426 where rig-sim has 0.1285
    (the comb check, thsa_control.fit.profile.ProfileSettings.comb_budget)."""
    assert len(PAWL_RUNS) >= 4, PAWL_RUNS
    doc = traced(name)
    truth = _truth(name)["effects"]["ratchet_backlash"]["params"]["pitch_deg"]["si"]
    seen = 0
    for r in doc["rounds"]:
        for c in r.get("candidates", []):
            d = ((c.get("profile") or {}).get("determination") or {}).get("noback.pawl_pitch")
            if d is None:
                continue
            seen += 1
            lo, hi = c["profile"]["interval"]["noback.pawl_pitch"] or (0.0, math.inf)  # None: it reaches the range's end
            assert lo <= truth <= hi, (r.get("round"), d["determined"], lo, hi, truth, d.get("comb_check"))
    assert seen, "the pawl clearance was never tried"


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", _cases([(n,) for n in NULLS]))
def test_a_null_never_hears_of_a_constant_torque_beyond_the_base_without_a_lossier_base_beside_it(traced, name):
    """Nothing planted: the record's answer names no constant torque beyond the base, and where a joint lift passes
    with carriers the base's own efficiencies beyond their catalogue spread are among them (the rig base's no-back
    drags while driven: a lossier base, no effect) or no single torque carries it."""
    b = traced(name)["beyond_plausible_base"]
    assert b["status"] in ("not_fitted", "within", "not_named", "no_carrier"), b
    if b["status"] == "not_named":
        assert any(c["base"] for c in b["carriers"]), b


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_drivetrain_compliance", "rig_screw_ripple", "rig_pair_coulomb_ripple"])
def test_found_effects_are_reported_in_the_order_of_what_they_explain(traced, name):
    """Runs where two or more found effects are kept (a planted one and the bases' load path): each still earns its
    place given the others (the backward check: its admission criterion, the model refitted without it), and they
    are reported in the order of their leave-one-out held-out drops; the bases' load path never comes before a
    planted effect that explains more given it (rig_drivetrain_compliance: the load path won round 1 with 1179
    against 651 on different sample sets; given each other, on all held-out samples, the drive-train compliance
    explains 5446, the load path 3026)."""
    doc = traced(name)
    order = doc["order"]
    assert order is not None and order["measure"], order
    contrib = [c["holdout_chi2_drop_given_others"] for c in order["contributions"]]
    assert contrib == sorted(contrib, reverse=True), order
    found = [e for e in doc["effects_added"] if e.get("round_added") and not e.get("implied_by")]
    assert [e["name"] for e in found] == order["order"]
    for e in found:
        assert e["leave_one_out"]["fails"] == [], e["leave_one_out"]
    planted = {LIBRARY[t] for t in _truth_effects(name)}
    names = [e["name"] for e in found]
    for p in planted & set(names):
        for b in BASE_COMPLIANCE & set(names):
            if contrib[names.index(p)] > contrib[names.index(b)]:
                assert names.index(p) < names.index(b), order


ALL_RUNS = sorted(p.stem for p in DATA.glob("*.csv"))


#: rig-sim's drive-train compliance records: the chirp, the position loop's steps and the whole speed excitation
RINGING = ["rig_drivetrain_compliance", "rig_drivetrain_compliance_steps", "rig_drivetrain_compliance_exc",
           "rig_drivetrain_compliance_rev"]


@pytest.mark.campaign
@pytest.mark.slow
def test_a_candidate_that_explains_another_part_is_no_rival(traced):
    """rig-sim's drive-train compliance under load reversals, on the rig base with its own load path: the load path's
    compliance (the LVDT) and the drive-train compliance (the screw speed) had held-out drops within the ambiguity
    gap, and neither was named on a66f206.  The load path leaves the screw-speed error the compliance explains, so
    the two are no rivals: both are added, the compliance first by what it explains, and the round says why."""
    doc = traced("rig_drivetrain_compliance_rev")
    assert not doc["ambiguous"], doc["ambiguous"]
    nr = [x for r in doc["rounds"] for x in r.get("not_rivals", [])]
    assert any(x["name"] == "drivetrain_compliance" and x["channel"] == "screw_speed"
               and x["best_reduction"] < 0.5 * x["its_reduction"] for x in nr), nr
    assert [e["name"] for e in _physical(doc)][:1] == ["drivetrain_compliance"], doc["order"]
    assert {"drivetrain_compliance", "loadpath_compliance"} <= {e["name"] for e in doc["effects_added"]}


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", RINGING)
def test_the_compliance_starts_at_the_mode_the_record_rings_at(traced, params, name):
    """rig-sim's drive-train compliance (8000 N m/rad in series, 2 N m s/rad: a mode near 47 Hz): each fit of the
    candidate starts its stiffness at the mode the record rings at (``start`` in trace.json, read by
    thsa_control.fit.resonance_screen), and the added compliance's series stiffness (with the file's screw) is within
    35 % of rig-sim's.  On the whole speed excitation the fit started at the file's stiffness (a mode near 87 Hz)
    stopped at a gearbox of 2.4e4 N m/rad, series 1.5e4 (+88 %), on 09049ae."""
    truth = _truth(name)["effects"]["drivetrain_compliance"]["params"]["k_Nm_rad"]["si"]
    doc = traced(name)
    fits = [c for r in doc["rounds"] for c in r["candidates"] if c["name"] == "drivetrain_compliance"]
    assert fits and all((c.get("start") or {}).get("rule") == "drivetrain_resonance" for c in fits), fits
    step = next((e for e in doc["effects_added"] if e["name"] == "drivetrain_compliance"), None)
    assert step is not None and step.get("start"), [e["name"] for e in doc["effects_added"]]
    k_gear = step["parameters"]["gear.torsional_stiffness"]["value"]
    series = 1.0 / (1.0 / k_gear + 1.0 / params.value("screw.torsional_stiffness"))
    assert series == pytest.approx(truth, rel=0.35), (k_gear, series, truth)


@pytest.mark.campaign
@pytest.mark.slow
def test_the_compliance_damping_is_rig_sims_once_the_no_back_holds_the_stop(traced, params):
    """rig-sim's drive-train compliance over its whole speed excitation ends with a drive-off stop under 20 kN: the
    rotors ring on the compliance at about 10 Hz while the rig's no-back holds the screw.  Level A's ideal no-back
    holds exactly the load torque, so in the model the screw slipped back with each swing, and the fit damped the
    ringing: 17.6 N m s/rad against rig-sim's 2 (gearbox 7.0e3, series 6.0e3 against 8e3) on 10d1b24, reported as the
    compliance's values.  Since e12fb32 the detailed no-back, refused in the base step, is offered again after the
    compliance and added at the parameter file's coefficients (the run determines none of them: reported so); in the
    final model the compliance is rig-sim's (series within 10 %, damping within a factor 1.5), and its entry says its
    values changed with the no-back (docs/trace_notes.md, "A damping the stop chose")."""
    name = "rig_drivetrain_compliance_exc"
    truth = _truth(name)["effects"]["drivetrain_compliance"]["params"]
    doc = traced(name)
    names = [e["name"] for e in doc["effects_added"]]
    assert names.index("drivetrain_compliance") < names.index("noback_quadrant_friction"), names
    nb = next(e for e in doc["effects_added"] if e["name"] == "noback_quadrant_friction")
    assert nb.get("refines_declared") == ["noback_ideal"]
    held = {h["parameter"] for h in nb["not_determined"]}
    assert {"noback.mu_static_pos", "noback.mu_coulomb_pos"} <= held, nb["not_determined"]
    step = next(e for e in doc["effects_added"] if e["name"] == "drivetrain_compliance")
    fin = step["parameters_final"]
    k_gear = fin["gear.torsional_stiffness"]["value"]
    series = 1.0 / (1.0 / k_gear + 1.0 / params.value("screw.torsional_stiffness"))
    assert series == pytest.approx(truth["k_Nm_rad"]["si"], rel=0.1), (k_gear, series)
    d = fin["gear.torsional_damping"]["value"]
    assert truth["d_Nm_s_rad"]["si"] / 1.5 <= d <= truth["d_Nm_s_rad"]["si"] * 1.5, d
    assert "gear.torsional_damping" in step["changed_after_added"]["parameters"]
    assert step["changed_after_added"]["with"] == ["noback_quadrant_friction"]


@pytest.mark.campaign
@pytest.mark.slow
def test_the_held_out_segments_decide_the_damping_under_reversals_and_it_is_said(traced, params):
    """rig-sim's drive-train compliance under speed reversals at 25 kN (rig_drivetrain_compliance_rev): after each
    reversal into the aiding quadrant the screw stands on the no-back while the twist builds, breaks away and rings.
    The reversals repeat every 2.4 s, 48 segments of 50 ms, and every third segment held out hides the breakaway
    from the search's fits: the damping comes out 0.42 +- 0.10 N m s/rad against rig-sim's 2.  The every-segment
    check fits the final model on the held-out segments too and reports the move, with the range both fits span;
    its value is rig-sim's within a factor 1.5, as is the series stiffness within 10 %, and it is the final model's
    value (docs/trace_notes.md, "A periodic record and the held-out segments")."""
    name = "rig_drivetrain_compliance_rev"
    truth = _truth(name)["effects"]["drivetrain_compliance"]["params"]
    doc = traced(name)
    assert doc["every_segment"]["holdout_layout"] == "every_kth"
    step = next(e for e in doc["effects_added"] if e["name"] == "drivetrain_compliance")
    fin = step.get("parameters_final") or step["parameters"]
    k_gear = fin["gear.torsional_stiffness"]["value"]
    series = 1.0 / (1.0 / k_gear + 1.0 / params.value("screw.torsional_stiffness"))
    assert series == pytest.approx(truth["k_Nm_rad"]["si"], rel=0.1), (k_gear, series)
    d_true = truth["d_Nm_s_rad"]["si"]
    ev = step["every_segment"]
    assert "gear.torsional_damping" in ev["moved"] and "gear.torsional_damping" in doc["every_segment"]["moved"]
    d_all = ev["parameters"]["gear.torsional_damping"]["value"]
    assert d_true / 1.5 <= d_all <= d_true * 1.5, d_all
    lo, hi = fin["gear.torsional_damping"]["range_over_segment_sets"]
    d_train = ev["training"]["gear.torsional_damping"]["value"]
    assert lo <= d_train <= hi and lo <= d_all <= hi
    assert doc["every_segment"]["adopted"] is True and ev["adopted"] is True
    assert fin["gear.torsional_damping"]["value"] == d_all
    assert doc["final_parameters"]["gear.torsional_damping"]["value"] == d_all


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ALL_RUNS)
def test_the_weight_check_reports_the_range_of_every_weighting(traced, name):
    """Every found effect's parameters are fitted again at the channels' residual spread and on the channels the
    model describes alone (thsa_control.trace.weights): the structural channels are those left beyond twice their
    noise, a parameter said to depend on the weights has a range holding the search's value and every weighting's
    that determines it, and where every channel is at its noise the check says the weights are the same."""
    doc = traced(name)
    for e in doc["effects_added"]:
        check = e.get("weight_check")
        if e.get("implied_by") or check is None:
            continue
        if check.get("same_as_sensor_noise"):
            assert all(check["channel_scales"][c] <= doc["channel_weights"]["rms"][c] for c in check["channel_scales"])
            continue
        assert "error" not in check, check
        over = check["scale_over_noise"]
        assert set(check["structural_channels"]) == {c for c, r in over.items() if r > 2.0}, check
        for n in check["depends_on_weights"]:
            lo, hi = check["range"][n]
            assert e["parameters"][n]["range_over_channel_weights"] == [lo, hi]
            for k, v in check["parameters"][n].items():
                sd = v["stderr"]
                if k == "sensor_noise_weights" or (sd is not None and abs(v["value"]) > 2.0 * sd):
                    assert lo <= v["value"] <= hi, (n, k, v, lo, hi)


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ALL_RUNS)
def test_the_cap_counts_found_effects_not_what_the_base_contains(traced, name):
    """``max_effects`` caps the found effects; the no-back the base step details is what the base contains and does
    not count.  A search whose last round added an effect stopped at the cap, so it holds ``max_effects`` found
    effects (on fd7f278 rig_screw_ripple, rig_pair_noback_ripple and rig_pair_coulomb_ripple stopped with the detailed
    no-back and two)."""
    doc = traced(name)
    found = [e for e in doc["effects_added"] if e.get("round_added") and not e.get("implied_by")]
    assert not [e for e in found if e.get("base_step")]
    if doc["rounds"] and any(e["round_added"] == doc["rounds"][-1]["round"] for e in found):
        # the last round added one: the search stopped at the cap, or because no candidate was left to score (each
        # skipped for a reason the trace names: rig_drivetrain_compliance_rev, whose two added compliances leave
        # only candidates that made things worse or cannot act)
        stop = doc.get("stop") or {"reason": "cap"}
        assert (len(found) == doc["settings"]["max_effects"]) == (stop["reason"] == "cap"), (
            [e["name"] for e in doc["effects_added"]], stop)
        assert stop["reason"] in ("cap", "nothing_to_score"), stop


def _untried_at_stop(doc: dict) -> list[str]:
    """The candidates skipped, for making the held-out error worse in the round before, in the round where the
    search stopped because nothing was significant (the last round added nothing and found no ambiguity), or when it
    stopped with no candidate left to score (``stop`` in trace.json names the skipped ones and why)."""
    rounds = doc["rounds"]
    stop = doc.get("stop") or {}
    if stop.get("reason") == "nothing_to_score":  # every candidate left skipped after the last addition
        return [n for n in EFFECTS if f"{n} (made the held-out error worse" in stop["detail"]]
    if not rounds:
        return []
    last = rounds[-1]
    added_last = any(e.get("round_added") == last["round"] for e in doc["effects_added"])
    if added_last or last.get("ambiguous"):
        return []
    return [s["name"] for s in last["skipped"] if s["reason"].startswith("made the held-out error worse")]


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ALL_RUNS)
def test_no_search_stops_with_a_candidate_untried(traced, name):
    """A candidate that made the held-out error worse is skipped in the next round; when that round finds nothing
    significant, the skipped ones are fitted on the final model before the search stops (a retry round): no
    verdict "nothing more" rests on a candidate never fitted to the final model (on fd7f278, 21 of the 42 committed
    runs stopped with one skipped, rig_cogging among them)."""
    doc = traced(name)
    assert _untried_at_stop(doc) == [], doc["rounds"][-1]["skipped"]
    for r in doc["rounds"]:
        if r.get("retry"):
            prev = doc["rounds"][r["round"] - 2]
            assert r["model"] == prev["model"], (r["model"], prev["model"])  # the same model, not refitted
            assert set(r["retry"]["fitted"]) == {c["name"] for c in r["candidates"]} | {
                s["name"] for s in r["skipped"]}, r
            assert set(r["retry"]["decided_with"]) == {c["name"] for c in prev["candidates"]}


@pytest.mark.slow
def test_trace_json_and_report_say_what_was_done(traced_result, tmp_path):
    """trace.json follows its schema and reports the base corrections with their bounds' sources; the report has
    the conclusion table, the candidates' drops and the signature plots (the short cogging run)."""
    from thsa_control.report.trace import write_trace_folder

    res = traced_result("rig_cogging")
    doc = res.to_dict()
    jsonschema = pytest.importorskip("jsonschema")
    jsonschema.validate(json.loads(json.dumps(doc, default=float)),
                        json.loads((DATA.parents[2] / "docs" / "trace_schema.json").read_text()))
    bc = doc["base_corrections"]
    assert bc is not None and all(c["bound_source"] for c in bc["corrections"]), bc
    assert all("signature_after" in r for r in doc["rounds"] if r is not doc["rounds"][-1] or doc["effects_added"])
    # the search did not stop with a candidate that hurt in the round before untried (fd7f278 stopped with
    # drivetrain_compliance and direction_friction skipped here); the retry round says what it fitted
    assert _untried_at_stop(doc) == [], doc["rounds"][-1]
    write_trace_folder(tmp_path, res)
    html = (tmp_path / "report.html").read_text()
    assert ">Conclusion</h2>" in html and "<table>" in html and "base correction" in html
    assert "held-out chi2 drops" in html and "signature of the remaining residual" in html


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ALL_RUNS)
def test_the_segments_interval_is_never_narrower_and_stays_in_the_physical_range(traced, name):
    """Every found effect's final value with a segment-clustered standard error (stderr_segments) has an interval
    over the segments (ci95_segments) that holds its information interval (ci95) within the physical range, and
    the report says it where the segments spread it more than twice (report.trace._segments_text)."""
    from thsa_control.report.trace import SEGMENTS_WIDER, _segments_text

    doc = traced(name)
    for e in doc["effects_added"]:
        if e.get("implied_by"):
            continue
        lines = " ".join(_segments_text(e))
        for n, p in (e.get("parameters_final") or e["parameters"]).items():
            if p.get("stderr_segments") is None or not p.get("ci95"):
                continue
            lo, hi = p["ci95_segments"]
            tol = 1e-12 * abs(p["value"])
            assert lo <= p["value"] <= hi and hi >= p["ci95"][1] - tol, (n, p)
            assert lo <= p["ci95"][0] + tol or lo == 0.0, (n, p)  # or cut at a zero lower bound
            assert (n in lines) == (p["stderr_segments"] > SEGMENTS_WIDER * p["stderr"]), (n, p, lines)


@pytest.mark.campaign
@pytest.mark.slow
@pytest.mark.parametrize("name", ALL_RUNS)
def test_every_harmonic_left_out_at_the_segment_rate_is_tested_on_the_second_grid_or_said_not_tested(traced, name):
    """An angle test's harmonics in step with the fit segments are tested on a second grid (the final model's
    segment states on segments of another length, where they are not in step), and what neither grid tests is listed
    under not_tested: no harmonic is silently untested, and one the second grid tests is not listed."""
    sig = traced(name)["residual_signature"]
    said = {(d["variable"], h) for d in sig["not_tested"] if d.get("harmonics") for h in d["harmonics"]}
    for t in sig["tests"]:
        hs = t.get("segment_rate_harmonics") or []
        if not hs or t["remainder"] != "structured":
            continue
        chk = t["segment_rate_check"]
        assert abs(chk["segment_s"] / sig["second_grid"]["segment_s"] - 1.0) < 1e-9
        tested = set(chk.get("harmonics") or [])
        for h in hs:
            assert (h in tested) != ((t["variable"], h) in said), (t["variable"], h, chk, sig["not_tested"])
        assert t["significant"] or not chk.get("significant"), chk  # a significant check flags the test
        if chk.get("significant"):
            assert t["flagged_by"].startswith("harmonic")


@pytest.mark.campaign
@pytest.mark.slow
def test_the_segments_interval_of_the_compliance_damping_is_wider_and_holds_rigsims(traced):
    """rig-sim's drive-train compliance over position steps (rig_drivetrain_compliance_steps).  While the base's own
    load path was refused ("no parameter determined": the load path is linear there) the final damping was 2.51
    N m s/rad with an information interval of +-0.30 that missed rig-sim's 2; with the load path in (its clearance
    held) it is 2.24 +-0.27, which holds 2.  Over the record's segments the standard error is still more than twice
    the information's (the steps' starts and stops carry the damping: the residual the rig's base leaves is
    structured), and the interval the segments support holds rig-sim's 2 (docs/trace_notes.md, "The interval the
    segments support")."""
    name = "rig_drivetrain_compliance_steps"
    d_true = _truth(name)["effects"]["drivetrain_compliance"]["params"]["d_Nm_s_rad"]["si"]
    doc = traced(name)
    assert "loadpath_compliance" in [e["name"] for e in doc["effects_added"]]
    step = next(e for e in doc["effects_added"] if e["name"] == "drivetrain_compliance")
    p = step["parameters_final"]["gear.torsional_damping"]
    assert p["ci95"][0] <= d_true <= p["ci95"][1], p
    assert p["stderr_segments"] > 2.0 * p["stderr"] and p["ci95_segments"][0] <= d_true <= p["ci95_segments"][1], p


@pytest.mark.campaign
@pytest.mark.slow
def test_a_pawl_records_direction_step_is_no_harmonic_at_the_segment_rate(traced):
    """rig-sim's pawl backlash on the trim (rig_ratchet_backlash, 15 mm/s both ways): after the fit the two
    directions' missing torques sit a few mN m apart, and the angle test's samples are a comb at the segment rate
    (the missing torque is NaN near every segment's edges), 16 per screw revolution at this speed, so against the
    mean alone the step put 5.3 mN m on the screw angle's 16th harmonic, the largest of the 24 (a blind pawl
    record was flagged at that harmonic).  Given a level per direction (signature_tests ``levels``) that harmonic
    holds what its neighbours hold."""
    name = "rig_ratchet_backlash"
    doc = traced(name)
    run = read_run(DATA / f"{name}.csv")
    cmd = np.abs(np.asarray(run.signals["speed_cmd"], float))
    speed = float(np.median(cmd[cmd > 0.5 * cmd.max()]))  # the trim speed [m/s]
    h = round(run.screw_lead / (speed * doc["settings"]["segment_duration"]))
    assert h == 16
    test = next(t for t in doc["residual_signature"]["tests"] if t["variable"] == "screw_angle")
    amps = np.asarray(test["harmonic_amplitudes"], float)
    others = np.delete(amps, h - 1)
    assert amps[h - 1] < 2.0 * float(np.median(others)), (amps[h - 1], float(np.median(others)))
    assert test["dominant_harmonic"] != h
    assert test["given_levels"] >= 2
    # that harmonic is tested on the second grid (segments about a third longer, where it is not in step): nothing
    # there either, and the record no longer lists it as not tested
    chk = test["segment_rate_check"]
    assert test["segment_rate_harmonics"] == [h] and chk["harmonics"] == [h], chk
    assert abs(chk["segment_s"] / doc["settings"]["segment_duration"] - 1.0) > 0.2
    assert not chk["significant"] and chk["amplitudes"][0] < 2.0 * float(np.median(others)), chk
    assert not any(d["test"].startswith("screw_angle at harmonic") for d in doc["residual_signature"]["not_tested"])
