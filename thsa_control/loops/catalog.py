"""The loops of the cascade, their metrics and requirements as data: names, units, which way is worse.

One table read by the analysis (:mod:`.loop_analysis`, :mod:`.requirements`)
and by the reports (:mod:`thsa_control.report`), which must not import the
analysis modules (the results call the reports, not the other way round).
Imports nothing of the package.
"""

from __future__ import annotations

__all__ = ["LOOPS", "METRICS", "METRIC_LABELS", "LOAD_STEP_UNITS", "metric_unit", "REQUIREMENT_METRICS"]

#: The three loops of the cascade, inner to outer.
LOOPS: tuple[str, ...] = ("current_loop", "velocity_loop", "position_loop")

#: Metric name -> (unit, which way is worse: 'min', 'max', 'min_abs', 'max_abs').
METRICS: dict[str, tuple[str, str]] = {
    "crossover_hz": ("Hz", "min"),
    "phase_margin_deg": ("deg", "min"),
    "gain_margin_db": ("dB", "min_abs"),
    "gain_margin_lower_db": ("dB", "max"),
    "gain_margin_upper_db": ("dB", "min"),
    "delay_margin_s": ("s", "min"),
    "bandwidth_hz": ("Hz", "min"),
    "ms": ("-", "max"),
    "rise_time_s": ("s", "max"),
    "settling_time_s": ("s", "max"),
    "overshoot_percent": ("%", "max"),
    "load_step_peak": ("m/s of nut speed per N of load (velocity loop), m of nut position per N (position loop)",
                       "max_abs"),
    "load_step_recovery_s": ("s", "max"),
}

#: Metric name -> words for tables and plots.
METRIC_LABELS: dict[str, str] = {
    "crossover_hz": "gain crossover",
    "phase_margin_deg": "phase margin",
    "gain_margin_db": "gain margin (nearest 0 dB)",
    "gain_margin_lower_db": "lower gain margin",
    "gain_margin_upper_db": "upper gain margin",
    "delay_margin_s": "delay margin",
    "bandwidth_hz": "closed-loop bandwidth",
    "ms": "sensitivity peak Ms",
    "rise_time_s": "rise time",
    "settling_time_s": "settling time",
    "overshoot_percent": "overshoot",
    "load_step_peak": "load-step peak",
    "load_step_recovery_s": "load-step recovery",
}

#: The unit of the load-step peak of each outer loop.
LOAD_STEP_UNITS = {"velocity_loop": "m/s of nut speed per N of load", "position_loop": "m of nut position per N of load"}


def metric_unit(loop: str, name: str) -> str:
    """Unit of metric ``name`` of ``loop`` (the load-step peak's depends on the loop)."""
    if name == "load_step_peak":
        return LOAD_STEP_UNITS.get(loop, "-")
    return METRICS[name][0]


#: Requirement key -> (metric it limits, comparison ``'>='``, ``'<='`` or ``'abs>='``).
REQUIREMENT_METRICS: dict[str, tuple[str, str]] = {
    "min_phase_margin_deg": ("phase_margin_deg", ">="),
    "min_gain_margin_db": ("gain_margin_db", "abs>="),
    "min_delay_margin_s": ("delay_margin_s", ">="),
    "min_bandwidth_hz": ("bandwidth_hz", ">="),
    "max_sensitivity_peak": ("ms", "<="),
    "max_overshoot_percent": ("overshoot_percent", "<="),
    "max_settling_time_s": ("settling_time_s", "<="),
    "max_rise_time_s": ("rise_time_s", "<="),
}
