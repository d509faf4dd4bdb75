"""What a fit leaves: the remaining residual's signature and its errors by regime (numerics only).

Owns the assembly of a fit's residual signature (the missing torque at the motor shaft tested against
the operating variables, the sensors' consistency, :func:`_signature`, with the data of the report's
signature plots, :func:`_signature_curves`) and the per-regime channel errors (:func:`_regime_errors`).
The statistical tests themselves are :mod:`thsa_control.trace.signature`'s.  Used by
:mod:`thsa_control.trace.engine`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from ..data.rigdata import (RigRun, drive_on, measured_motor_speed, motion_sign, motor_speed_from, speed_integral,
                            stop_band)
from ..data.rigformat import speed_sensor_delays
from ..fit.residuals import quadrant, reversal_proximity
from ..model.laws import kinematic_ratio, torque_constant
from ..model.params import ParameterSet
from .candidates import ANGLE_HARMONIC, ANGLE_OF, CANDIDATES, PERIODS
from .scoring import _rms_by_channel
from .signature import (
    MIN_DRIVE_OFF_SAMPLES,
    MIN_HOLD,
    TORQUE_CONSTANT,
    SignatureSettings,
    angle_test_samples,
    base_transients,
    breakaway_events,
    breakaway_position_test,
    current_noise,
    binned_mean,
    cross_correlation,
    command_level,
    current_drift_test,
    current_offset_test,
    drift_test,
    harmonics_test,
    hold_drift_test,
    hold_samples,
    missing_torque,
    one_pass_bump_test,
    position_local_test,
    remainder_kind,
    second_grid_ratio,
    segment_rate_harmonics,
    segment_torques,
    sensor_consistency,
    sg_derivative,
    signature_tests,
    still_band,
    time_or_position_test,
)


def hold_drift_of_runs(runs: Sequence[RigRun], s: SignatureSettings | None = None,
                       transients: Mapping[str, np.ndarray] | None = None) -> dict | None:
    """:func:`~thsa_control.trace.signature.hold_drift_test` over the holds of ``runs`` (one after another in time,
    a gap between runs ending every hold): the load reading where the physics holds the load, the LVDT as the
    structure's witness, the compliance from the held samples where the load changes.  From the records alone (no
    fit), at the tracer's sample-based level ``s.alpha``; None when no run has a hold.  ``transients``: run name ->
    its :func:`~thsa_control.trace.signature.base_transients` at ``s.transient_time``, where the caller has them."""
    s = s or SignatureSettings()
    cols: dict[str, list] = {"t": [], "f": [], "x": [], "held": [], "still": []}
    t_offset = 0.0
    for run in runs:
        w = measured_motor_speed(run)
        if w is None:
            continue
        t = np.asarray(run.time, float)
        f = np.asarray(run.signals["load_force"], float)
        cmd = np.asarray(run.signals["speed_cmd"], float)
        band = still_band(w, cmd)
        held = hold_samples(t, w, f, cmd, transient_time=s.transient_time, band=band,
                            transients=(transients or {}).get(run.name))
        # held with the load changes included: the structure's compliance
        still = (cmd == 0) & (np.abs(np.nan_to_num(np.asarray(w, float))) <= band)
        x = np.asarray(run.signals["nut_position"], float) if "nut_position" in run.source_columns \
            else np.full(t.size, np.nan)
        for k, v in (("t", t - t[0] + t_offset), ("f", f), ("x", x), ("held", held), ("still", still)):
            cols[k] += [v, np.zeros(1, bool) if k in ("held", "still") else np.full(1, np.nan)]
        t_offset += float(t[-1] - t[0]) + 1.0
    if not cols["t"]:
        return None
    c = {k: np.concatenate(v) for k, v in cols.items()}
    c["t"] = np.where(np.isfinite(c["t"]), c["t"], 0.0)
    x = c["x"] if np.isfinite(c["x"][c["held"]]).all() and c["held"].any() else None
    return hold_drift_test(c["t"], c["f"], x, c["held"], alpha=s.alpha, compliance_samples=c["still"])


def breakaway_of_runs(runs: Sequence[RigRun], s: SignatureSettings | None = None) -> dict | None:
    """:func:`~thsa_control.trace.signature.breakaway_position_test` over the starts and reversals of ``runs`` (one
    rig: the events of all runs are compared by class), each run's events with its own current noise.  From the
    records alone: the current is the model's input, so the fit leaves no residual in it; the drive's breakaway
    current at a start against the same kind of start elsewhere is the worn spot's trace (at ``s.local_alpha`` where
    replicate events measured the scatter, ``s.alpha`` where none did).  Each event carries the
    housing temperature at it, so a cold run's starts are not compared with a warm run's (within
    ``s.temperature_span``).  Places apart by more than the position test's bin.  None where no class of events is
    seen at two places."""
    s = s or SignatureSettings()
    events = []
    for run in runs:
        w = measured_motor_speed(run)
        if w is None or not {"nut_position", "motor_current"} <= set(run.source_columns):
            continue
        sig = run.signals
        cn = current_noise(run.time, w, sig["load_force"], sig["motor_current"], transient_time=s.transient_time)
        if cn is None:
            continue
        t_run = np.asarray(run.time, float)
        temp_run = np.asarray(sig["temperature"], float)

        def temp_at(te, t_run=t_run, temp_run=temp_run):
            """the housing temperature at an event (NaN where it is not read): its class's temperature"""
            v = temp_run[int(np.clip(np.searchsorted(t_run, te), 0, t_run.size - 1))]
            return float(v)

        for e in breakaway_events(run.time, w, sig["load_force"], sig["speed_cmd"], sig["nut_position"],
                                  sig["motor_current"], transient_time=s.transient_time):
            events.append({**e, "run": run.name, "noise": cn[0], "iact": cn[1], "temperature": temp_at(e["time"])})
    return breakaway_position_test(events, place_gap=s.position_bin, alpha=s.local_alpha,
                                   temperature_gap=s.temperature_span, sample_alpha=s.alpha)

def amps_per_newton(params: ParameterSet, lead: float, gear_ratio: float) -> float:
    """The motor current one newton of nut load needs through a lossless drive: ``lead / (2 pi N Kt)`` (the laws'
    :func:`~thsa_control.model.laws.kinematic_ratio` of the run's kinematics over the file's
    :func:`~thsa_control.model.laws.torque_constant`): the scale of a load difference in current; efficiencies change
    it by tens of per cent, not its order."""
    return kinematic_ratio({"screw.lead": lead, "gear.ratio": gear_ratio}) / torque_constant(params)


def current_drift_of_runs(runs: Sequence[RigRun], params: ParameterSet, s: SignatureSettings | None = None) -> dict | None:
    """:func:`~thsa_control.trace.signature.current_drift_test` over ``runs`` (each run its own group: passes are
    compared within a run, whose clock is one), from the records alone, at the sample-based level ``s.alpha`` (its
    errors are IACT-corrected sample counts); None when no run has comparable passes.  The runs are joined end to end
    (a 1 s gap), each run's passes found on its own samples (``group``).  None without a parameter set ``params``
    (a signature assembled without a model: the load tolerance needs the file's torque constant)."""
    s = s or SignatureSettings()
    if params is None:
        return None
    cols: dict[str, list] = {k: [] for k in ("t", "i", "w", "f", "cmd", "x", "temp", "on", "g")}
    t_offset = 0.0
    apn = None
    for k, run in enumerate(runs):
        w = measured_motor_speed(run)
        if w is None or "motor_current" not in run.source_columns or "nut_position" not in run.source_columns:
            continue
        t = np.asarray(run.time, float)
        cmd = np.asarray(run.signals["speed_cmd"], float)
        on = drive_on(run)
        apn = amps_per_newton(params, run.screw_lead, run.gear_ratio)
        for key, v in (("t", t - t[0] + t_offset), ("i", run.signals["motor_current"]), ("w", w),
                       ("f", run.signals["load_force"]), ("cmd", cmd), ("x", run.signals["nut_position"]),
                       ("temp", run.signals["temperature"]), ("on", on), ("g", np.full(t.size, float(k)))):
            cols[key].append(np.asarray(v, float))
        t_offset += float(t[-1] - t[0]) + 1.0
    if apn is None:
        return None
    c = {k: np.concatenate(v) for k, v in cols.items()}
    return current_drift_test(c["t"], c["i"], c["w"], c["f"], c["cmd"], c["x"], c["temp"], c["on"] > 0.5, c["g"],
                              amps_per_newton=apn, transient_time=s.transient_time, alpha=s.alpha,
                              temperature_span=s.temperature_span)


# ----------------------------------------------------------------------------- signature
def _signature(fit: dict, runs: Sequence[RigRun], params: ParameterSet, plant, s: SignatureSettings,
               noise: Mapping[str, float] | None = None, speed_sensors: Mapping[str, object] | None = None,
               harmonics_only: Mapping[str, Sequence[int]] | None = None) -> dict:
    """The residual signature of ``fit`` (its predictions of ``runs``): the tests, the sensors, what was not tested,
    the report's curves.  Where an angle test leaves harmonics out because they are in step with the fit's segments,
    ``second_grid`` names a segment length on which they are not (:func:`~thsa_control.trace.signature.
    second_grid_ratio`).  ``harmonics_only`` (angle name -> harmonics): the angle tests of those harmonics alone on
    this fit (:func:`~thsa_control.trace.signature.harmonics_test`; a fit of the same model on that second grid),
    returned as ``{"harmonics_only": {name: test or None}}`` and nothing else."""
    inertia = plant.inertia(params)[1]  # the signature's missing torque at the motor shaft (what the current drives)
    torque: list = []
    vars_: dict = {}
    spans: dict[str, float] = {}  # the largest motor and screw angle spanned by one run's steady samples [rad]
    local_in: dict[str, list] = {"e": [], "x": [], "d": []}
    steady: list = []  # outside the base's transients, per run
    steady_local: list = []  # the position tests' samples, per run (:func:`_load_ramp_steady`)
    transients: dict = {}  # run name -> the base's transients (the load-cell hold test's too)
    drift_in: list = []  # (time, segment torque, direction, speed command)
    drift_at: list = []  # (nut position, run and command group) of each drift segment: time told from position
    drift_groups: dict = {}  # (run number, speed command) -> group number
    drift_off_command = 0  # steady segments in motion left out of the drift tests: the speed command not constant
    accel: list = []  # J x the measured motor acceleration, per run
    levels: list = []  # the group of each sample (run, direction of motion, sign of the load), per run
    cycles: dict[str, list] = {}  # angle -> its revolutions per multiple-shooting segment at each sample, per run
    phase: list = []  # each sample's place in its segment (0..1), per run
    t_run: list = []  # each sample's time from its run's first sample [s], per run (the segments start there)
    seg_lens: list = []  # each run's segment length [s]
    t_offset = 0.0
    for run in runs:
        pr = fit["predictions"][run.name]
        n = len(run.time)
        meas, sim = pr["measured"], pr["simulated"]
        # the speed error at the motor shaft, by the rule of a run's motor speed
        e = motor_speed_from(lambda c: (np.asarray(meas[c]) - np.asarray(sim[c]))[:n] if c in meas else None,
                             run.gear_ratio)
        if e is None:
            continue
        t = np.asarray(run.time, float)
        starts = np.searchsorted(t, pr["segment_starts"])
        torque.append(missing_torque(t, e, starts, inertia, s.window))
        w = np.nan_to_num(measured_motor_speed(run))
        dt = np.r_[np.diff(t), 0.0]
        angle = speed_integral(t, w)
        load = np.asarray(run.signals["load_force"], float)
        # outside the base's transients: the samples the pass-replicated position test uses; the angle tests use
        # the samples outside its starts, stops, reversals, load changes and sustained speed changes (a periodic
        # torque's own speed ripple is not a transient: ``sustained``)
        transients[run.name] = base_transients(t, w, load, s.transient_time)
        steady.append(~transients[run.name])
        # the position tests' samples: on a record whose load ramps through the motion (an elastic surface, a load
        # sweep) every moving sample is within 0.3 s of a load change, so there a steady ramp of the load is no
        # transient, only a change of its rate is (``load_steps``, as the candidates' scoring has it)
        steady_local.append(_load_ramp_steady(t, w, load, steady[-1], s))
        # the angle tests' samples likewise: on such a run the plain mask left none, so an angle's harmonics were
        # tested on every sample, starts and stops included, and their remainder was "base" by the travel rule
        steady_angle = angle_test_samples(t, w, load, s.transient_time,
                                          load_steps=steady_local[-1] is not steady[-1])
        # the angle the steady samples span; under two revolutions the harmonics are not told from a dependence on
        # position (below) and a Fourier series on less than a revolution is degenerate: the test then keeps every
        # sample, for the report only (its remainder is "base")
        steady_span = float(np.ptp(angle[steady_angle])) if steady_angle.any() else 0.0
        tested = {}  # angle variable -> (its samples, the angle its steady samples span)
        for name, a in (("motor_angle", angle), ("screw_angle", angle / run.gear_ratio)):
            span = steady_span / (run.gear_ratio if name == "screw_angle" else 1.0)
            tested[name] = (np.where(steady_angle, a, np.nan) if span >= 4 * math.pi else a, span)
        dv = stop_band(w)
        load_band = max(0.02 * float(np.max(np.abs(load))), 1.0)  # an unloaded sample: the quadrant's 0
        on = drive_on(run)
        cols = {
            "quadrant": ("category", quadrant(w, load, (dv, load_band))),
            "motor_on": ("category", on.astype(float)),
            "temperature": ("quantile", np.asarray(run.signals["temperature"], float)),
            "time_since_reversal": ("quantile", np.minimum(reversal_proximity(t, w, deadband=dv), 10.0)),
            "nut_position": ("position", np.asarray(run.signals["nut_position"], float)
                             if "nut_position" in run.source_columns else np.full(n, np.nan)),
            # periodic in angle: on the samples outside the base's transients only (``steady_angle``).  A run whose
            # passes start and end at the same nut positions (reversals, trim stops) puts every start, stop and
            # reversal at the same motor angle, so the transient residual a declared model of another rig's base
            # leaves there projects coherently on the angle harmonics and is replicated by every pass (a fresh
            # reversal null: 88 % of the first harmonic's projection from the 55 % of samples within 0.3 s of a
            # reversal, p 4e-8 on all samples, p 1 outside them).  A cogging or ripple acts on every revolution.
            "motor_angle": ("angle", tested["motor_angle"][0]),
            "screw_angle": ("angle", tested["screw_angle"][0]),
            "speed_sign": ("category", motion_sign(w, dv).astype(float)),
            # a torque-constant error (torque against current); a slow drift is tested per pass below
            TORQUE_CONSTANT: ("linear", np.asarray(run.signals["motor_current"], float)),
        }
        # the rotor's measured acceleration torque, the nuisance of the torque-constant test (see signature_tests)
        accel.append(inertia * sg_derivative(w, s.window, float(np.median(np.diff(t)))))
        del dt
        for name, (_a, span) in tested.items():
            spans[name] = max(spans.get(name, 0.0), span)
        for name, (kind, v) in cols.items():
            vars_.setdefault(name, (kind, []))[1].append(np.asarray(v, float))
        # the angle tests' levels (signature_tests' ``levels``): one per run, direction of motion and sign of the
        # load, the pieces the no-back's and the constant-torque explainers' torques are constant on
        load_sign = np.where(np.abs(load) > load_band, np.sign(load), 0.0)
        levels.append(9.0 * len(levels) + 3.0 * (1.0 + np.asarray(cols["speed_sign"][1], float)) + 1.0 + load_sign)
        # each angle's revolutions per segment (signature_tests' ``segment_cycles``: its harmonics at the segment rate)
        seg_len = float(np.median(np.diff(pr["segment_starts"]))) if len(pr["segment_starts"]) > 1 else 0.0
        seg_lens.append(seg_len)
        for name, ratio in (("motor_angle", 1.0), ("screw_angle", run.gear_ratio)):
            cycles.setdefault(name, []).append(np.abs(w) * seg_len / (2 * math.pi * ratio))
        first = np.asarray(pr["segment_starts"], float)[np.maximum(np.searchsorted(starts, np.arange(n), side="right")
                                                                   - 1, 0)]
        phase.append((t - first) / seg_len if seg_len > 0 else np.full(n, np.nan))
        t_run.append(t - t[0])
        # the pass-replicated position test (runs separated by a gap that ends every pass), on the residual
        # outside the base's transients: a declared model whose base differs from the rig's leaves structure at
        # starts, stops, reversals and load changes, and a trim run starts and stops at the same positions
        gap = np.full(100, np.nan)
        local_in["e"] += [np.where(steady_local[-1], torque[-1], np.nan), gap]
        local_in["x"] += [cols["nut_position"][1], gap]
        # a slow drift: one torque per segment outside the base's transients while moving, passes per direction
        # at one constant speed command (unchanged conditions: a position loop's decaying command moves the speed,
        # and a speed-dependent remainder of the base with it); the passes are cut where the command changes, and
        # the position test's levels are per run and command
        sgn = cols["speed_sign"][1]
        cmd = np.asarray(run.signals["speed_cmd"], float)
        for a, b, tm, tq in segment_torques(t, e, starts, inertia):
            if sgn[a] != 0 and steady[-1][a:b].all() and np.all(sgn[a:b] == sgn[a]):
                level = command_level(cmd[a:b])
                if level is None:
                    drift_off_command += 1
                    continue
                drift_in.append((t_offset + tm, tq, float(sgn[a]), level))
                group = drift_groups.setdefault((len(torque), level), float(len(drift_groups)))
                drift_at.append((float(np.mean(cols["nut_position"][1][a:b])), group))  # position, run and command
        t_offset += float(t[-1] - t[0]) + 1.0  # runs one after another, separated by more than a pass gap
        local_in["d"] += [cols["speed_sign"][1], np.zeros(100)]
    if not torque:
        return {"missing_torque_rms": None, "tests": [], "sensors": []}
    e_all = np.concatenate(torque)
    variables = {n: (k, np.concatenate(v)) for n, (k, v) in vars_.items()}
    # the model's own periodic torques in an angle (an added ripple or cogging): the angle tests look beyond them
    own: dict[str, dict[str, int]] = {}
    for n in fit.get("effects", ()):
        if n in ANGLE_OF:
            own.setdefault(ANGLE_OF[n], {})[n] = ANGLE_HARMONIC[n](params)
    level_of = np.concatenate(levels)
    seg_cycles = {n: np.concatenate(c) for n, c in cycles.items()}
    seg_phase = np.concatenate(phase)
    if harmonics_only is not None:  # the second grid's tests of the harmonics the first could not test
        only = {}
        for name, hs in harmonics_only.items():
            v = variables[name][1]
            ok = np.isfinite(e_all) & np.isfinite(v)
            in_step = segment_rate_harmonics(v[ok], seg_cycles[name][ok], seg_phase[ok], s.harmonics, level_of[ok])
            only[name] = harmonics_test(e_all, v, hs, levels=level_of, settings=s,
                                        given_harmonics=sorted(set(own.get(name, {}).values()) | set(in_step)))
            if only[name] is not None:
                only[name]["in_step_here"] = [h for h in hs if h in in_step]
        return {"harmonics_only": only}
    tests = signature_tests(e_all, variables, unit="N m", settings=s,
                            given={TORQUE_CONSTANT: np.concatenate(accel)}, added=own,
                            levels=level_of, segment_cycles=seg_cycles, segment_phase=seg_phase)
    for t in tests:  # the angle tests' (the position test's below)
        for name, a in (t.get("added_shapes") or {}).items():
            _against_fitted(a, name, params, phase=False)
    xs = variables["nut_position"][1]
    # the model's own periodic drags (an added screw ripple): their shape misfitted is no effect the model lacks
    shapes = {n: PERIODS[n](params) for n in fit.get("effects", ()) if n in PERIODS}
    local = [np.concatenate(local_in[k]) for k in ("e", "x", "d")]  # (residual, position, direction)
    origin = float(np.nanmin(xs)) if np.isfinite(xs).any() else None  # the curves' bins
    loc = position_local_test(*local, bin_width=s.position_bin, alpha=s.local_alpha, origin=origin, shapes=shapes)
    if loc is not None:
        loc["unit"] = "N m"
        for name, a in (loc.get("added_shapes") or {}).items():
            _against_fitted(a, name, params)
        tests.insert(0, loc) if loc["significant"] else tests.append(loc)
    dr = drift_test(*(np.asarray(v) for v in zip(*drift_in)), alpha=s.local_alpha, min_r2=s.min_r2) \
        if drift_in else None
    if dr is not None:
        tests.insert(0, dr) if dr["significant"] else tests.append(dr)
        _time_or_position(dr, drift_in, drift_at, tests, s)
        if drift_off_command:
            dr["segments_off_command"] = drift_off_command
    one = None
    if loc is None:
        # no position crossed by two passes (a check record, a cold ramp, an excitation around one speed): a bump
        # along one pass against the record's own bins, a place or a moment
        one = one_pass_bump_test(*local, bin_width=s.position_bin, origin=origin, alpha=s.local_alpha)
        if one is not None:
            tests.insert(0, one) if one["significant"] else tests.append(one)
    bk = breakaway_of_runs(runs, s)
    if bk is not None:
        tests.insert(0, bk) if bk["significant"] else tests.append(bk)
    # said, not silent: neither position test ran
    sensors, not_tested = [], ([_position_not_tested(*local, s)] if loc is None and one is None else [])
    for run in runs:
        measured = {c: run.signals[c] for c in ("motor_speed", "screw_speed", "nut_position") if c in run.source_columns}
        # the redundant sensors' lag at the replicate-based level (signature.LAG_ALPHA), the chains' declared
        # difference quotients compensated
        for d in sensor_consistency(run.time, {**measured, "load_force": run.signals["load_force"]},
                                    gear_ratio=run.gear_ratio, lead=run.screw_lead, alpha=s.alpha,
                                    transient_time=s.transient_time, lag_alpha=s.local_alpha,
                                    delays=speed_sensor_delays(run, speed_sensors)):
            d["run"] = run.name
            sensors.append(d)
        on = drive_on(run)
        co = current_offset_test(run.signals["motor_current"], ~on, alpha=s.alpha)
        if co is not None:
            co["run"] = run.name
            sensors.append(co)
        elif "motor_current" in run.source_columns:
            # said, not silent: with the drive on throughout (a rig that keeps it energised at zero command) an offset
            # reads as a constant torque at the motor, which the constant-torque explainers share (measured on a blind
            # rig-sim record, --no-gating, 0.36 A planted: absorbed by the base corrections, nothing flagged)
            not_tested.append({"test": "motor_current with the drive off", "run": run.name,
                               "would_show": "a current-sensor offset",
                               "why": f"the drive is off on {int(np.count_nonzero(~on))} samples (fewer than "
                                      f"{MIN_DRIVE_OFF_SAMPLES}); with the drive on, an offset reads as a constant "
                                      "torque at the motor, which the constant-torque explainers share"})
    if dr is None and drift_off_command:
        # said, not silent: a record in motion only at a changing speed command (a position loop's steps)
        not_tested.append({"test": "time (slow drift)", "run": None,
                           "would_show": "a drifting sensor or torque constant in the missing torque",
                           "why": f"{drift_off_command} of the {drift_off_command + len(drift_in)} steady segments "
                                  "in motion are at a changing speed command (a position loop's); the test needs "
                                  "eight at one constant command, four of them in one pass: a speed-dependent "
                                  "remainder of the base trends in time wherever the speed does"})
    # an angle test's harmonics in step with the fit segments: a periodic torque there is not told from the grid
    seg = float(np.median([x for x in seg_lens if x > 0] or [0.0]))
    for t in tests:
        hs = t.get("segment_rate_harmonics") or []
        if hs:
            not_tested.append(_segment_rate_not_tested(t["variable"], hs, seg))
    # the load cell where the physics holds the load (drive stopped, nut held): a reading trending with time, which
    # the structure's deflection (LVDT) does not follow, is a drifting sensor (from the records alone)
    hd = hold_drift_of_runs(runs, s, transients)
    hold_curve = None
    if hd is None:
        not_tested.append({"test": "time (slow drift) of the load reading in the holds", "run": None,
                           "would_show": "a drifting load cell",
                           "why": f"no hold of the load of {MIN_HOLD:g} s or more (the drive stopped, the nut still, "
                                  "outside the base's transients)"})
    else:
        hold_curve = {**hd.pop("curve"), "slope": hd["slope"], "p_value": hd["p_value"], "significant": hd["significant"]}
        sensors.append(hd)
    # the current at one operating point (same direction, command, load and nut positions) drifting in proportion to
    # itself over the record: a torque constant that changes with the rotor's temperature (from the records alone; a
    # load-cell drift moves the load reading, not the current)
    cd = current_drift_of_runs(runs, params, s)
    if cd is not None:
        tests.insert(0, cd) if cd["significant"] else tests.append(cd)
    # which remainder each test describes: structure an unmodelled-but-declared base does not leave (local in
    # position over passes, periodic in angle, a drift, a torque-constant error, the sensors) or the regime
    # dependences such a base leaves (quadrant, motor on/off, time since a reversal, direction, position bins
    # not replicated over passes, temperature within a few kelvin: a proxy for time)
    t_span = float(np.nanmax(variables["temperature"][1]) - np.nanmin(variables["temperature"][1])) \
        if np.isfinite(variables["temperature"][1]).any() else 0.0
    for d in tests:
        d["remainder"] = remainder_kind(d, t_span, s)
        # periodic in an angle only where the same angle recurs at another position: a travel of less than two
        # revolutions bins the residual by position (the base's drags at the ends of a short stroke); the travel of
        # the samples outside the base's transients, which the test uses
        if d["variable"] in spans and spans[d["variable"]] < 4 * math.pi and d["remainder"] == "structured":
            d["remainder"] = "base"
            d["why_base"] = (f"{d['variable']} spans {spans[d['variable']] / (2 * math.pi):.2g} revolutions (< 2) "
                             "outside the base's transients: not told from a dependence on position")
    for d in sensors:
        d["remainder"] = "structured"
    # the harmonics an angle test left out at the segment rate: a segment length on which they are not in step
    comb = {d["variable"]: d["segment_rate_harmonics"] for d in tests
            if d.get("segment_rate_harmonics") and d["remainder"] == "structured"}
    second = None
    if comb and seg > 0:
        ok = np.isfinite(e_all)
        for name in comb:
            ok &= np.isfinite(variables[name][1])
        ratio_, still = second_grid_ratio({n: (variables[n][1][ok], seg_cycles[n][ok]) for n in comb}, comb,
                                          np.concatenate(t_run)[ok], seg, level_of[ok])
        second = {"segment_s": ratio_ * seg, "ratio": ratio_, "harmonics": comb, "in_step_there": still}
    ok = np.isfinite(e_all)
    ratio = {c: math.sqrt(v / n) for c, (v, n) in _holdout_chi2_and_count(fit, noise or {}).items() if n > 0}
    return {"residual": "missing torque at the motor shaft, J d(speed residual)/dt", "unit": "N m",
            "reflected_inertia": inertia, "missing_torque_rms": float(np.sqrt(np.mean(e_all[ok] ** 2))),
            "residual_to_noise": ratio, "max_noise_ratio": s.max_noise_ratio,
            "tests": tests, "sensors": sensors, "not_tested": not_tested,
            **({"second_grid": second} if second is not None else {}),
            # the nut-position curves in the position test's bins (narrower on short passes), so that they share them
            "curves": {**_signature_curves(e_all, variables, runs, s if loc is None else dataclasses.replace(
                           s, position_bin=loc["bin_width"]), np.concatenate(steady_local), level_of),
                       # the drift test's data: one torque per steady segment (runs one after another in time)
                       "segment_torque": {"time": [d[0] for d in drift_in], "torque": [d[1] for d in drift_in],
                                          "direction": [d[2] for d in drift_in],
                                          "speed_command": [d[3] for d in drift_in],
                                          "nut_position": [d[0] for d in drift_at]},
                       # the load-cell drift test's data: the load reading and the LVDT in the holds
                       "hold_load": hold_curve}}


def _segment_rate_not_tested(name: str, harmonics: Sequence[int], segment_s: float,
                             second_s: float | None = None) -> dict:
    """The ``not_tested`` entry of an angle test's harmonics in step with the ``segment_s`` fit segments (and, where
    a second grid was fitted, ``second_s``: still in step there; where its fit failed the first grid's entry stands)."""
    which = ", ".join(str(h) for h in harmonics)
    there = (f" and with the {second_s:.3g} s segments of the second grid" if second_s is not None else "")
    return {"test": f"{name} at harmonic{'s' if len(harmonics) > 1 else ''} {which}", "run": None,
            "variable": name, "harmonics": list(harmonics), "segment_s": segment_s,
            "would_show": f"a periodic torque at {which} per revolution",
            "why": f"in step with the {segment_s:g} s fit segments{there} at this record's speed (the tested samples "
                   "are a comb at the segment rate, and a pattern repeated in every segment is periodic there); "
                   "another --segment moves it"}


def _against_fitted(along: dict, name: str, params: ParameterSet, phase: bool = True) -> None:
    """What the residual holds along an added periodic drag's shape (:func:`position_local_test`'s ``added_shapes``:
    the residual times the direction against a cosine and a sine of the nut position over the period) compared with
    the drag as fitted (its cosine and sine parameters, the same angle ``2 pi x / period``): ``in_phase`` [N m] > 0
    where the model's drag is short of the rig's (less friction than measured, in its phase), < 0 where it is too
    large; ``fitted_amplitude`` its own.  For an angle test's ``added_shapes`` (``phase=False``) the fitted amplitude
    only: the test's angle is the motor speed's integral from the run's start, the effect's the nut position's."""
    spec = CANDIDATES.get(name)
    pair = [n for n in (spec.free if spec else ()) if spec.plausible.get(n) == "periodic" and n in params]
    if len(pair) != 2:
        return
    c, s = (params.value(n) for n in pair)
    amp = math.hypot(c, s)
    along["fitted_amplitude"] = amp
    if not phase:  # an angle test's angle starts at the run's start, the effect's at its nut position: no phase
        return
    # a friction the model lacks slows the motion: the missing torque opposes it, so times the direction it is < 0
    along["in_phase"] = -(along["cos"] * c + along["sin"] * s) / amp if amp > 0 else None


def _time_or_position(dr: dict, drift_in: list, drift_at: list, tests: list, s: SignatureSettings) -> None:
    """A significant per-pass drift on a record whose passes revisit positions: told from a dependence on the nut
    position (:func:`~thsa_control.trace.signature.time_or_position_test`).  Where position explains it and time
    does not, the drift is not significant (``superseded_by``) and the position test is reported instead: a
    stationary drag along the stroke is never a slow drift.  Where time explains it beyond position (the levels of
    same-direction passes at the same positions grow), the drift is significant even when the per-pass slopes are
    not (``flagged_by``): each test at the replicate-based level, so the drift's family-wise level is at most twice
    it.  Otherwise the separation is reported with the drift test (``time_or_position``) and changes nothing."""
    tm, tq, dirn = (np.asarray(v) for v in list(zip(*drift_in))[:3])  # (the speed command: the group in drift_at)
    pos, grp = (np.asarray(v) for v in zip(*drift_at))
    sep = time_or_position_test(tm, tq, dirn, pos, grp, alpha=s.local_alpha)
    if sep is None:
        return
    dr["time_or_position"] = {k: v for k, v in sep.items() if k not in ("variable", "kind", "unit", "significant")}
    if sep["verdict"] == "position" and dr["significant"]:
        dr["significant"] = False
        dr["superseded_by"] = sep["variable"]
        tests.remove(dr)
        tests.append(dr)
        tests.insert(0, sep)
    elif sep["verdict"] == "time" and not dr["significant"]:
        # the passes' levels at the same positions grow with time: a drift the per-pass slopes alone miss (a pass
        # of a reversal record is 0.6 s outside the transients; its slope's error falls as the duration^1.5)
        dr["significant"] = True
        dr["flagged_by"] = "time beyond position over revisited passes"
        tests.remove(dr)
        tests.insert(0, dr)


def _holdout_chi2_and_count(fit: dict, noise: Mapping[str, float]) -> dict:
    """Per channel: the held-out noise-weighted squared error and its sample count."""
    out: dict = {}
    for p in fit["predictions"].values():
        hold = np.asarray(p["holdout"], bool)
        for c, y in p["measured"].items():
            if c not in noise or not noise[c] > 0:
                continue
            e = (np.asarray(y) - np.asarray(p["simulated"][c]))[:hold.size]
            m = hold[:e.size] & np.isfinite(e)
            a, n = out.get(c, (0.0, 0))
            out[c] = (a + float(np.sum((e[m] / noise[c]) ** 2)), n + int(m.sum()))
    return out


def _position_not_tested(e, x, d, s: SignatureSettings) -> dict:
    """The ``not_tested`` entry of a record on which neither position test ran: how far its steady samples (outside
    the base's transients) travel in each direction, against what the tests need."""
    ok = np.isfinite(e) & np.isfinite(x) & (d != 0)
    travel = {label: float(np.ptp(x[ok & (d == sgn)])) if np.any(ok & (d == sgn)) else 0.0
              for label, sgn in (("extending", 1.0), ("retracting", -1.0))}
    said = ", ".join(f"{v * 1e3:.3g} mm {k}" for k, v in travel.items())
    return {"test": "nut_position (a place)", "run": None, "would_show": "a friction bump or a worn spot",
            "travel_m": travel,
            "why": f"the samples outside the base's transients span {said}: the pass-replicated test needs three "
                   f"positions crossed by two passes, the one-pass test {7 * s.position_bin * 1e3:g} mm of one "
                   "direction (seven bins)"}


#: a run whose load ramps through the motion: the plain transient mask leaves fewer than this share of the moving
#: samples that the ``load_steps`` mask leaves outside the base's transients
LOAD_RAMP_SHARE = 0.25


def _load_ramp_steady(t, w, load, steady, s: SignatureSettings) -> np.ndarray:
    """The position tests' samples of one run: ``steady`` (outside the base's transients), or, on a run whose load
    ramps through the motion, the samples outside the transients where only a change of the load's rate is one
    (:func:`~thsa_control.trace.signature.base_transients` with ``load_steps``).

    Measured on rig-sim's elastic surface (``spring_load_ramp``, 30 kN/s while moving) and load sweeps
    (``triangular_load_sweep``, ``check_load_sweep``): the plain mask leaves none of their moving samples, so the
    position tests had nothing to test (a 6 N m friction bump at the screw, 0.29 A in the current each way, was not
    flagged), where ``load_steps`` leaves 0.4 s of each spring pass and 4.4 s of the sweep."""
    moving = motion_sign(w, stop_band(w)) != 0
    plain = int(np.count_nonzero(steady & moving))
    ramp = ~base_transients(t, w, load, s.transient_time, load_steps=True)
    if plain >= LOAD_RAMP_SHARE * int(np.count_nonzero(ramp & moving)):
        return steady
    return ramp


def _signature_curves(e: np.ndarray, variables: dict, runs, s: SignatureSettings, steady: np.ndarray | None = None,
                      levels: np.ndarray | None = None) -> dict:
    """Binned residual against nut position and motor / screw angle, and the redundant sensors'
    cross-correlation: the data of the report's signature plots.

    The angle curves are of the residual less its level in each ``levels`` group (run, direction, load sign), as the
    angle tests see it (``given_levels``): binned by angle, a step between the directions' levels seen through the
    tested samples' comb draws a pattern at the segment rate that is no periodic torque (rig-sim's pawl record:
    a zigzag of +-4 mN m at 16 per screw revolution).

    The nut-position curve is also given per direction of motion on the samples outside the base's transients
    (``by_direction``: what the pass-replicated position test uses): a friction feature changes sign with the
    direction and cancels in the mean over both."""
    out: dict = {}
    x = variables["nut_position"][1]
    if np.isfinite(x).sum() > 50 and np.nanmax(x) - np.nanmin(x) >= 2 * s.position_bin:
        lo, hi = float(np.nanmin(x)), float(np.nanmax(x))
        edges = np.arange(lo, hi + s.position_bin, s.position_bin)
        out["nut_position"] = binned_mean(e, x, edges)
        d = variables["speed_sign"][1]
        keep = np.ones(e.size, bool) if steady is None else np.asarray(steady, bool)
        out["nut_position"]["by_direction"] = {
            label: binned_mean(np.where(keep & (d == sgn), e, np.nan), x, edges)
            for label, sgn in (("extending", 1.0), ("retracting", -1.0)) if np.any(keep & (d == sgn))}
    for name in ("motor_angle", "screw_angle"):
        a = np.asarray(variables[name][1], float)
        ea = np.asarray(e, float)
        if levels is not None:
            ok = np.isfinite(ea) & np.isfinite(a)
            lab = np.asarray(levels, float)
            ea = ea.copy()
            for g in np.unique(lab[ok]):
                m = ok & (lab == g)
                ea[m] -= float(np.mean(ea[m]))
        out[name] = binned_mean(ea, np.mod(a, 2 * math.pi), np.linspace(0, 2 * math.pi, 37))
        if levels is not None:
            out[name]["given_levels"] = True
    cc = {}
    for run in runs:
        t = np.asarray(run.time, float)
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
        sig = run.signals
        if "motor_speed" in run.source_columns and "screw_speed" in run.source_columns:
            cc[f"{run.name}: motor_speed vs gear_ratio x screw_speed"] = cross_correlation(
                sig["motor_speed"], run.gear_ratio * np.asarray(sig["screw_speed"], float), dt)
        if "motor_speed" in run.source_columns and "nut_position" in run.source_columns:
            x_ = np.asarray(sig["nut_position"], float)
            cc[f"{run.name}: LVDT rate vs lead/(2 pi N) x motor_speed"] = cross_correlation(
                np.r_[0.0, np.diff(x_)] / dt, kinematic_ratio({"screw.lead": run.screw_lead, "gear.ratio": run.gear_ratio})
                * np.asarray(sig["motor_speed"], float), dt)
    out["cross_correlation"] = cc
    i = variables[TORQUE_CONSTANT][1]
    if np.isfinite(i).sum() > 50 and np.nanmax(i) > np.nanmin(i):  # a torque-constant error: torque against current
        out["motor_current"] = binned_mean(e, i, np.unique(np.nanquantile(i, np.linspace(0, 1, 2 * s.quantile_bins + 1))))
    return out


def _regime_errors(fit: dict, runs: Sequence[RigRun]) -> dict:
    """RMS of each channel's error per regime (aiding/opposing/unloaded, motor on/off, temperature band)."""
    by_run = {r.name: r for r in runs}
    regimes: dict[str, Callable] = {}

    def quad(r, label):
        run = by_run[r]
        w = np.nan_to_num(np.asarray(run.signals["speed_cmd"], float))
        load = np.asarray(run.signals["load_force"], float)
        q = quadrant(w, load, (stop_band(w), max(0.02 * float(np.max(np.abs(load))), 1.0)))
        return q == label

    for label, name in ((1, "opposing"), (-1, "aiding"), (0, "unloaded_or_stopped")):
        regimes[name] = lambda r, p, label=label: quad(r, label)[:len(p["holdout"])]
    for val, name in ((1, "motor_on"), (0, "motor_off")):
        def on(r, p, val=val):
            run = by_run[r]
            m = drive_on(run)
            return (m if val else ~m)[:len(p["holdout"])]
        regimes[name] = on
    for lo, hi in ((-60, 0), (0, 40), (40, 80)):
        regimes[f"temperature_{lo}_{hi}C"] = lambda r, p, lo=lo, hi=hi: (
            (np.asarray(by_run[r].signals["temperature"]) >= lo) & (np.asarray(by_run[r].signals["temperature"]) < hi)
        )[:len(p["holdout"])]
    out = {}
    for name, fn in regimes.items():
        rms = _rms_by_channel(fit, fn)
        if any(math.isfinite(v) for v in rms.values()):
            out[name] = {c: (v if math.isfinite(v) else None) for c, v in rms.items()}
    return out

