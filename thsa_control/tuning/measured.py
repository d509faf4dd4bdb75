"""Validation on the rig: measured runs recorded with a design, judged against its ``[validation]`` limits.

``thsa check --design D --runs RUN.csv ...`` reads each run (FORMAT.md), makes
sure it was recorded with ``D``'s gains (the run's JSON ``controller`` block),
and computes on the measured signals the same metrics as the simulated
validation runs (:func:`~.validation.run_metrics`: speed error in % as the
papers define it, ISE against the command, overshoot, settling, current peak),
plus a sustained-oscillation measure.  Beside each, the model's prediction
for the same inputs (a closed-loop replay of the run's command, load and
temperature through the workbench's plant with ``D``).

Nut speed of a measured run: the drive's motor-speed channel times the
kinematic ratio (lead / (2 pi N)), the speed the velocity loop controls; the
prediction uses the same formula on the model's motor speed.

Sustained oscillation: on every plateau (constant non-zero command of at least
0.2 s), the rms of the speed error minus its 50 ms moving mean over the last
half of the plateau, in % of the command (a ringing that decays within the
first half does not count).  Limit :data:`OSCILLATION_LIMIT_PERCENT` (assumed:
ten times the rms of the rig's resolver-speed noise at 1 mm/s, 0.2 %).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from ..errors import ThsaError
from ..loops.design import Design
from ..sim.metrics import plateaus
from .validation import run_metrics

__all__ = ["OSCILLATION_LIMIT_PERCENT", "MeasuredRun", "judge_runs", "oscillation_percent"]

#: Sustained-oscillation limit [% of the command] (assumed: 10 x the resolver noise at 1 mm/s, see module notes).
OSCILLATION_LIMIT_PERCENT = 2.0
_GAIN_RTOL = 1e-6


class _Signals:
    """The minimum of a run result :func:`~.validation.run_metrics` reads."""

    def __init__(self, name, time, signals):
        self.name, self.time = name, np.asarray(time, float)
        self.signals = MappingProxyType(signals)
        self.names = tuple(signals)

    def __getitem__(self, k):
        return self.signals[k]


def oscillation_percent(time, cmd, speed, load) -> float:
    """Worst sustained oscillation over the plateaus [% of the command] (see the module notes)."""
    t = np.asarray(time, float)
    e = np.asarray(cmd, float) - np.asarray(speed, float)
    dt = float(np.median(np.diff(t)))
    w = max(1, int(round(0.05 / dt)))
    worst = 0.0
    for p in plateaus(t, np.asarray(cmd, float), np.asarray(load, float)):
        m = (t >= p.start + 0.5 * (p.end - p.start)) & (t <= p.end)
        if np.count_nonzero(m) < 2 * w:
            continue
        seg = e[m]
        mean = np.convolve(seg, np.ones(w) / w, mode="same")
        core = slice(w // 2, seg.size - w // 2)
        rms = float(np.sqrt(np.mean((seg[core] - mean[core]) ** 2)))
        worst = max(worst, 100.0 * rms / abs(p.command))
    return worst


@dataclass(frozen=True)
class MeasuredRun:
    """One measured run: its metrics, the model's for the same inputs, the oscillation measures."""

    name: str
    path: str
    temperature: float
    measured: object  # RunMetrics
    predicted: object | None  # RunMetrics or None when the replay failed
    oscillation_percent: float
    predicted_oscillation_percent: float
    prediction_error: str = ""

    def as_dict(self) -> dict:
        return {"run": self.name, "path": self.path, "temperature_C": self.temperature,
                "measured": self.measured.as_dict() | {"oscillation_percent": round(self.oscillation_percent, 6)},
                "predicted": (self.predicted.as_dict() | {"oscillation_percent": round(
                    self.predicted_oscillation_percent, 6)}) if self.predicted is not None else None,
                "prediction_error": self.prediction_error}


def _design_mismatch(run, design: Design) -> list[str]:
    c = run.controller
    if c is None:
        return ["the run's JSON has no controller block: cannot tell it was recorded with this design"]
    pairs = (("velocity_loop.kp_A_per_rad_s", c.velocity_loop.kp, design.velocity_kp),
             ("velocity_loop.ki_A_per_rad", c.velocity_loop.ki, design.velocity_ki),
             ("current_loop.kp_V_per_A", c.current_loop.kp, design.current_kp),
             ("current_loop.ki_V_per_A_s", c.current_loop.ki, design.current_ki),
             ("velocity_loop.current_limit_A", c.velocity_loop.current_limit, design.current_limit))
    return [f"{k} = {a:g} in the run, {b:g} in the design" for k, a, b in pairs
            if not math.isclose(a, b, rel_tol=_GAIN_RTOL)]


def judge_runs(design: Design, params, paths, *, level: str = "B", effects=None):
    """Rows of the validation limits on measured runs, and each run's measured and predicted metrics.

    Returns
    -------
    rows : list of thsa_control.verdict.RequirementVerdict
        Kind ``measured``: every validation limit (worst over the runs) and ``measured.sustained_oscillation``;
        a run not recorded with ``design`` or without a plateau to judge is an ``error`` row (a failure).

    Raises
    ------
    RigDataError
        A run that cannot be read (FORMAT.md), naming the file and the field.
    runs : list of MeasuredRun
    """
    from ..data.rigdata import read_run
    from ..fit.kinematics import run_kinematics
    from ..fit.replay import ReplaySettings, replay_closed_loop
    from ..fit.segment_states import measured_speed
    from ..loops.analysis import DEFAULT_ANALYSIS_EFFECTS
    from ..model import build_plant
    from ..verdict import RequirementVerdict, rows_from_metrics, validation_limits

    effects = tuple(DEFAULT_ANALYSIS_EFFECTS if effects is None else effects)
    plant = build_plant(level, effects, params=params)
    kin = (params.value("screw.lead") * 1e3, params.value("gear.ratio"))
    out, metrics, errors, osc = [], {}, [], {}
    for path in paths:
        # an unreadable run is bad input (RigDataError: exit 2 from the CLI, nothing judged)
        run = run_kinematics(read_run(path, default_kinematics=kin), params)
        bad = _design_mismatch(run, design)
        if bad:
            errors.append((run.name, "not recorded with design " + design.name + ": " + "; ".join(bad)))
            continue
        w = measured_speed(run)
        if w is None:
            errors.append((run.name, "no motor or screw speed channel"))
            continue
        # the run's kinematics are the parameter set's (run_kinematics refuses others): one ratio, the model's
        r = plant.kinematic_ratio(params)
        sig = run.signals
        temp = float(np.nanmedian(sig["temperature"]))
        mres = _Signals(run.name, run.time, {"speed_cmd": sig["speed_cmd"], "nut_speed": w * r,
                                             "load_force": sig["load_force"], "motor_current": sig["motor_current"],
                                             "temperature": sig["temperature"]})
        try:
            m = run_metrics(mres)
        except ThsaError as exc:
            errors.append((run.name, str(exc)))
            continue
        o = oscillation_percent(run.time, sig["speed_cmd"], w * r, sig["load_force"])
        pred, po, perr = None, float("nan"), ""
        try:
            # the logged housing temperature carries sensor noise (0.05 degC): a -55 degC run reads -55.1; the
            # model's range is -55..70 degC, so the prediction takes it clipped to that range
            from dataclasses import replace as _replace

            sig_model = dict(run.signals)
            sig_model["temperature"] = np.clip(np.asarray(sig["temperature"], float), -55.0, 70.0)
            rep = replay_closed_loop(_replace(run, signals=MappingProxyType(sig_model)), plant, params,
                                     design=design, settings=ReplaySettings())
            s = rep.simulated
            i = np.asarray(s["motor_current"]) + (np.asarray(s["standby_current"]) if "standby_current" in s else 0)
            pres = _Signals(run.name, run.time, {"speed_cmd": sig["speed_cmd"],
                                                 "nut_speed": np.asarray(s["motor_speed"]) * r,
                                                 "load_force": sig["load_force"], "motor_current": i,
                                                 "temperature": sig["temperature"]})
            pred = run_metrics(pres)
            po = oscillation_percent(run.time, sig["speed_cmd"], np.asarray(s["motor_speed"]) * r, sig["load_force"])
        except Exception as exc:
            perr = f"{type(exc).__name__}: {exc}"
        metrics[run.name] = m
        osc[run.name] = o
        out.append(MeasuredRun(run.name, str(path), temp, m, pred, o, po, perr))
    limits = validation_limits(design)
    rows = rows_from_metrics(limits, metrics, errors, "measured", lambda k: f"run {k}")
    rows = [RequirementVerdict("measured." + r.requirement, r.kind, r.limit, r.value, r.unit, r.worst_point, r.status,
                               r.checked, r.failed, r.origin, r.detail) for r in rows]
    if osc:
        wk = max(osc, key=lambda k: osc[k])
        n_fail = sum(v > OSCILLATION_LIMIT_PERCENT for v in osc.values())
        rows.append(RequirementVerdict("measured.sustained_oscillation", "measured", OSCILLATION_LIMIT_PERCENT,
                                       osc[wk], "%", f"run {wk}", "pass" if n_fail == 0 and not errors else (
                                           "fail" if n_fail else "error"), len(osc) + len(errors),
                                       n_fail + len(errors), "assumed: 10 x the resolver-speed noise at 1 mm/s"))
    elif errors:
        rows.append(RequirementVerdict("measured.sustained_oscillation", "measured", OSCILLATION_LIMIT_PERCENT,
                                       float("nan"), "%", "-", "error", len(errors), len(errors), "assumed",
                                       "; ".join(f"{w}: {e}" for w, e in errors[:3])))
    failed = [m for m in out if m.predicted is None]
    if out:
        rows.append(RequirementVerdict("measured.model_prediction", "measured", float("nan"), float(len(failed)),
                                       "runs", failed[0].name if failed else "-", "error" if failed else "pass",
                                       len(out), len(failed), "the model's prediction beside each run",
                                       "; ".join(f"{m.name}: {m.prediction_error}" for m in failed[:3])))
    return rows, out
