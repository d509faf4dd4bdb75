"""Segmented open-loop replay: a residual that does not drift, and the missing torque of the inverse model.

A whole-run open-loop replay (:func:`~thsa_control.fit.replay.replay_open_loop`)
integrates the mechanics driven by the measured current from the first sample
to the last.  On a drive whose position integrates (a reversible screw
without a no-back, any plain positioning axis) every small torque error
integrates twice: the position residual grows with time and says more about
the run's length than about the model.

:func:`replay_segmented` cuts the run into segments of ``segment_duration``
and restarts the mechanics at the start of each from the measured state:
motor speed (or gear ratio x screw speed), nut position (the LVDT, the
surface at level D), the unmeasured states from a closed-loop replay under
the run's controller or at rest.  These are the multiple-shooting segments
of the identification, evaluated at the declared parameters with the
segments' initial states held at their measured values
(:class:`thsa_control.fit.shooting.RunProblem`: the same map, the same
initial states, no second simulator).  Each channel's residual is then the
one-segment prediction error: it is bounded by what the model misses within
one segment and does not drift.

The inverse-model residual ``missing_torque`` [N m, at the motor shaft] is
the torque the measured motion needs minus the torque the measured current
gives: ``J (d w_meas/dt - d w_pred/dt)``, with ``w_pred`` the segment
prediction driven by the same current (so the model's own friction, load and
drag at the segment's state are accounted for), the derivative a
Savitzky-Golay one inside each segment
(:func:`thsa_control.trace.signature.missing_torque`, the tracer's), and
``J`` the plant's reflected inertia at each sample,
``(d motor_torque / d i) / (d w_next / d i) * h``, differentiated through the
same current-driven map.  It appears as a residual channel whose "measured"
signal is the torque needed and whose "simulated" signal is the plant's
``motor_torque`` of the measured current.  A friction the model lacks shows
as ``-T sign(w)``: a negative missing torque while moving positively.  It is
NaN where the model sticks (no inertia to speak of), within half a
derivative window of a segment edge, and where the speed is not measured.

No file I/O, no matplotlib.
"""

from __future__ import annotations

import math
import time as _time
import warnings
from types import MappingProxyType

import casadi as ca
import numpy as np

from ..data.rigdata import RigRun, motor_speed_from
from ..errors import ThsaError, UsageError
from ..model.params import ParameterSet
from ..model.plant import Plant
from .replay import ReplayResult, channel_fit, check_run_model, compared_signals, current_driven_map

__all__ = ["DEFAULT_SEGMENT", "WHOLE_RUN", "parse_segment", "check_segment", "replay_segmented",
           "replay_for_residual", "MISSING_TORQUE"]

#: Default segment length [s]: the tracer's and the identification command's multiple-shooting segments.
DEFAULT_SEGMENT = 0.05
#: Value of ``--segment`` (and ``segment_duration=None``) for the whole-run open-loop replay.
WHOLE_RUN = "whole"
#: Name of the inverse-model residual channel [N m].
MISSING_TORQUE = "missing_torque"


def parse_segment(text) -> float | None:
    """``--segment`` value: a positive length [s], or ``whole`` / ``0`` for the whole-run replay (None).

    Raises
    ------
    UsageError
        Not a number, negative, not finite.

    Examples
    --------
    >>> parse_segment("0.05"), parse_segment("whole"), parse_segment("0")
    (0.05, None, None)
    """
    if text is None:
        return DEFAULT_SEGMENT
    s = str(text).strip().lower()
    if s == WHOLE_RUN:
        return None
    try:
        v = float(s)
    except ValueError:
        raise UsageError(f"--segment {text!r}: give a segment length in seconds (e.g. 0.05) or "
                         f"'{WHOLE_RUN}' (or 0) for the whole-run open-loop replay") from None
    if v == 0:
        return None
    if not (math.isfinite(v) and v > 0):
        raise UsageError(f"--segment {text!r}: the segment length must be a positive number of seconds "
                         f"(or '{WHOLE_RUN}' / 0 for the whole-run open-loop replay)")
    return v


def check_segment(run: RigRun, segment_duration: float) -> None:
    """Refuse a segment that is not positive, or longer than the run.

    Raises
    ------
    UsageError
        Naming the segment, the run and its duration.
    """
    t = np.asarray(run.time, float)
    duration = float(t[-1] - t[0]) if t.size > 1 else 0.0
    if not (isinstance(segment_duration, (int, float)) and math.isfinite(segment_duration) and segment_duration > 0):
        raise UsageError(f"segment {segment_duration!r} s: must be a positive number of seconds")
    dt = float(np.median(np.diff(t))) if t.size > 1 else math.inf
    if segment_duration > duration:
        raise UsageError(f"segment {segment_duration:g} s is longer than run {run.name!r} "
                         f"({duration:g} s); give a shorter --segment or '{WHOLE_RUN}'")
    if segment_duration < 2 * dt:
        raise UsageError(f"segment {segment_duration:g} s is shorter than two samples of run {run.name!r} "
                         f"(sample time {dt:g} s)")


def _effective_inertia_function(plant: Plant, mech: ca.Function) -> tuple[ca.Function, int]:
    """``(dT, dw)(x, v, p, h)``: motor torque and motor-sensor speed responses of one step of the current-driven
    map to a shift of the measured current, and the speed state the motor sensor reads.

    Their ratio is the inertia the measured motion sees through the map at each sample [kg m^2 at the motor
    shaft]: the plant's :meth:`~thsa_control.model.Plant.inertia` as the step resolves it, with the gearbox
    efficiency of the sample's power flow, and no response (NaN) while the model sticks.
    """
    names = plant.state_names
    k_w = names.index(plant.sensor_state("motor_speed"))
    x = ca.SX.sym("x", len(names))
    v = ca.SX.sym("v", mech.size1_in(1))
    p = ca.SX.sym("p", mech.size1_in(2))
    h = ca.SX.sym("h")
    xn, y = mech(x, v, p, h)
    # a constant shift of the measured current: both ends of the period (current_start, current_end)
    shift = ca.DM([1.0, 1.0] + [0.0] * (mech.size1_in(1) - 2))
    dw = ca.mtimes(ca.jacobian(xn[k_w], v), shift)
    dt = ca.mtimes(ca.jacobian(y[plant.index("output", "motor_torque")], v), shift)
    return ca.Function("reflected_inertia", [x, v, p, h], [dt * h, dw]), k_w


def replay_segmented(run: RigRun, plant: Plant, params: ParameterSet, *, segment_duration: float = DEFAULT_SEGMENT,
                     substeps: int = 1, window: int = 21) -> ReplayResult:
    """Replay the mechanics driven by the measured current, restarted from the measured state every segment.

    Parameters
    ----------
    run : RigRun
        Needs ``motor_current`` and one of ``motor_speed``, ``nut_position``,
        ``screw_speed``.
    plant : Plant
    params : ParameterSet
    segment_duration : float
        Segment length [s] (default :data:`DEFAULT_SEGMENT`).
    substeps : int
        Plant steps per sample period.
    window : int
        Savitzky-Golay window of the missing torque [samples] (reduced to
        half a segment when segments are short).

    Returns
    -------
    ReplayResult
        ``mode = "open_loop"``; ``simulated`` every plant output of the
        segment predictions; ``fits`` the measured mechanical channels and
        :data:`MISSING_TORQUE` (when the speed is measured); ``info`` has
        ``open_loop_replay = "segmented"``, ``segment_s`` (the length used,
        a whole number of samples), ``segments``, ``segment_starts_s``,
        ``reflected_inertia_median``.

    Raises
    ------
    UsageError
        Segment not positive, shorter than two samples or longer than the run.
    RigDataError
        No ``motor_current``, or no mechanical channel measured.
    ThsaError
        The segment predictions are not finite.
    """
    from .identify import IdentificationSettings, RunProblem
    from .replay import measured_signals
    from ..trace.signature import missing_torque

    check_segment(run, segment_duration)
    if not (isinstance(substeps, int) and substeps >= 1):
        raise UsageError(f"substeps {substeps!r}: must be an integer >= 1")
    for msg in check_run_model(run, plant, mode="open_loop"):
        warnings.warn(msg, stacklevel=2)
    t0 = _time.perf_counter()
    mech = current_driven_map(plant, substeps)
    settings = IdentificationSettings(segment_duration=float(segment_duration), substeps=substeps)
    pb = RunProblem(run, plant, mech, params, (), settings)
    p0 = plant.p_vector(params)
    X, Y = pb.f_pred_all(pb.initial_decision(), p0, np.zeros(0))
    t = np.asarray(run.time, float)
    n = t.size
    X, Y = np.asarray(X)[:, :n], np.asarray(Y)[:, :n]
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise ThsaError(f"segmented open-loop replay of {run.name!r} diverged (non-finite segment predictions)")
    simulated = {name: Y[i] for i, name in enumerate(plant.outputs)}
    measured = measured_signals(run)
    compared = compared_signals(run, simulated, [c for c in measured if c != "motor_current"])
    starts = np.arange(pb.M) * pb.L
    starts = starts[starts < n]
    info = {"open_loop_replay": "segmented", "segment_s": round(float(pb.L * np.median(np.diff(t))), 9),
            "segments": int(starts.size), "segment_starts_s": t[starts].tolist(), "substeps": substeps}

    # inverse model: the torque the measured motion needs minus the torque the measured current gives
    w_meas = motor_speed_from(measured.get, run.gear_ratio)
    if w_meas is not None:
        f_j, k_w = _effective_inertia_function(plant, mech)
        gain, dw = f_j.map(n)(X, pb.V[:, :n], ca.repmat(ca.DM(p0), 1, n), ca.DM(pb.H[:n]).T)
        gain, dw = np.asarray(gain).ravel(), np.asarray(dw).ravel()
        with np.errstate(divide="ignore", invalid="ignore"):
            inertia = np.where(np.abs(dw) > 1e-12 * np.maximum(np.abs(gain), 1e-300), gain / dw, np.nan)
        inertia[~(inertia > 0)] = np.nan  # stuck in the model (no speed response), or not a physical value
        w_pred = X[k_w]
        win = max(5, min(window, pb.L // 2))
        win = win if win % 2 else win - 1
        accel_error = missing_torque(t, w_meas - w_pred, starts, 1.0, win)  # d(w_meas - w_pred)/dt
        given = simulated["motor_torque"]
        need = given + inertia * accel_error
        if int(np.sum(np.isfinite(need))) >= 16:
            measured[MISSING_TORQUE] = need
            compared[MISSING_TORQUE] = np.asarray(given, float)
            info["reflected_inertia_median"] = float(np.nanmedian(inertia))
            info["missing_torque_window"] = win
        else:
            info["missing_torque_skipped"] = (f"fewer than 16 samples inside segments of {pb.L} samples with a "
                                              f"{win}-sample derivative window")
    fits = {c: channel_fit(c, measured[c], compared[c], unit="N m" if c == MISSING_TORQUE else None)
            for c in compared}
    info["wall_s"] = _time.perf_counter() - t0
    return ReplayResult(run.name, "open_loop", t, MappingProxyType(simulated), MappingProxyType(measured),
                        plant.effects, params, MappingProxyType(fits), info, MappingProxyType(compared))


def replay_for_residual(run: RigRun, plant: Plant, params: ParameterSet, mode: str, *,
                        segment_duration: float | None = DEFAULT_SEGMENT) -> ReplayResult:
    """The replay ``thsa residual`` analyses.

    ``mode = "closed_loop"``: under the run's controller
    (:func:`~thsa_control.fit.replay.replay_closed_loop`).  ``"open_loop"``:
    segmented (:func:`replay_segmented`) unless ``segment_duration`` is None,
    then the whole-run replay (:func:`~thsa_control.fit.replay.replay_open_loop`),
    whose ``info`` says ``open_loop_replay = "whole_run"``.

    Raises
    ------
    UsageError
        Unknown mode, or a bad segment (see :func:`check_segment`).
    """
    from .replay import replay_closed_loop, replay_open_loop

    if mode == "closed_loop":
        return replay_closed_loop(run, plant, params)
    if mode != "open_loop":
        raise UsageError(f"replay mode {mode!r}: expected 'closed_loop' or 'open_loop'")
    if segment_duration is None:
        return replay_open_loop(run, plant, params)
    return replay_segmented(run, plant, params, segment_duration=segment_duration)
