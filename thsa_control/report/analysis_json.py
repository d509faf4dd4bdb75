"""``analysis.json`` of a design's loop analysis (format ``thsa-analysis/1``, schema ``docs/analysis_schema.json``).

Numbers are finite, ``null`` (undefined, e.g. no crossover, or a point without
a linear loop) or the strings ``"inf"`` / ``"-inf"``.  Re-exported by
:mod:`.analysis_report`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..loops.catalog import METRICS
from .results import finite_or_none

if TYPE_CHECKING:  # annotations only
    from ..loops.analysis import DesignAnalysis

__all__ = ["ANALYSIS_FORMAT", "analysis_to_dict"]

#: Format tag of ``analysis.json``.
ANALYSIS_FORMAT = "thsa-analysis/1"


# ----------------------------------------------------------------------------------------------------------------
# JSON
# ----------------------------------------------------------------------------------------------------------------
def _num(x):
    """A JSON-safe number: finite float, None for nan, 'inf' / '-inf'."""
    return None if x is None else finite_or_none(float(x))


def _cond(c) -> dict:
    return {"nut_speed_mm_s": c.nut_speed * 1e3, "load_N": c.load_force, "temperature_C": c.temperature,
            "active": c.active, "label": c.label()}


def analysis_to_dict(result: DesignAnalysis) -> dict:
    """The analysis as a JSON-ready dict (format ``thsa-analysis/1``, schema ``docs/analysis_schema.json``)."""
    a, d = result.loops, result.design
    check = result.requirements
    failed_at: dict[tuple[str, int], list[str]] = {}
    for v in check.violations:
        failed_at.setdefault((v.loop, v.index), []).append(v.requirement)
    lin = a.linearization
    points = []
    for k, c in enumerate(a.conditions):
        points.append({"index": k, **_cond(c), "aiding": bool(c.aiding), "valid": bool(a.valid[k]),
                       "invalid_reasons": list(a.reasons[k]), "notes": list(lin.notes[k]),
                       "friction_slope_Nms_per_rad": _num(lin.friction_slope[k]),
                       "net_damping_Nms_per_rad": _num(lin.net_damping[k]),
                       "inertia_kg_m2": _num(lin.inertia[k])})
    loops = {}
    for loop, lm in a.loops.items():
        checked = loop in d.requirements
        rows = []
        for k in range(len(a)):
            m = lm.margins
            si = lm.step_info
            # no numbers where the linear loop does not exist (they would be silently wrong)
            num = _num if a.valid[k] else (lambda _x: None)
            row = {"index": k, "valid": bool(a.valid[k]), "stable": bool(lm.stable[k]) if a.valid[k] else None,
                   "crossover_hz": num(m.crossover_hz[k]), "phase_margin_deg": num(m.phase_margin_deg[k]),
                   "gain_margin_db": num(m.gain_margin_db[k]),
                   "gain_margin_lower_db": num(m.gain_margin_lower_db[k]),
                   "gain_margin_upper_db": num(m.gain_margin_upper_db[k]),
                   "phase_crossover_hz": num(m.phase_crossover_hz[k]),
                   "delay_margin_s": num(m.delay_margin_s[k]), "bandwidth_hz": num(m.bandwidth_hz[k]),
                   "ms": num(m.ms[k]), "spectral_radius": num(lm.spectral_radius[k]),
                   "step": {"rise_time_s": num(si.rise_time_s[k]), "settling_time_s": num(si.settling_time_s[k]),
                            "overshoot_percent": num(si.overshoot_percent[k]),
                            "peak_time_s": num(si.peak_time_s[k])},
                   "load_step": None if lm.load_step is None else {
                       "peak": num(lm.load_step_peak[k]), "unit": lm.load_step_unit,
                       "recovery_time_s": num(lm.load_step_recovery_s[k])},
                   "passed": (None if not (checked and a.valid[k])
                              else not failed_at.get((loop, k)) and bool(lm.stable[k])),
                   "failed_requirements": failed_at.get((loop, k), [])}
            rows.append(row)
        worst = {}
        for name in METRICS:
            if name.startswith("load_step") and loop == "current_loop":
                continue
            w = a.worst(loop, name)
            if w is not None:
                worst[name] = {"index": w.index, "value": _num(w.value), "unit": w.unit, "uniform": w.uniform,
                               "condition": _cond(w.condition), "note": w.note}
        loops[loop] = {"points": rows, "worst": worst}
    req = {
        "passed": check.passed, "checked_points": check.checked_points, "skipped_points": check.skipped_points,
        "rows": [{"loop": r.loop, "requirement": r.requirement, "metric": r.metric, "limit": _num(r.limit),
                  "worst_value": _num(r.worst_value), "worst_index": r.worst_index,
                  "worst_condition": None if r.worst_condition is None else _cond(r.worst_condition),
                  "failed_points": r.n_failed, "passed": r.passed, "uniform": r.uniform} for r in check.rows],
        "violations": [{"loop": v.loop, "requirement": v.requirement, "metric": v.metric, "limit": _num(v.limit),
                        "value": _num(v.value), "index": v.index, "condition": _cond(v.condition)}
                       for v in check.violations],
        "unstable": [{"loop": loop, "index": k, "condition": _cond(c)} for loop, k, c in check.unstable],
    }
    cycles = [{"loop": c.loop, "nonlinearity": c.nonlinearity, "condition": _cond(c.condition),
               "predicted": c.predicted, "signal": c.signal, "amplitude": _num(c.amplitude),
               "amplitude_unit": c.amplitude_unit, "frequency_hz": _num(c.frequency_hz), "note": c.note}
              for c in result.limit_cycles]
    configs = None
    if result.configurations is not None:
        configs = [{k: (_num(v) if isinstance(v, float) else v) for k, v in row.items()}
                   for row in result.configurations.rows()]
    sw = None
    if result.switching is not None:
        sw = {"level": getattr(result.switching, "level", None),
              "scenario": getattr(result.switching, "scenario", None),
              "cases": [{"delay_s": c.delay_s, "handover": bool(c.handover),
                         "peak_speed_error_m_s": _num(c.peak_speed_error_m_s),
                         "peak_position_error_m": _num(c.peak_position_error_m),
                         "recovery_time_s": _num(c.recovery_time_s)} for c in result.switching.cases]}
    s = result.settings
    return {
        "format": ANALYSIS_FORMAT,
        "design": {"name": d.name, "source": d.source, "control_period_s": d.control_period,
                   "computation_delay_samples": d.computation_delay_samples,
                   "current_kp_V_per_A": d.current_kp, "current_ki_V_per_A_s": d.current_ki,
                   "velocity_kp_A_per_rad_s": d.velocity_kp, "velocity_ki_A_per_rad": d.velocity_ki,
                   "position_kp_per_s": d.position_kp},
        "model": {"level": lin.model.level, "effects": list(lin.model.effects),
                  "states": list(lin.batch.states), "drifting_states": list(lin.model.named.drifting_states),
                  "inputs": list(lin.batch.inputs)},
        "grid": {"nut_speeds_mm_s": [v * 1e3 for v in s.nut_speeds], "load_forces_N": list(s.load_forces),
                 "temperatures_C": list(s.temperatures), "n_points": len(a), "n_valid": int(a.valid.sum())},
        "requirements": {k: dict(v) for k, v in d.requirements.items()},
        "passed": check.passed,
        "points": points,
        "loops": loops,
        "requirement_check": req,
        "limit_cycles": cycles,
        "configurations": configs,
        "switching": sw,
        "timings_s": {k: _num(v) for k, v in result.timings.items()},
    }
