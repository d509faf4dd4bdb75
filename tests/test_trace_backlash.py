"""The tracer finds the no-back's ratchet/pawl backlash (issue #11): a profiled pawl pitch.

The pawl clearance acts through a switch (engaged or not), so the pitch gets no gradient: it is profiled
(thsa_control.fit.profile), each value with segment clearances of its own (thsa_control.fit.segment_states).
The runs: short extensions against a 20 kN compressive load with the motors switched off between them
(the papers' trim stops): at each stop the load back-drives the screw through the clearance its
compressive-side pawl has left (the extension's screw travel modulo the pitch) until the pawl engages.
The truth's pitch (0.10 rad) is not the parameter file's (0.1496 rad, the papers' 8.57 deg).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from handcalc import RIG_NOISE

from thsa_control.data.rigdata import read_run
from thsa_control.errors import ParameterError
from thsa_control.fit.profile import OneStepScreen, profile_identify
from thsa_control.fit.virtual_rig import VirtualRig
from thsa_control.model import build_plant
from thsa_control.sim.scenarios import Scenario
from thsa_control.trace import TraceSettings, trace

NOISE = RIG_NOISE
TRUE_PITCH = 0.10  # rad at the screw; the parameter file says 0.1496
PITCH = "noback.pawl_pitch"
INITIAL = "noback.pawl_initial_clearance"  # fraction of the pitch; the parameter file says 0.5
DISTRACTORS = ("coulomb_friction", "force_offset", "direction_friction")


def _stops_scenario() -> Scenario:
    """+6 mm/s extensions of 0.13-0.29 s against 20 kN (compressive: opposing), motors off for 0.35 s between."""
    points, t = [(0.0, 0.0)], 0.2
    for dur in (0.17, 0.23, 0.13, 0.29, 0.19):
        points += [(t, 6e-3), (t + dur, 0.0)]
        t += dur + 0.35
    return Scenario("trim_stops_20kN", "short extensions against 20 kN, motors off in the stops (back-drive "
                    "through the pawl clearance)", round(t, 3), tuple(points), 0.1, ((0.0, 0.0), (0.15, 20e3)))


@pytest.fixture(scope="module")
def stops_record(tmp_path_factory, params, rig_1khz):
    """``stops_record(level, seed)`` -> RigRun of the stops scenario, truth pitch 0.10 rad, memoised."""
    rig = rig_1khz
    d = tmp_path_factory.mktemp("backlash")
    cache = {}

    def _record(level="C", seed=1, initial=None):
        if (level, seed, initial) not in cache:
            stem = d / f"stops_{level}_{seed}_{initial}".replace(".", "p")
            truth = params.replace({PITCH: TRUE_PITCH, **({INITIAL: initial} if initial is not None else {})})
            VirtualRig(level, params=truth, design=rig, noise=NOISE, seed=seed,
                       truth_columns=True).record(_stops_scenario(), stem)
            cache[level, seed, initial] = read_run(stem.with_suffix(".csv"))
        return cache[level, seed, initial]

    return _record


def test_the_stops_back_drive_through_the_pawl_clearance(stops_record):
    """The record shows the effect: with the backlash each motor-off stop back-drives the screw (less than a
    pitch at the screw), without it the no-back holds."""
    c, b = stops_record("C"), stops_record("B")
    off = np.asarray(c.extra["primary_energised"]) < 0.5  # truth column: the inverter off
    assert off.sum() > 1000
    w_c, w_b = np.asarray(c.signals["motor_speed"]), np.asarray(b.signals["motor_speed"])
    assert np.min(w_c[off]) < -50.0  # rad/s: back-driven in the stops
    assert np.min(w_b[off]) > -2.0  # held: never back-driven (noise 0.2 rad/s)
    depth = (np.max(np.asarray(b.signals["nut_position"]) - np.asarray(c.signals["nut_position"])))
    lead = c.screw_lead
    assert 0 < depth < 5 * TRUE_PITCH * lead / (2 * np.pi)  # a few stops' back-drive, each below one pitch


def test_segment_clearances_follow_the_truth_at_the_true_pitch(stops_record, params):
    """The clearance the identification gives each segment (the model's own map driven by the measured speed)
    follows the simulated truth's clearance, and the one-step screen's best pitch is the truth's."""
    from thsa_control.fit.replay import current_driven_map, mech_inputs, sample_periods
    from thsa_control.fit.segment_states import (
        custom_state_track,
        measured_state_matrix,
    )

    run = dataclasses.replace(stops_record("C"), controller=None)
    truth = params.replace({PITCH: TRUE_PITCH})
    plant = build_plant("C", params=truth)
    X = measured_state_matrix(run, plant, truth)
    track = custom_state_track(plant, current_driven_map(plant), X, mech_inputs(run), sample_periods(run),
                               plant.p_vector(truth))
    for k, side in enumerate(("comp", "tens")):
        true_c = np.deg2rad(np.asarray(run.extra[f"pawl_clearance_{side}_deg"], float))  # truth column
        err = np.abs(track[k] - true_c)
        err = np.minimum(err, TRUE_PITCH - err)  # a wrap one sample apart is the same tooth
        assert np.mean(err < 0.005) > 0.99, (side, float(np.max(err)))
    screen = OneStepScreen([run], plant, params)
    grid = np.linspace(0.06, 0.16, 201)
    chi2 = [screen.chi2(params.replace({PITCH: float(v)})) for v in grid]
    assert grid[int(np.argmin(chi2))] == pytest.approx(TRUE_PITCH, rel=0.01)


def test_clearance_window_is_the_first_pitch_after_each_change_of_direction():
    """The backlash acts within one pitch of screw travel after the screw changes direction: the first motion,
    a back-drive after a stop; not a restart in the back-drive's direction once past the pitch, not a lone noise
    spike, not the rotors ringing while the screw sensor shows the screw held."""
    from pathlib import Path

    from thsa_control.data.rigdata import RigRun
    from thsa_control.trace.candidates import clearance_window

    fs, n_ratio = 500.0, 65.61
    t = np.arange(0.0, 4.0, 1 / fs)
    ws = np.zeros_like(t)
    ws[(t >= 0.5) & (t < 1.5)] = 2.0     # extension, 2 rad of screw travel
    ws[(t >= 2.0) & (t < 2.2)] = -1.0    # back-driven by the load, 0.2 rad
    ws[(t >= 2.6) & (t < 3.4)] = -2.0    # retraction: the same direction as the back-drive
    ws = ws + 0.01 * np.random.default_rng(3).standard_normal(t.size)
    ws[np.argmin(np.abs(t - 1.8))] = 0.5  # one noise spike while still
    w = n_ratio * ws
    ring = (t >= 2.2) & (t < 2.5)        # the rotors ring on the drive train while the screw is held
    w[ring] += 5.0 * np.sin(2 * np.pi * 48 * t[ring])
    cols = {"screw_speed": "screw_speed_rpm", "motor_speed": "motor_speed_rpm"}
    run = RigRun("synthetic", Path("synthetic.csv"), Path("synthetic.json"), {}, t,
                 {"screw_speed": ws, "motor_speed": w, "load_force": np.full(t.size, 2e4)}, gear_ratio=n_ratio,
                 source_columns=cols)
    win = clearance_window(run, 0.3)

    def spans(m):
        return (float(t[m].min()), float(t[m].max())) if m.any() else None

    first = win & (t < 1.9)
    assert spans(first)[0] == pytest.approx(0.5, abs=0.01) and spans(first)[1] == pytest.approx(0.65, abs=0.01)
    assert win[(t >= 2.0) & (t < 2.2)].mean() > 0.95  # the back-drive (0.2 rad < 0.3)
    assert not win[(t > 1.7) & (t < 1.95)].any() and not win[ring].any()
    restart = win & (t >= 2.5)  # 0.1 rad of retraction makes up the 0.3 rad since the back-drive began
    assert spans(restart)[0] == pytest.approx(2.6, abs=0.01) and spans(restart)[1] == pytest.approx(2.65, abs=0.01)
    # without the screw sensor the motor speed over the gear ratio is read: the ringing is then motion too
    bare = dataclasses.replace(run, source_columns={"motor_speed": "motor_speed_rpm"})
    assert clearance_window(bare, 0.3)[ring].any()


def test_profiled_parameter_cannot_also_be_free(stops_record, params):
    with pytest.raises(ParameterError, match="both free and profiled"):
        profile_identify(stops_record("C"), params, (PITCH,), {PITCH: (0.03, 0.3)}, level="C")
    with pytest.raises(ParameterError, match="inside its bounds"):
        profile_identify(stops_record("C"), params, ("gear.viscous_friction",), {PITCH: (0.03, 5.0)}, level="C")
    with pytest.raises(ParameterError, match="holdout"):  # a held-out choice without held-out samples or noise
        profile_identify(stops_record("C"), params, ("gear.viscous_friction",), {PITCH: (0.03, 0.3)}, level="C",
                         score="holdout")


@pytest.mark.slow
def test_backlash_is_found_first_with_its_pitch(stops_record, params, capsys):
    """Level-C data (pitch 0.10 rad), declared level B: noback_backlash is added first among drive-friction
    and offset distractors, the motor-speed error falls by more than half, and the profiled pitch is within
    15 % of the truth with the profile in the result."""
    run = stops_record("C")
    res = trace(run, "B", params=params, settings=TraceSettings(candidates=("noback_backlash",) + DISTRACTORS,
                                                                 max_nfev=30, max_effects=1))
    doc = res.to_dict()
    assert res.effects_added == ["noback_backlash"], doc["rounds"]
    step = doc["effects_added"][0]
    red = step["error_reduction"]
    assert red["motor_speed"] >= 0.5, red
    pitch = step["parameters"][PITCH]
    assert pitch["profiled"] and pitch["value"] == pytest.approx(TRUE_PITCH, rel=0.15), pitch
    lo, hi = pitch["ci95"]
    assert lo <= pitch["value"] <= hi
    # five stops after different travels pick one tooth of the comb: the profile set is one range (fit.profile_set)
    assert PITCH not in {h["parameter"] for h in step["not_determined"]}, step["not_determined"]
    assert step["profile"]["determination"][PITCH]["determined"], step["profile"]["determination"]
    # the 301 values' tooth was narrower than their step: screened again densely, the tooth still one and at least
    # half the dense step wide (fit.profile.COMB_HIT)
    assert step["profile"]["determination"][PITCH]["comb_check"]["dense"], step["profile"]["determination"]
    prof = step["profile"]
    assert len(prof["screen"][PITCH]) > 100 and prof["fits"]
    best = min((f for f in prof["fits"] if "score" in f), key=lambda f: f["score"])
    assert best["values"][PITCH] == pitch["value"]
    # chosen on the training error (the fits' own objective); the held-out error is kept for the judgement only
    assert prof["chosen_by"] == "training_chi2" and pitch["chosen_by"] == "training_chi2", prof["chosen_by"]
    assert all(f["score"] == f["training_chi2"] and "holdout_chi2" in f for f in prof["fits"] if "score" in f)
    cand = next(c for c in doc["candidates"] if c["name"] == "noback_backlash")
    assert cand["window"] == "clearance" and cand["window_reduction"]["motor_speed"] >= 0.5
    with capsys.disabled():
        print(f"\nbacklash: pitch {pitch['value']:.5f} rad (truth {TRUE_PITCH}), interval {lo:.5f}..{hi:.5f}; "
              f"RMS drop {', '.join(f'{c} {v:.0%}' for c, v in red.items())}; "
              f"profiled candidate fit {cand['fit_time_s']:.1f} s")


@pytest.mark.slow
def test_initial_clearance_is_screened_as_an_angle_not_taken_up_by_the_pitch(stops_record, params):
    """Truth: pitch 0.10 rad, the ratchets stopped 0.2 pitch from their pawls (0.02 rad; the file's fraction is
    0.5).  The load's application back-drives through that angle before any travel, the five stops through the
    extensions' travel modulo the pitch.  Screened in the model's coordinates one after the other (the pitch at
    the file's fraction 0.5 first), the pitch took up the first back-drive (0.5 x pitch = its angle); screened as
    the angle first, both come out right."""
    from thsa_control.fit.identify import IdentificationSettings

    run = stops_record("C", 1, 0.2)
    free = ("gear.viscous_friction",)
    st = IdentificationSettings(max_nfev=20)
    prof = profile_identify(run, params, free, {PITCH: (0.03, 0.3), INITIAL: (0.0, 1.0)}, level="C", settings=st,
                            fractions={INITIAL: PITCH})
    assert prof.values[PITCH] == pytest.approx(TRUE_PITCH, rel=0.05), prof.values
    assert prof.values[INITIAL] * prof.values[PITCH] == pytest.approx(0.2 * TRUE_PITCH, abs=0.004), prof.values
    assert prof.mattered[INITIAL] and any("product" in n for n in prof.notes)
    with pytest.raises(ParameterError, match="fraction"):
        profile_identify(run, params, free, {PITCH: (0.03, 0.3), INITIAL: (0.0, 1.0)}, level="C", settings=st,
                         fractions={PITCH: INITIAL})


@pytest.mark.slow
def test_backlash_null_stays_null(stops_record, params, capsys):
    """Level-B data (no backlash) traced with level B: noback_backlash is not added (2 noise seeds)."""
    added = []
    for seed in (1, 2):
        res = trace(stops_record("B", seed), "B", params=params,
                    settings=TraceSettings(candidates=("noback_backlash", "coulomb_friction"), max_nfev=30,
                                           max_effects=1))
        added.append(res.effects_added)
        cand = next(c for c in res.to_dict()["candidates"] if c["name"] == "noback_backlash")
        assert not cand["significant"], cand
    with capsys.disabled():
        print(f"\nbacklash null (level B, trim stops, 2 seeds): added {added}")
    assert all("noback_backlash" not in a for a in added), added


def test_compiled_screen_and_track_equal_the_interpreter(stops_record, params):
    """The screen's compiled one-step loop (a whole grid in one call) and the segments' custom-state track give
    the interpreter's numbers to the last digit, also where a measured sample is missing (the compiled run
    stops there and the interpreter, which carries on past it, takes over)."""
    from thsa_control.fit.replay import current_driven_map, mech_inputs, sample_periods
    from thsa_control.fit.segment_states import custom_state_track, measured_state_matrix, one_step_map

    run = dataclasses.replace(stops_record("C"), controller=None)
    plant = build_plant("C", params=params)
    screen = OneStepScreen([run], plant, params)
    if screen.loop is None:
        pytest.skip("no working C compiler: the screen runs in casadi's interpreter only")
    sets = [params.replace({PITCH: float(v), "noback.pawl_initial_clearance": c})
            for v in (0.05, 0.1, 0.1496, 0.25) for c in (0.0, 0.5)]
    _, U, w_next, sigma, keep = screen.parts[0]
    interpreted = OneStepScreen([run], plant, params)
    interpreted.parts = [(one_step_map(plant, interpreted._mech, U.shape[1]), U, w_next, sigma, keep)]
    compiled = screen.chi2_many(sets)
    assert np.all(np.isfinite(compiled)) and np.ptp(compiled) > 0  # the pitch matters on this record
    np.testing.assert_array_equal(compiled, interpreted.chi2_many(sets))
    gap = U.copy()
    gap[0, U.shape[1] // 2] = np.nan  # a missing measured state: its prediction is not finite
    screen.parts = [(None, gap, w_next, sigma, keep)]
    interpreted.parts = [(one_step_map(plant, interpreted._mech, U.shape[1]), gap, w_next, sigma, keep)]
    np.testing.assert_array_equal(screen.chi2_many(sets), interpreted.chi2_many(sets))
    # the custom-state track through the compiled loop, against the interpreter's map
    mech = current_driven_map(plant)
    X = measured_state_matrix(run, plant, params)
    V, H, p = mech_inputs(run), sample_periods(run), plant.p_vector(params)
    track = custom_state_track(plant, mech, X, V, H, p)
    idx = [i for i, s in enumerate(plant.states) if s.name.startswith("pawl_clearance")]
    n = X.shape[1]
    Ufull = np.vstack([X[:, :-1], V[:, :n - 1], np.asarray(H, float)[None, :n - 1]])
    ref = np.asarray(one_step_map(plant, mech, n - 1)(X[idx, 0], Ufull, p)[0])
    np.testing.assert_array_equal(track[:, 1:], ref)


def test_the_screen_sums_the_training_samples_only(stops_record, params):
    """With the fit's hold-out, the one-step screen leaves the held-out segments' samples out of its sum (the pitch
    is then chosen where the fits are, and the held-out samples judge it): the same per-sample errors as the screen
    over every sample, restricted to the samples the fit trains on; the clearances are carried through the held-out
    segments from the measured speeds, so the kept samples' errors do not change."""
    from thsa_control.fit.identify import IdentificationSettings
    from thsa_control.fit.shooting import segment_layout

    run = dataclasses.replace(stops_record("C"), controller=None)
    plant = build_plant("C", params=params)
    st = IdentificationSettings(segment_duration=0.05, holdout_every=3)
    every, training = OneStepScreen([run], plant, params), OneStepScreen([run], plant, params, holdout=st)
    _, _, hold = segment_layout(run.time, st)
    kept = ~hold[1:run.time.size]
    assert 0 < training.n == int(kept.sum()) < every.n == run.time.size - 1
    sets = [params.replace({PITCH: float(v)}) for v in (0.05, 0.1, 0.1496)]
    for e_all, e_tr in zip(every._errors_many(sets), training._errors_many(sets)):
        np.testing.assert_array_equal(e_tr, e_all[kept])
    # the pitch still matters on the training samples of this record (five stops, some in training segments)
    assert np.ptp(training.chi2_many(sets)) > 0


def test_a_refit_from_a_fits_optimum_starts_at_its_predictions(stops_record, params):
    """The pawl clearances at the segment starts are not decision variables: they follow the model's map at the
    fit's initial values.  A refit of a fit's model on every segment (the tracer's final values) starts at that
    fit's predictions only with its segment states and its clearances (``initial_states``, ``custom_states``);
    with the clearances tracked again at the fitted values it starts elsewhere (rig_ratchet_backlash: 1.34e6
    against the search's 1.30e5, and the refit ended at 6.7e5).  A clearance array of another layout is named."""
    from thsa_control.fit.identify import IdentificationSettings, Identifier

    run = stops_record("C")
    free = ("gear.viscous_friction", "screw.efficiency_inverse")
    start = params.replace({PITCH: TRUE_PITCH, "gear.viscous_friction": 2.0 * params.value("gear.viscous_friction"),
                            "screw.efficiency_inverse": 0.7})
    s = IdentificationSettings(channels=("motor_speed", "nut_position"), noise=dict(NOISE), holdout_every=3)
    first = Identifier("C", start, free, settings=s).fit(run)
    assert first.custom_states[run.name].shape[0] == 2  # both pawls, every segment
    at = first.to_parameter_set()
    still = dataclasses.replace(s, holdout_every=0, max_nfev=0)
    warm = Identifier("C", at, free, settings=still).fit(run, initial_states=first.segment_states,
                                                         custom_states=first.custom_states)
    states_only = Identifier("C", at, free, settings=still).fit(run, initial_states=first.segment_states)
    for c in ("motor_speed", "nut_position"):
        a, b = first.predictions[run.name]["simulated"][c], warm.predictions[run.name]["simulated"][c]
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12 * np.max(np.abs(a)))
    moved = np.max(np.abs(np.asarray(states_only.predictions[run.name]["simulated"]["motor_speed"])
                          - np.asarray(first.predictions[run.name]["simulated"]["motor_speed"])))
    assert moved > 1.0, moved  # rad/s (measured 11.3): the stops back-drive through other clearances
    with pytest.raises(ValueError, match=f"custom_states\\['{run.name}'\\]: shape \\(2, 3\\)"):
        Identifier("C", at, free, settings=still).fit(run, custom_states={run.name: np.zeros((2, 3))})


def test_the_one_step_screen_compares_what_the_motor_speed_sensor_reads():
    """The one-step screen's predicted speed is the state the motor-speed sensor reads (segment_states.
    one_step_function: ``plant.sensor_state("motor_speed")``).  With a compliant drive train that is the rotors' speed;
    it was the gear output's, which a torque on the rotors does not move within one step, so the cogging period's
    screen was flat and held the period at its grid's first value (a rig-sim position loop with a cogging beside a
    drive-train compliance: 6 per revolution against rig-sim's 18).  On rig-sim's cogging record (check_slow, 18 per
    revolution) the screen with a compliant drive train declared picks 18, as the rigid one does."""
    from pathlib import Path

    from thsa_control.fit.kinematics import run_kinematics
    from thsa_control.model import resolve_effects
    from thsa_control.model.params import default_parameters

    params = default_parameters()
    run = run_kinematics(read_run(Path(__file__).parent / "data" / "rigsim" / "rig_cogging.csv"), params)
    amp = params.replace({"drive.cogging_torque_cos": 0.0, "drive.cogging_torque_sin": 0.05})
    for extra in ((), ("drivetrain_compliance",)):
        plant = build_plant(effects=resolve_effects("A", add=["cogging_torque", *extra]), params=amp)
        assert (plant.sensor_state("motor_speed") == "rotor_speed") == bool(extra)
        screen = OneStepScreen([run], plant, amp)
        counts = [6.0, 12.0, 18.0, 24.0, 36.0]
        chi2 = [screen.chi2(amp.replace({"drive.cogging_periods": c}),
                            solve=("drive.cogging_torque_cos", "drive.cogging_torque_sin")) for c in counts]
        assert counts[int(np.argmin(chi2))] == 18.0, (extra, chi2)
        # the count matters: the next best lies beyond the one-step chi-square's noise (176 rigid, 781 compliant;
        # the flat screen gave one value, 215169, for every count)
        assert sorted(chi2)[1] - min(chi2) > 100.0, (extra, chi2)
