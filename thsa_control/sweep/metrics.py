"""The metrics a sweep may keep: one number per run, by name (numbers only).

Each metric is computed from one :class:`~thsa_control.sim.simulate.SimulationResult`
with the functions the rest of the workbench uses (``sim.metrics``, the
validation metrics of ``thsa check``, the monitor trips of ``faults``); a
metric that does not apply to a run (no plateau, no monitors, no trip) is
``nan`` or ``inf`` as stated.  Besides the named metrics, three generic forms
take any output signal of the run: ``peak_abs:SIGNAL``, ``mean:SIGNAL``,
``final:SIGNAL`` (SI units of the signal).

Examples
--------
>>> "current_peak_A" in METRICS and "first_detection_s" in METRICS
True
>>> check_metric_name("peak_abs:jam_force")
'peak_abs:jam_force'
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import ScenarioError, ThsaError

__all__ = ["DEFAULT_METRICS", "GENERIC_FORMS", "METRICS", "check_metric_name", "compute_metrics", "metric_unit"]


@dataclass(frozen=True)
class _Metric:
    unit: str
    description: str


METRICS: dict[str, _Metric] = {
    "current_peak_A": _Metric("A", "largest |current| (active + standby channel)"),
    "current_rate_peak_A_per_s": _Metric("A/s", "largest |di/dt| at the output period"),
    "speed_error_percent": _Metric("%", "papers' speed error, worst plateau: mean |command - nut speed| / |command|"),
    "overshoot_percent": _Metric("%", "largest nut-speed excursion beyond the command on a plateau"),
    "settling_time_s": _Metric("s", "worst plateau: time until the speed error stays within 5 % (inf: never)"),
    "ise_mm2_s": _Metric("(mm/s)^2 s", "integral of the squared speed error"),
    "plateau_current_A": _Metric("A", "mean current (active + standby) on the first plateau, 0.3 s after its start"),
    "surface_speed_deviation_percent": _Metric("%", "largest |surface speed - command| on plateaus, % of command"),
    "opposing_mean_current_A": _Metric("A", "mean |current| on the opposing plateau (back-drive runs)"),
    "aiding_mean_current_A": _Metric("A", "mean |current| on the aiding plateau (back-drive runs)"),
    "aiding_to_opposing": _Metric("-", "aiding / opposing mean |current|"),
    "breakaway_peak_A": _Metric("A", "largest |current| in the first 0.6 s of the aiding motion"),
    "stop_backdrive_percent": _Metric("%", "largest |nut speed| in a trim stop, % of the command amplitude"),
    "final_position_mm": _Metric("mm", "nut position at the end of the run"),
    "validation_pass": _Metric("-", "1 when every [validation] limit of the design holds (thsa check), else 0"),
    "detection_discrepancy_s": _Metric("s", "discrepancy-monitor trip after the first fault (inf: none)"),
    "detection_lvdt_s": _Metric("s", "LVDT-monitor trip after the first fault (inf: none)"),
    "detection_speed_s": _Metric("s", "speed-monitor trip after the first fault (inf: none)"),
    "first_detection_s": _Metric("s", "first trip of any monitor after the first fault (inf: none)"),
    "takeover_s": _Metric("s", "standby take-over after the first fault (inf: none)"),
    "safed_s": _Metric("s", "safing (motors off, brakes on) after the first fault (inf: none)"),
    "surface_excursion_mm": _Metric("mm", "largest |surface position - position at the first fault| after it"),
}
GENERIC_FORMS = ("peak_abs", "mean", "final")
DEFAULT_METRICS = ("current_peak_A", "speed_error_percent", "overshoot_percent", "settling_time_s",
                   "plateau_current_A", "final_position_mm")
#: Metrics timed from the first fault of a run: they need faults (and the monitors) in the runs.
FAULT_METRICS = ("detection_discrepancy_s", "detection_lvdt_s", "detection_speed_s", "first_detection_s",
                  "takeover_s", "safed_s", "surface_excursion_mm")


def check_metric_name(name: str) -> str:
    """``name`` if it is a metric (or a generic form), else ValueError with the known names."""
    if name in METRICS:
        return name
    form, sep, signal = str(name).partition(":")
    if sep and form in GENERIC_FORMS and signal:
        return name
    close = difflib.get_close_matches(str(name), list(METRICS), n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise ValueError(f"unknown metric {name!r}{hint}; metrics are {', '.join(METRICS)}, or "
                     f"{'/'.join(GENERIC_FORMS)}:SIGNAL for any output signal")


def metric_unit(name: str) -> str:
    """Unit of a named metric ('SI' for the generic forms)."""
    return METRICS[name].unit if name in METRICS else "SI"


class _Run:
    """Lazily computed pieces of one run shared by several metrics."""

    def __init__(self, result, design, fault_time: float):
        self.r = result
        self.design = design
        self.t_fault = fault_time

    @cached_property
    def validation(self):
        from ..tuning.validation import run_metrics

        try:
            return run_metrics(self.r)
        except ScenarioError:
            return None

    @cached_property
    def backdrive(self):
        from ..sim.metrics import backdrive_metrics

        try:
            return backdrive_metrics(self.r)
        except ValueError:
            return None

    @cached_property
    def current(self) -> np.ndarray:
        i = np.asarray(self.r["motor_current"], float)
        if "standby_current" in self.r.names:
            i = i + np.asarray(self.r["standby_current"], float)
        return i

    def first_after_fault(self, signal: str) -> float:
        from ..faults.analysis import first_time_after

        if not math.isfinite(self.t_fault) or signal not in self.r.names:
            return math.nan
        return first_time_after(np.asarray(self.r.time), self.r[signal], self.t_fault)


def _validation_pass(run: _Run) -> float:
    from ..verdict import VALIDATION_METRICS, validation_limits

    m = run.validation
    if m is None:
        return math.nan
    for key, (limit, _origin) in validation_limits(run.design).items():
        value = getattr(m, VALIDATION_METRICS[key][0])
        if not value <= limit:
            return 0.0
    return 1.0


def _plateau_current(run: _Run) -> float:
    from ..sim.metrics import plateaus

    t = np.asarray(run.r.time)
    ps = plateaus(t, run.r["speed_cmd"], run.r["load_force"])
    if not ps:
        return math.nan
    m = (t >= ps[0].start + 0.3) & (t <= ps[0].end)
    return float(np.mean(run.current[m])) if np.any(m) else math.nan


def _value(name: str, run: _Run) -> float:
    r = run.r
    v, b = run.validation, run.backdrive
    if name in ("current_peak_A", "current_rate_peak_A_per_s", "speed_error_percent", "overshoot_percent",
                "settling_time_s"):
        return math.nan if v is None else float(getattr(v, name))
    if name == "ise_mm2_s":
        return math.nan if v is None else float(v.ise)
    if name == "plateau_current_A":
        return _plateau_current(run)
    if name == "surface_speed_deviation_percent":
        from ..sim.metrics import surface_speed_deviation

        return 100.0 * surface_speed_deviation(r) if "surface_speed" in r.names else math.nan
    if name in ("opposing_mean_current_A", "aiding_mean_current_A", "breakaway_peak_A"):
        return math.nan if b is None else float(getattr(b, name[:-2]))
    if name == "aiding_to_opposing":
        return math.nan if b is None else float(b.aiding_to_opposing)
    if name == "stop_backdrive_percent":
        return math.nan if b is None or not b.stop_backdrive_peak else \
            100.0 * max(b.stop_backdrive_peak) / b.command_amplitude
    if name == "final_position_mm":
        return float(r["nut_position"][-1]) * 1e3
    if name == "validation_pass":
        return _validation_pass(run)
    if name.startswith("detection_"):
        return run.first_after_fault(f"trip_{name[len('detection_'):-2]}")
    if name == "first_detection_s":
        return min(run.first_after_fault(s) for s in ("trip_discrepancy", "trip_lvdt", "trip_speed"))
    if name == "takeover_s":
        return run.first_after_fault("standby_active")
    if name == "safed_s":
        return run.first_after_fault("safed")
    if name == "surface_excursion_mm":
        if not math.isfinite(run.t_fault) or "surface_position" not in r.names:
            return math.nan
        t, x = np.asarray(r.time), np.asarray(r["surface_position"])
        after = t >= run.t_fault
        return float(np.max(np.abs(x[after] - x[np.argmax(after)]))) * 1e3 if np.any(after) else math.nan
    form, _, signal = name.partition(":")
    if signal not in r.names:
        raise ThsaError(f"metric {name!r}: the run has no signal {signal!r}; signals are {', '.join(r.names)}")
    s = np.asarray(r[signal], float)
    return float(np.max(np.abs(s)) if form == "peak_abs" else np.mean(s) if form == "mean" else s[-1])


def compute_metrics(result, design, names, *, fault_time: float = math.nan) -> dict[str, float]:
    """The metrics ``names`` of one run (``fault_time``: onset of its first fault [s], nan: none)."""
    run = _Run(result, design, fault_time)
    return {n: float(_value(n, run)) for n in names}
