"""What each result type's ``.report()``, ``.to_dict()`` and ``.plot(ax=None)`` do.

The result classes (``SimulationResult``, ``ReplayResult``, ``ResidualAnalysis``,
``IdentificationResult``, ``PlantLinearization``, ``LoopAnalysis``,
``RequirementCheck``, ``DesignAnalysis``, ``SwitchoverAnalysis``,
``FaultAnalysis``) keep numbers only; their three methods are lazy one-line
pass-throughs to the functions here (python-control's
``TimeResponseData.plot()`` and lmfit's ``ModelResult.fit_report()`` style):

The reports import only the catalogue of the loops (:mod:`thsa_control.loops.catalog`),
the unit table and each other, never the modules whose results call them (no import cycle).

* ``report() -> str``: a text report in display units (:mod:`thsa_control.data.units`);
* ``to_dict() -> dict``: JSON-able numbers in SI, the unit in each key or beside it;
* ``plot(ax=None)``: a figure (:class:`~thsa_control.report.figure.ReportFigure`),
  drawn into ``ax`` (an Axes, or the array of Axes the figure needs) when given.

Nothing here imports ``thsa_control.sim`` or ``thsa_control.fit`` at module
level: the results call in, not the other way round.
"""

from __future__ import annotations

import math

import numpy as np

from ..data.units import display_unit, signal_display, to_display

__all__ = [
    "format_simulation", "simulation_to_dict", "format_replay", "replay_to_dict", "plot_replay",
    "linearization_to_dict", "plot_linearization_poles",
    "format_loop_analysis", "loop_analysis_to_dict", "format_requirement_check", "requirement_check_to_dict",
    "plot_requirements", "format_design_analysis", "format_switchover", "switchover_to_dict",
    "format_fault_analysis", "finite_or_none",
]


def finite_or_none(x):
    """``x`` with NaN -> None and +-inf -> ``"inf"`` / ``"-inf"`` (strict JSON), recursively; arrays to lists."""
    if isinstance(x, dict):
        return {str(k): finite_or_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [finite_or_none(v) for v in x]
    if isinstance(x, np.ndarray):
        return finite_or_none(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        if math.isnan(x):
            return None
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        return x
    return x


def _axes_or_none(ax, n: int):
    """``ax`` as a list of ``n`` Axes (or None for a new figure); a clear error otherwise."""
    if ax is None:
        return None
    axes = list(np.ravel(ax)) if isinstance(ax, (list, tuple, np.ndarray)) else [ax]
    if len(axes) != n:
        raise ValueError(f"this plot needs {n} axes, got {len(axes)}")
    return axes


# ---------------------------------------------------------------------------------------------- simulation
def format_simulation(result) -> str:
    """Range and final value of every signal of a simulation run, in display units."""
    t = np.asarray(result.time)
    lines = [f"[[Simulation {result.name}]]",
             f"    effects            = {', '.join(result.effects) or 'functional (level A)'}",
             f"    duration           = {t[-1] if t.size else 0.0:.4g} s, {t.size} samples "
             f"every {result.info.get('output_period_s', float('nan')):.4g} s",
             f"    wall time          = {result.info.get('wall_s', float('nan')):.3g} s",
             "[[Signals]] (display units: min / max / final)"]
    width = max((len(n) for n in result.names), default=0)
    for n in result.names:
        x = np.asarray(result[n], float)
        du = signal_display(n)
        unit = du.unit if n in _KNOWN else result.units.get(n, "-")
        k = du.factor if n in _KNOWN else 1.0
        if x.size:
            lines.append(f"    {n:<{width}} [{unit}] {np.nanmin(x) * k:12.5g} {np.nanmax(x) * k:12.5g} "
                         f"{x[-1] * k:12.5g}")
    return "\n".join(lines)


def _known():
    from ..data.units import SIGNAL_QUANTITY

    return set(SIGNAL_QUANTITY)


_KNOWN = _known()


def simulation_to_dict(result) -> dict:
    """Name, effects, units and every signal (SI) of a run; ``time_s`` the sample times."""
    return finite_or_none({"name": result.name, "effects": list(result.effects), "units": dict(result.units),
                           "output_period_s": result.info.get("output_period_s"),
                           "time_s": np.asarray(result.time),
                           "signals": {n: np.asarray(result[n]) for n in result.names}})


# ---------------------------------------------------------------------------------------------- replay
def format_replay(result) -> str:
    """Fit of every compared channel of a replay (display units)."""
    lines = [f"[[Replay {result.run_name}]] ({result.mode.replace('_', ' ')}, effects "
             f"{', '.join(result.effects) or 'functional'})"]
    for c, f in result.fits.items():
        du = signal_display(c)
        lines.append(f"    {c:<14s} fit {f.fit_percent:7.2f} %, RMS {f.rms * du.factor:.4g} {du.unit}, "
                     f"NRMSE {f.nrmse:.4g}")
    return "\n".join(lines)


def replay_to_dict(result) -> dict:
    """Run, mode, effects and the fit of each channel (SI)."""
    return finite_or_none({"run": result.run_name, "mode": result.mode, "effects": list(result.effects),
                           "fits": {c: f.to_dict() for c, f in result.fits.items()},
                           "open_loop_replay": result.info.get("open_loop_replay"),
                           "segment_s": result.info.get("segment_s")})


def plot_replay(result, ax=None):
    """Measured and simulated channels of a replay, one panel each."""
    from .identification import plot_overlay

    chans = list(result.fits)
    sim = {c: (result.compared[c] if c in result.compared else result.simulated[c]) for c in chans}
    return plot_overlay(result.time, result.measured, {result.mode.replace("_", " "): sim}, channels=chans,
                        title=f"{result.run_name}: {result.mode.replace('_', ' ')} replay",
                        axes=_axes_or_none(ax, len(chans)))


# ---------------------------------------------------------------------------------------------- linear models
def linearization_to_dict(lin) -> dict:
    """Per condition: validity, reasons, notes, A/B/C/D with the signal names (SI), inertia and damping."""
    points = []
    for k, c in enumerate(lin.conditions):
        m = lin[k]
        points.append({"condition": {"nut_speed_m_s": c.nut_speed, "load_force_N": c.load_force,
                                     "temperature_C": c.temperature, "active": c.active, "label": c.label()},
                       "valid": bool(lin.valid[k]), "reasons": list(lin.reasons[k]), "notes": list(lin.notes[k]),
                       "states": list(m.states), "inputs": list(m.inputs), "outputs": list(m.outputs),
                       "A": np.asarray(m.A), "B": np.asarray(m.B), "C": np.asarray(m.C), "D": np.asarray(m.D),
                       "inertia_kg_m2": float(lin.inertia[k]), "net_damping_N_m_s_rad": float(lin.net_damping[k]),
                       "friction_slope_N_m_s_rad": float(lin.friction_slope[k])})
    return finite_or_none({"model": lin.model.describe(), "points": points})


def plot_linearization_poles(lin, ax=None):
    """Poles of every linear model in the s-plane [Hz] (invalid points hollow grey)."""
    from .figure import subplots

    if ax is None:
        fig, ax = subplots(1, 1, figsize=(7, 5))
    else:
        fig = ax.figure
    for k, c in enumerate(lin.conditions):
        p = np.linalg.eigvals(np.asarray(lin[k].A)) / (2 * np.pi)
        if lin.valid[k]:
            ax.plot(p.real, p.imag, "x", ms=6, label=c.label())
        else:
            ax.plot(p.real, p.imag, "o", mfc="none", color="0.6", ms=5, label=f"{c.label()} (invalid)")
    ax.axvline(0, color="k", lw=0.7)
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_xlabel("Re s / 2 pi [Hz] (symlog)")
    ax.set_ylabel("Im s / 2 pi [Hz]")
    ax.set_title(f"poles of the linear plant: {lin.model.describe()[:80]}", fontsize=9)
    ax.grid(True, alpha=0.3)
    if len(lin.conditions) <= 12:
        ax.legend(fontsize=7)
    return fig


# ---------------------------------------------------------------------------------------------- loop analysis
def format_loop_analysis(analysis) -> str:
    """Worst point of each metric of each loop (display units) and the points not analysed."""
    from .display import fmt_metric

    lines = [f"[[Loop analysis]] {len(analysis)} points, {int(analysis.valid.sum())} valid"]
    for w in analysis.worst_points():
        where = "the same at every valid point" if w.uniform else w.condition.label()
        note = f" ({w.note})" if w.note else ""
        lines.append(f"    {w.loop:<13s} {w.metric:<22s} {fmt_metric(w.loop, w.metric, w.value, unit=True):>16s}  "
                     f"{where}{note}")
    bad = analysis.invalid_points()
    if bad:
        lines.append(f"[[Not analysed]] {len(bad)} points")
        for c, reasons in bad[:10]:
            lines.append(f"    {c.label()}: {reasons[0] if reasons else ''}")
        if len(bad) > 10:
            lines.append(f"    ... and {len(bad) - 10} more")
    return "\n".join(lines)


def loop_analysis_to_dict(analysis) -> dict:
    """Conditions, validity with reasons, and every metric of every loop at every point (SI, unit in the key)."""
    from ..loops.catalog import METRICS

    return finite_or_none({
        "conditions": [{"nut_speed_m_s": c.nut_speed, "load_force_N": c.load_force, "temperature_C": c.temperature,
                        "label": c.label()} for c in analysis.conditions],
        "valid": np.asarray(analysis.valid), "reasons": [list(r) for r in analysis.reasons],
        "loops": {loop: {"stable": np.asarray(lm.stable),
                         **{name: np.asarray(lm.metric(name), float) for name in METRICS
                            if not (loop == "current_loop" and name.startswith("load_step"))}}
                  for loop, lm in analysis.loops.items()},
        "load_step_peak_units": {loop: lm.load_step_unit for loop, lm in analysis.loops.items()},
    })


def format_requirement_check(check) -> str:
    """Each requirement: limit, worst value and where, in display units; PASS/FAIL."""
    from .display import fmt_metric, requirement_text

    lines = [check.summary().splitlines()[0],
             f"    {check.checked_points} valid points checked, {check.skipped_points} not analysed"]
    for r in check.rows:
        where = "every valid point" if r.uniform else (r.worst_condition.label() if r.worst_condition else "-")
        worst = fmt_metric(r.loop, r.metric, r.worst_value, unit=True)
        if r.metric == "gain_margin_db" and np.isfinite(r.worst_value):  # the margin nearest 0 dB, named
            worst = (f"{'lower' if r.worst_value < 0 else 'upper'} GM {r.worst_value:+.1f} dB"
                     + (" (conditionally stable)" if r.worst_value < 0 else ""))
        lines.append(f"    {'PASS' if r.passed else 'FAIL'}  {r.loop:<13s} {requirement_text(r.loop, r.requirement, r.limit):<46s}"
                     f" worst {worst} at {where}"
                     + (f" ({r.n_failed} points fail)" if r.n_failed else ""))
    for loop, _, cond in check.unstable:
        lines.append(f"    {loop}: closed loop unstable at {cond.label()}")
    return "\n".join(lines)


def requirement_check_to_dict(check) -> dict:
    """Verdict, every requirement's worst value and the violations (SI, as the design file)."""
    def cond(c):
        return None if c is None else {"nut_speed_m_s": c.nut_speed, "load_force_N": c.load_force,
                                       "temperature_C": c.temperature, "label": c.label()}
    return finite_or_none({
        "passed": check.passed, "checked_points": check.checked_points, "skipped_points": check.skipped_points,
        "requirements": [{"loop": r.loop, "requirement": r.requirement, "metric": r.metric, "limit": r.limit,
                          "worst_value": r.worst_value, "worst_condition": cond(r.worst_condition),
                          "failing_points": r.n_failed, "passed": r.passed, "uniform": r.uniform} for r in check.rows],
        "violations": [{"loop": v.loop, "requirement": v.requirement, "metric": v.metric, "limit": v.limit,
                        "value": v.value, "condition": cond(v.condition)} for v in check.violations],
        "unstable": [{"loop": loop, "condition": cond(c)} for loop, _, c in check.unstable]})


def plot_requirements(check, ax=None):
    """How far each requirement's worst point is from its limit: bars of the spare fraction, coloured pass/close/fail.

    Spare fraction: ``(worst - limit) / |limit|`` for a minimum, ``(limit - worst) / |limit|`` for a maximum
    (gain margins by magnitude); below 0 fails.
    """
    from ..loops.catalog import REQUIREMENT_METRICS
    from .display import NEAR_FRACTION, STATUS_COLORS, requirement_status, requirement_text
    from .figure import subplots

    rows = [r for r in check.rows if np.isfinite(r.worst_value)]
    if ax is None:
        fig, ax = subplots(1, 1, figsize=(9, 0.32 * len(rows) + 1.4))
    else:
        fig = ax.figure
    spare, colors, labels = [], [], []
    for r in rows:
        op = REQUIREMENT_METRICS[r.requirement][1]
        v = abs(r.worst_value) if op == "abs>=" else r.worst_value
        s = (v - r.limit) / abs(r.limit) if op.endswith(">=") else (r.limit - v) / abs(r.limit)
        spare.append(max(min(s, 3.0), -1.0))
        colors.append(STATUS_COLORS[int(requirement_status([r.worst_value], r.limit, op)[0])])
        labels.append(f"{r.loop.replace('_loop', '')}: {requirement_text(r.loop, r.requirement, r.limit)}")
    y = np.arange(len(rows))[::-1]
    ax.barh(y, spare, color=colors, edgecolor="0.4")
    ax.axvline(0, color="k", lw=1)
    ax.axvline(NEAR_FRACTION, color="0.5", lw=0.8, ls=":")
    ax.set_yticks(y, labels, fontsize=8)
    ax.set_xlabel("spare at the worst valid point, fraction of the limit (< 0 fails; clipped at -1 and 3)")
    ax.set_title(f"requirements: {'PASS' if check.passed else 'FAIL'}", fontsize=10)
    ax.grid(True, axis="x", alpha=0.3)
    return fig


def format_design_analysis(result) -> str:
    """Requirements, the worst margins and the points not analysed (as ``thsa report`` prints)."""
    return format_requirement_check(result.requirements) + "\n" + format_loop_analysis(result.loops)


# ---------------------------------------------------------------------------------------------- switch-over
def format_switchover(sw) -> str:
    """Recovery and peaks of each switch-over case (ms, mm/s, mm)."""
    lines = [f"[[Switch-over]] scenario {sw.scenario}, level {sw.level}, fault at {sw.fault_time_s:g} s, recovery "
             f"within {sw.tolerance * 100:g} % of the command"]
    for c in sorted(sw.cases, key=lambda c: (c.handover, c.delay_s)):
        lines.append(f"    delay {to_display('time', c.delay_s):5.1f} ms, {'with' if c.handover else 'without'} "
                     f"hand-over: recovery {to_display('time', c.recovery_time_s):.1f} ms, peak speed error "
                     f"{to_display('nut_speed', c.peak_speed_error_m_s):.3g} mm/s, peak position error "
                     f"{to_display('position', c.peak_position_error_m):.3g} mm")
    return "\n".join(lines)


def switchover_to_dict(sw) -> dict:
    """The cases' numbers (SI)."""
    return finite_or_none({"scenario": sw.scenario, "level": sw.level, "fault_time_s": sw.fault_time_s,
                           "tolerance": sw.tolerance,
                           "cases": [{"delay_s": c.delay_s, "handover": c.handover,
                                      "recovery_time_s": c.recovery_time_s,
                                      "peak_speed_error_m_s": c.peak_speed_error_m_s,
                                      "peak_position_error_m": c.peak_position_error_m} for c in sw.cases]})


# ---------------------------------------------------------------------------------------------- faults
def format_fault_analysis(a) -> str:
    """The fault report's key numbers as ``thsa faults`` prints them: cases by plant, margins, sweep."""
    from .faults import monitor_display

    def ms(v):
        return "-" if not math.isfinite(v) else f"{to_display('time', v):.1f} ms"

    kn = display_unit("force")
    lines = [f"plant: level {a.level} + {', '.join(a.effects)}"]
    every = a.cases + a.rigid_cases
    order = list(dict.fromkeys(c.label for c in every))  # the sections of the HTML report, in their order
    heading = None
    for c in sorted(every, key=lambda c: order.index(c.label)):
        if c.label != heading:
            heading = c.label
            lines.append(f"-- {heading} --")
        det = ", ".join(f"{m} {ms(t)}" for m, t in c.detection_s.items() if math.isfinite(t)) or "no trip"
        how = " (scheduled by the scenario; the monitors only watch)" if c.takeover_source == "schedule" else ""
        name = c.scenario if c.label == "fault plant" else c.title  # the rigid-drive cases repeat scenario names
        line = (f"{name}: {', '.join(c.faults)} at {c.fault_time_s:g} s; trips: {det}; "
                f"take-over {ms(c.takeover_s)}{how}, safed {ms(c.safed_s)}")
        if not math.isnan(c.recovery_s):
            line += f", recovery {ms(c.recovery_s)}"
        lines.append(line)
        lines.append(f"    peaks after the fault: load path {kn.to_display(c.peaks['loadpath']):.1f} kN, upper gimbal "
                     f"{kn.to_display(c.peaks['primary_attachment']):.1f} kN, secondary "
                     f"{kn.to_display(c.peaks['secondary_path']):.1f} kN, jam {kn.to_display(c.peaks['jam']):.1f} kN, "
                     f"limiter {c.peaks['limiter_torque']:.0f} N m (slip {to_display('angle', c.limiter_slip_rad):.1f} "
                     f"deg); surface moved {to_display('position', c.surface_displacement_m):.2f} mm; "
                     f"energy residual {c.energy_residual * 100:.3f} %")
    for m in sorted({x.monitor for x in a.margins}):
        worst = min((x for x in a.margins if x.monitor == m), key=lambda x: x.margin)
        du = monitor_display(m)
        lines.append(f"false-alarm margin {m}: {a.min_margin(m):.2f} (threshold {du.to_display(worst.threshold):.4g} "
                     f"{du.unit} / {du.to_display(worst.persisted):.4g} {du.unit} held on {worst.scenario})")
    for p in a.sweep:
        if p.normal_trips:
            lines.append(f"sweep: thresholds x {p.scale:g} trip on {', '.join(p.normal_trips)}")
    missed = sorted({(p.scale, n) for p in a.sweep for n, t in p.detection_s.items() if not math.isfinite(t)})
    for scale, n in missed:
        lines.append(f"sweep: thresholds x {scale:g} miss {n}")
    return "\n".join(lines)
