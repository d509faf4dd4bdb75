"""Report of a design's loop analysis: a self-contained HTML page and ``analysis.json``.

Takes a :class:`thsa_control.loops.analysis.DesignAnalysis` (numbers only) and
draws and writes it; it computes no physics.  The folder is built in a
temporary sibling and renamed (:func:`thsa_control.report.build.atomic_folder`),
so a failure leaves nothing half-written.

Contents (each figure and table has the HTML id ``fig-<name>`` /
``table-<name>``, see :data:`FIGURES` and :data:`TABLES`):

* Bode plots of the current, velocity and position loops overlaid across
  temperature (reference point coloured, every valid grid point in grey);
* step responses (reference steps, velocity steps over the grid, load steps);
* maps of the velocity-loop margins over speed and load at each temperature;
* the pole map of the velocity loop over temperature;
* the local friction slopes and net damping (Stribeck region);
* the nonlinear switch-over transient and its recovery time vs detection delay;
* tables: requirements (pass/fail, worst point), worst point of every metric,
  the margins of each loop at every grid point with failures and worst values
  marked, invalid points with their reason, Stribeck points, predicted limit
  cycles, the active/standby configurations, switch-over recovery.

``analysis.json`` (format ``thsa-analysis/1``) follows the JSON Schema in
``docs/analysis_schema.json``: numbers are finite, ``null`` (undefined, e.g.
no crossover) or the strings ``"inf"`` / ``"-inf"``.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from ..loops.analysis import LOOPS, METRICS, DesignAnalysis, LoopAnalysis, check_requirements  # noqa: E402
from .build import atomic_folder, write_json  # noqa: E402

__all__ = [
    "ANALYSIS_FORMAT",
    "FIGURES",
    "TABLES",
    "analysis_to_dict",
    "write_analysis_report",
    "plot_loop_bode",
    "plot_steps",
    "plot_margin_maps",
    "plot_velocity_poles",
    "plot_friction_slopes",
    "plot_switching",
]

#: Format tag of ``analysis.json``.
ANALYSIS_FORMAT = "thsa-analysis/1"
#: Figures of the report (HTML ids ``fig-<name>``, files ``figures/<name>.png``).
FIGURES = ("bode_current_loop", "bode_velocity_loop", "bode_position_loop", "step_responses", "margin_maps",
           "velocity_poles", "friction_slopes", "switching_transient")
#: Tables of the report (HTML ids ``table-<name>``).
TABLES = ("requirements", "worst_points", "margins_current_loop", "margins_velocity_loop", "margins_position_loop",
          "invalid_points", "stribeck_points", "limit_cycles", "configurations", "switching_recovery")

_LOOP_TITLE = {"current_loop": "current loop", "velocity_loop": "velocity loop", "position_loop": "position loop"}
_CMAP = plt.get_cmap("coolwarm")


def _tcolor(t: float):
    return _CMAP((t + 55.0) / 125.0)


def _hz(w):
    return np.asarray(w) / (2 * np.pi)


# ----------------------------------------------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------------------------------------------
def plot_loop_bode(analysis: LoopAnalysis, loop: str, axes=None):
    """Open-loop Bode plot of ``loop``: reference point per temperature in colour, all valid points in grey.

    Parameters
    ----------
    analysis : LoopAnalysis
    loop : str
        One of ``LOOPS``.
    axes : (Axes, Axes), optional
        Magnitude and phase axes; default a new figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if axes is None:
        fig, axes = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True, constrained_layout=True)
    else:
        fig = axes[0].figure
    ax_m, ax_p = axes
    lm = analysis.loops[loop]
    f = _hz(lm.margins.omega)
    L = lm.margins.L
    with np.errstate(divide="ignore"):
        mag = 20 * np.log10(np.abs(L))
    ph = np.degrees(np.unwrap(np.angle(L), axis=1))
    # one branch per curve: the phase at the gain crossover in (-360, 0], so that it reads PM - 180
    wc = lm.margins.crossover_hz
    jc = np.where(np.isfinite(wc), np.argmin(np.abs(f[None, :] - np.nan_to_num(wc)[:, None]), axis=1), f.size - 1)
    ph -= 360 * np.ceil(ph[np.arange(len(ph)), jc] / 360)[:, None]
    ks = np.flatnonzero(analysis.valid)
    logf = np.log10(f)
    ax_m.add_collection(LineCollection([np.column_stack([f, mag[k]]) for k in ks], colors="0.82", lw=0.5, zorder=1))
    ax_p.add_collection(LineCollection([np.column_stack([f, ph[k]]) for k in ks], colors="0.82", lw=0.5, zorder=1))
    ax_m.set_xscale("log")
    ax_m.set_xlim(f[0], f[-1] * 1.05)
    del logf
    for temp, k in analysis.reference_indices().items():
        c = _tcolor(temp)
        pm, wc = lm.margins.phase_margin_deg[k], lm.margins.crossover_hz[k]
        ax_m.semilogx(f, mag[k], color=c, lw=1.6, label=f"{temp:g} degC: PM {pm:.1f} deg at {wc:.3g} Hz", zorder=3)
        ax_p.semilogx(f, ph[k], color=c, lw=1.6, zorder=3)
        if np.isfinite(wc):
            ax_m.plot([wc], [0.0], "o", color=c, ms=4, zorder=4)
    ax_m.axhline(0, color="k", lw=0.7)
    ax_p.axhline(-180, color="k", lw=0.7)
    lo, hi = np.nanpercentile(mag[analysis.valid], [1, 99]) if analysis.valid.any() else (-60, 60)
    ax_m.set_ylim(max(lo - 5, -120), min(hi + 5, 150))
    ax_m.set_ylabel("|L| [dB]")
    ax_p.set_ylabel("phase of L [deg]")
    ax_p.set_xlabel("frequency [Hz] (up to Nyquist)")
    ax_p.set_ylim(max(np.nanpercentile(ph, 1) - 20, -540), min(np.nanpercentile(ph, 99) + 20, 180))
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    refs = analysis.reference_indices()
    ref = analysis.conditions[next(iter(refs.values()))] if refs else None
    where = f"{ref.nut_speed * 1e3:g} mm/s, {ref.load_force * 1e-3:g} kN" if ref else "-"
    ax_m.legend(fontsize=7, loc="lower left", title=f"reference point {where}", title_fontsize=7)
    w = analysis.worst(loop, "phase_margin_deg")
    if w is None:
        extra = ""
    elif w.uniform:
        extra = "; the same at every valid point"
    else:
        extra = f"; worst PM {w.value:.1f} deg at {w.condition.label()}"
    ax_m.set_title(f"{_LOOP_TITLE[loop]}: open loop L(z), grey: every valid grid point{extra}", fontsize=9)
    return fig


def plot_steps(analysis: LoopAnalysis):
    """Step responses: reference steps per temperature, velocity steps over the grid, load steps.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, axes = plt.subplots(2, 3, figsize=(14, 7.5), constrained_layout=True)
    refs = analysis.reference_indices()
    scale = {"current_loop": (1e3, "ms"), "velocity_loop": (1e3, "ms"), "position_loop": (1.0, "s")}
    for j, loop in enumerate(LOOPS):
        lm = analysis.loops[loop]
        ax = axes[0, j]
        s, unit = scale[loop]
        for temp, k in refs.items():
            ax.plot(lm.step_time * s, lm.step[k], color=_tcolor(temp), label=f"{temp:g} degC")
        ax.set_title(f"{_LOOP_TITLE[loop]}: unit reference step", fontsize=9)
        ax.set_xlabel(f"time [{unit}]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    axes[0, 0].set_ylabel("output / reference [-]")
    ax = axes[1, 0]
    lm = analysis.loops["velocity_loop"]
    ks = np.flatnonzero(analysis.valid)
    ax.add_collection(LineCollection([np.column_stack([lm.step_time * 1e3, lm.step[k]]) for k in ks],
                                     colors="0.8", lw=0.5))
    ax.autoscale()
    w = analysis.worst("velocity_loop", "overshoot_percent")
    if w is not None:
        ax.plot(lm.step_time * 1e3, lm.step[w.index], color="tab:red", lw=1.5,
                label=f"worst overshoot {w.value:.0f} %: {w.condition.label()}")
        ax.legend(fontsize=7)
    ax.set_title("velocity loop: unit step at every valid grid point", fontsize=9)
    ax.set_xlabel("time [ms]")
    ax.set_ylabel("motor speed / reference [-]")
    ax.grid(True, alpha=0.3)
    for j, (loop, factor, unit) in enumerate((("velocity_loop", 1e6, "nut speed [mm/s per kN]"),
                                              ("position_loop", 1e9, "nut position [um per kN]"))):
        ax = axes[1, j + 1]
        lm = analysis.loops[loop]
        tscale = 1e3 if loop == "velocity_loop" else 1.0
        for temp, k in refs.items():
            ax.plot(lm.load_step_time * tscale, lm.load_step[k] * factor, color=_tcolor(temp), label=f"{temp:g} degC")
        ax.set_title(f"{_LOOP_TITLE[loop]}: +1 kN load step (compressive)", fontsize=9)
        ax.set_ylabel(unit)
        ax.set_xlabel("time [ms]" if loop == "velocity_loop" else "time [s]")
        ax.grid(True, alpha=0.3)
    ref = analysis.conditions[next(iter(refs.values()))] if refs else None
    if ref is not None:
        fig.suptitle(f"Step responses at the reference point {ref.nut_speed * 1e3:g} mm/s, "
                     f"{ref.load_force * 1e-3:g} kN (colour: temperature)", fontsize=10)
    return fig


def plot_margin_maps(analysis: LoopAnalysis, loop: str = "velocity_loop",
                     metrics=("phase_margin_deg", "gain_margin_db", "ms")):
    """Maps of ``metrics`` of ``loop`` over speed x load, one column per temperature.

    Invalid points are hatched; the worst valid point of each metric is framed.
    Needs a grid analysis.

    Returns
    -------
    matplotlib.figure.Figure
    """
    grid = analysis.grid
    if grid is None:
        raise ValueError("plot_margin_maps needs an analysis over a ConditionGrid")
    nT, nV, nF = grid.shape
    fig, axes = plt.subplots(len(metrics), nT, figsize=(3.1 * nT + 1, 2.9 * len(metrics)), squeeze=False,
                             constrained_layout=True)
    valid = analysis.valid.reshape(nT, nV, nF)
    for i, name in enumerate(metrics):
        vals = np.asarray(analysis.metric(loop, name), float).reshape(nT, nV, nF)
        shown = np.where(valid, np.abs(vals) if name == "gain_margin_db" else vals, np.nan)
        finite = shown[np.isfinite(shown)]
        vmin, vmax = (np.min(finite), np.max(finite)) if finite.size else (0, 1)
        cmap = plt.get_cmap("RdYlGn_r" if METRICS[name][1].startswith("max") else "RdYlGn")
        w = analysis.worst(loop, name)
        for t in range(nT):
            ax = axes[i, t]
            im = ax.imshow(shown[t], origin="lower", aspect="auto", cmap=cmap, vmin=vmin, vmax=vmax)
            for a in range(nV):
                for b in range(nF):
                    if not valid[t, a, b]:
                        ax.add_patch(plt.Rectangle((b - 0.5, a - 0.5), 1, 1, fill=False, hatch="///", color="0.6"))
                    elif np.isfinite(vals[t, a, b]):
                        ax.text(b, a, f"{vals[t, a, b]:.3g}", ha="center", va="center", fontsize=6)
            if w is not None and w.index // (nV * nF) == t:
                a, b = divmod(w.index % (nV * nF), nF)
                ax.add_patch(plt.Rectangle((b - 0.5, a - 0.5), 1, 1, fill=False, lw=2.2, color="k"))
            ax.set_xticks(range(nF), [f"{f * 1e-3:g}" for f in grid.load_forces], fontsize=7)
            ax.set_yticks(range(nV), [f"{v * 1e3:g}" for v in grid.nut_speeds], fontsize=7)
            if i == len(metrics) - 1:
                ax.set_xlabel("load [kN] (< 0 aids)", fontsize=8)
            if t == 0:
                ax.set_ylabel(f"{name}\nspeed [mm/s]", fontsize=8)
            if i == 0:
                ax.set_title(f"{grid.temperatures[t]:g} degC", fontsize=9)
        fig.colorbar(im, ax=axes[i, :], shrink=0.8, label=f"{name} [{METRICS[name][0]}]")
    fig.suptitle(f"{_LOOP_TITLE[loop]} over the grid (hatched: not analysed, see the invalid points; framed: worst point"
                 f"{'; gain margin shown by magnitude' if 'gain_margin_db' in metrics else ''})", fontsize=10)
    return fig


def plot_velocity_poles(analysis: LoopAnalysis, ax=None):
    """Closed-loop poles of the velocity loop over temperature: z-plane and continuous equivalent.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if ax is None:
        fig, ax = plt.subplots(1, 2, figsize=(12, 5.2), constrained_layout=True)
    else:
        fig = ax[0].figure
    lm = analysis.loops["velocity_loop"]
    h = analysis.design.control_period
    temps = sorted({c.temperature for c in analysis.conditions})
    loads = sorted({c.load_force for c in analysis.conditions})
    markers = "ov^s<>Dph*"
    dominant = []
    for temp in temps:
        for j, f in enumerate(loads):
            ks = [k for k, c in enumerate(analysis.conditions)
                  if c.temperature == temp and c.load_force == f and analysis.valid[k]]
            if not ks:
                continue
            p = lm.poles[ks].ravel()
            p = p[np.abs(p) > 1e-9]
            s = np.log(p) / h / (2 * np.pi)
            c = _tcolor(temp)
            lab = f"{temp:g} degC" if j == 0 else None
            ax[0].plot(s.real, s.imag, markers[j % len(markers)], color=c, ms=4, mfc="none", label=lab)
            dom = s[np.abs(s) < 60]
            dominant.append(dom)
            ax[1].plot(dom.real, dom.imag, markers[j % len(markers)], color=c, ms=5, mfc="none",
                       label=f"{f * 1e-3:g} kN" if temp == temps[0] else None)
    ax[0].axvline(0, color="k", lw=0.7)
    ax[0].set_xscale("symlog", linthresh=10)
    ax[0].set_xlabel("Re s / 2 pi [Hz] (symlog)")
    ax[0].set_ylabel("Im s / 2 pi [Hz]")
    ax[0].set_title("all closed-loop poles, continuous equivalent s = ln z / h (colour: temperature)", fontsize=9)
    ax[1].axvline(0, color="k", lw=0.7)
    if dominant:
        d = np.concatenate(dominant)
        if d.size:
            ax[1].set_xlim(min(d.real.min() * 1.1, -1), max(1.0, d.real.max() + 1))
            span = max(np.abs(d.imag).max() * 1.2, 2.0)
            ax[1].set_ylim(-span, span)
    ax[1].set_xlabel("Re s / 2 pi [Hz]")
    ax[1].set_ylabel("Im s / 2 pi [Hz]")
    ax[1].set_title("dominant poles (|s| < 60 Hz); marker: load", fontsize=9)
    for a in ax:
        a.grid(True, alpha=0.3)
    ax[0].legend(fontsize=7, loc="upper left")
    ax[1].legend(fontsize=7, loc="upper left", title="load", title_fontsize=7)
    fig.suptitle("Velocity loop: closed-loop poles at every valid grid point over temperature", fontsize=10)
    return fig


def plot_friction_slopes(analysis: LoopAnalysis):
    """Net damping and friction slope at the motor shaft vs speed, per load and temperature.

    Returns
    -------
    matplotlib.figure.Figure
    """
    lin = analysis.linearization
    loads = sorted({c.load_force for c in analysis.conditions})
    temps = sorted({c.temperature for c in analysis.conditions})
    fig, axes = plt.subplots(2, len(loads), figsize=(3.2 * len(loads) + 1, 6), sharex=True, squeeze=False,
                             constrained_layout=True)
    for j, f in enumerate(loads):
        for temp in temps:
            ks = [k for k, c in enumerate(analysis.conditions)
                  if c.load_force == f and c.temperature == temp and analysis.valid[k]]
            if not ks:
                continue
            v = [analysis.conditions[k].nut_speed * 1e3 for k in ks]
            axes[0, j].plot(v, lin.net_damping[ks] * 1e3, "o-", ms=3, color=_tcolor(temp), label=f"{temp:g} degC")
            axes[1, j].plot(v, lin.friction_slope[ks] * 1e3, "o-", ms=3, color=_tcolor(temp))
        for i in range(2):
            axes[i, j].axhline(0, color="k", lw=0.7)
            axes[i, j].axhspan(axes[i, j].get_ylim()[0], 0, color="tab:red", alpha=0.06, lw=0)
            axes[i, j].grid(True, alpha=0.3)
            axes[i, j].set_xscale("log")
        axes[0, j].set_title(f"load {f * 1e-3:g} kN", fontsize=9)
        axes[1, j].set_xlabel("nut speed [mm/s]")
    axes[0, 0].set_ylabel("net damping [mN m s/rad]\n(< 0: unstable mechanical mode)")
    axes[1, 0].set_ylabel("friction slope dTf/dw [mN m s/rad]\n(< 0: Stribeck region)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Local friction slope and net damping at the motor shaft (from the linearisation)", fontsize=10)
    return fig


def plot_switching(switching):
    """Switch-over transient (nut speed) per detection delay, without and with hand-over; recovery vs delay.

    Parameters
    ----------
    switching : thsa_control.loops.switching.SwitchoverAnalysis

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = plt.figure(figsize=(13, 7.5), constrained_layout=True)
    gs = fig.add_gridspec(2, 2, height_ratios=(2.2, 1))
    cases = list(switching.cases)
    delays = sorted({c.delay_s for c in cases})
    cmap = plt.get_cmap("viridis")
    t_fault = getattr(switching, "fault_time_s", None)
    for j, hand in enumerate((False, True)):
        ax = fig.add_subplot(gs[0, j])
        sel = [c for c in cases if c.handover == hand]
        for c in sel:
            color = cmap(delays.index(c.delay_s) / max(1, len(delays) - 1))
            ax.plot(c.time, np.asarray(c.nut_speed) * 1e3, color=color, lw=1.1,
                    label=f"{c.delay_s * 1e3:g} ms: recovery {c.recovery_time_s * 1e3:.0f} ms")
        if sel:
            ax.plot(sel[0].time, np.asarray(sel[0].speed_cmd) * 1e3, "k--", lw=0.8, label="command")
            nf = getattr(sel[0], "nut_speed_no_fault", None)
            if nf is not None:
                ax.plot(sel[0].time, np.asarray(nf) * 1e3, color="0.5", lw=0.8, label="no fault")
        if t_fault is not None:
            ax.axvline(t_fault, color="tab:red", lw=0.8)
            rec = [c.recovery_time_s for c in cases if np.isfinite(c.recovery_time_s)]
            ax.set_xlim(t_fault - 0.05, t_fault + max(rec + [0.2]) + 0.1)
        ax.set_title(f"switch-over {'with' if hand else 'without'} integrator hand-over", fontsize=9)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("nut speed [mm/s]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    ax = fig.add_subplot(gs[1, :])
    for hand, style in ((False, "o-"), (True, "s--")):
        sel = sorted((c for c in cases if c.handover == hand), key=lambda c: c.delay_s)
        ax.plot([c.delay_s * 1e3 for c in sel], [c.recovery_time_s * 1e3 for c in sel], style,
                label="with hand-over" if hand else "without hand-over")
    ax.set_xlabel("detection delay [ms]")
    ax.set_ylabel("recovery time [ms]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.suptitle(f"Active/standby switch-over (nonlinear simulation, scenario "
                 f"{getattr(switching, 'scenario', 'motor_fault_switch')}, level {getattr(switching, 'level', '?')})",
                 fontsize=10)
    return fig


# ----------------------------------------------------------------------------------------------------------------
# JSON
# ----------------------------------------------------------------------------------------------------------------
def _num(x):
    """A JSON-safe number: finite float, None for nan, 'inf' / '-inf'."""
    if x is None:
        return None
    x = float(x)
    if math.isnan(x):
        return None
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return x


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
            row = {"index": k, "valid": bool(a.valid[k]), "stable": bool(lm.stable[k]),
                   "crossover_hz": num(m.crossover_hz[k]), "phase_margin_deg": num(m.phase_margin_deg[k]),
                   "gain_margin_db": num(m.gain_margin_db[k]), "phase_crossover_hz": num(m.phase_crossover_hz[k]),
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
                               "condition": _cond(w.condition)}
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


# ----------------------------------------------------------------------------------------------------------------
# HTML
# ----------------------------------------------------------------------------------------------------------------
_CSS = """
body{font-family:system-ui,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em 2em;color:#222;max-width:1500px}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:1.8em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:12px;margin:0.5em 0}td,th{border:1px solid #ccc;padding:2px 6px;
text-align:right}th{background:#f0f0f0}td.l,th.l{text-align:left}tr.invalid td{color:#999;background:#fafafa}
td.fail{background:#f8c9c4}td.worst{font-weight:bold;background:#fff2a8}tr.worstrow td{border-top:2px solid #000;
border-bottom:2px solid #000}.pass{color:#167a2b;font-weight:bold}.failtxt{color:#b3261e;font-weight:bold}
figure{margin:0.8em 0}figcaption{font-size:12px;color:#555}img{max-width:100%}
details{margin:0.5em 0}.note{font-size:12px;color:#555}
"""


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def _fmt(x, digits: int = 4) -> str:
    if x is None:
        return "-"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    x = float(x)
    if math.isnan(x):
        return "-"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.{digits}g}"


def _table(name: str, header, rows, classes=None, caption: str = "") -> str:
    """HTML table; ``rows`` of cells (str), ``classes`` per row: (row class, [cell classes])."""
    out = [f'<table id="table-{name}">']
    if caption:
        out.append(f"<caption class='note' style='caption-side:top;text-align:left'>{html.escape(caption)}</caption>")
    out.append("<tr>" + "".join(f"<th class='l'>{html.escape(h)}</th>" if i == 0 else f"<th>{html.escape(h)}</th>"
                                 for i, h in enumerate(header)) + "</tr>")
    for i, row in enumerate(rows):
        rcls, ccls = (classes[i] if classes else ("", None))
        cells = []
        for j, cell in enumerate(row):
            cls = [] if ccls is None or not ccls[j] else [ccls[j]]
            if j == 0 or (isinstance(cell, str) and len(cell) > 24):
                cls.append("l")
            attr = f" class='{' '.join(cls)}'" if cls else ""
            cells.append(f"<td{attr}>{cell}</td>")
        out.append(f"<tr class='{rcls}'>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


_MARGIN_COLUMNS = ("crossover_hz", "phase_margin_deg", "gain_margin_db", "delay_margin_s", "bandwidth_hz", "ms",
                   "rise_time_s", "settling_time_s", "overshoot_percent", "load_step_peak", "load_step_recovery_s")


def _margin_table(result: DesignAnalysis, loop: str) -> str:
    a = result.loops
    lm = a.loops[loop]
    cols = [c for c in _MARGIN_COLUMNS if not (loop == "current_loop" and c.startswith("load_step"))]
    fails: dict[int, set[str]] = {}
    for v in result.requirements.violations:
        if v.loop == loop:
            fails.setdefault(v.index, set()).add(v.metric)
    worst = {name: a.worst(loop, name) for name in cols}
    worst_pm = worst.get("phase_margin_deg")
    rows, classes = [], []
    for k, c in enumerate(a.conditions):
        row = [html.escape(f"{c.nut_speed * 1e3:g}"), html.escape(f"{c.load_force * 1e-3:g}"),
               html.escape(f"{c.temperature:g}"), "yes" if a.valid[k] else "no",
               ("yes" if lm.stable[k] else "NO") if a.valid[k] else "-"]
        ccls = [""] * 5
        if not lm.stable[k] and a.valid[k]:
            ccls[4] = "fail"
        for name in cols:
            val = lm.metric(name)[k]
            row.append(_fmt(val) if a.valid[k] else "-")
            cl = ""
            if a.valid[k] and name in fails.get(k, ()):
                cl = "fail"
            w = worst.get(name)
            if w is not None and w.index == k and not w.uniform:
                cl = (cl + " worst").strip()
            ccls.append(cl)
        rcls = "invalid" if not a.valid[k] else ("worstrow" if worst_pm is not None and worst_pm.index == k
                                                    and not worst_pm.uniform else "")
        row.append(html.escape("; ".join(r.split(":")[0] for r in a.reasons[k])))
        ccls.append("")
        rows.append(row)
        classes.append((rcls, ccls))
    header = ["speed [mm/s]", "load [kN]", "T [degC]", "valid", "stable"] + [
        f"{n} [{METRICS[n][0]}]" for n in cols] + ["invalid because"]
    cap = (f"{_LOOP_TITLE[loop]}: every grid point. Red: requirement not met; bold yellow: worst valid point of the "
           "column; framed row: worst phase margin; grey rows: not analysed (invalid linearisation or saturated "
           "controller; no numbers, not checked).")
    return _table(f"margins_{loop}", header, rows, classes, cap)


def _html(result: DesignAnalysis, figures: dict[str, bytes]) -> str:
    a, d, check = result.loops, result.design, result.requirements
    lin = a.linearization
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>THSA loop analysis: {html.escape(d.name)}"
             f"</title><style>{_CSS}</style></head><body>"]
    status = "<span class='pass'>PASS</span>" if check.passed else "<span class='failtxt'>FAIL</span>"
    parts.append(f"<h1>THSA loop analysis: design <code>{html.escape(d.name)}</code></h1>")
    parts.append(
        f"<p>Design file <code>{html.escape(d.source)}</code>; control period {d.control_period * 1e6:g} us, "
        f"computation delay {d.computation_delay_samples} sample(s). Plant: {html.escape(lin.model.describe())}. "
        f"Grid: {len(a)} points ({int(a.valid.sum())} valid): speeds "
        f"{', '.join(f'{v * 1e3:g}' for v in result.settings.nut_speeds)} mm/s, loads "
        f"{', '.join(f'{f * 1e-3:g}' for f in result.settings.load_forces)} kN (compressive positive: negative loads "
        f"aid the positive motion), temperatures {', '.join(f'{t:g}' for t in result.settings.temperatures)} degC."
        f"</p><p>Requirements at every valid grid point: {status} "
        f"({check.checked_points} points checked, {check.skipped_points} invalid points not checked).</p>")
    if not check.passed:
        parts.append("<pre>" + html.escape(check.summary()) + "</pre>")
    # requirements table
    rows, classes = [], []
    for r in check.rows:
        where = "same at every valid point" if r.uniform else (r.worst_condition.label() if r.worst_condition else "-")
        rows.append([r.loop, html.escape(r.requirement), _fmt(r.limit), _fmt(r.worst_value),
                     html.escape(where), str(r.n_failed),
                     "PASS" if r.passed else "FAIL"])
        classes.append(("", [""] * 6 + ["" if r.passed else "fail"]))
    parts.append("<h2>Requirements</h2>")
    parts.append(_table("requirements", ["loop", "requirement", "limit", "worst value", "worst point",
                                         "failing points", "result"], rows, classes,
                        "Gain margins are compared by magnitude (a negative value is the lower gain margin of a "
                        "conditionally stable loop). A closed-loop-unstable valid point fails every requirement."))
    # worst points
    rows = [[w.loop, w.metric, _fmt(w.value), html.escape(w.unit),
             "same at every valid point" if w.uniform else html.escape(w.condition.label())] for w in a.worst_points()]
    parts.append("<h2>Worst operating point of each metric</h2>")
    parts.append(_table("worst_points", ["loop", "metric", "value", "unit", "where"], rows))
    # figures
    captions = {
        "bode_current_loop": "Current loop: discrete PI around the ZOH RL plant of the linearisation.",
        "bode_velocity_loop": "Velocity loop: discrete PI around current reference -> motor speed, closed current "
                              "loop, ZOH and back-EMF inside.",
        "bode_position_loop": "Position-monitoring loop: P gain and the shaper's one-sample delay around the closed "
                              "velocity loop and the nut kinematics.",
        "step_responses": "Step responses of the three loops (linear, discrete) and the response to a load step.",
        "margin_maps": "Velocity-loop phase margin, |gain margin| and Ms over speed and load at each temperature.",
        "velocity_poles": "Closed-loop poles of the velocity loop at every valid grid point, coloured by temperature.",
        "friction_slopes": "Local friction slope and net damping at the motor shaft: negative slopes (Stribeck "
                           "region) remove damping and destabilise the mechanical mode.",
        "switching_transient": "Nonlinear switch-over transient (primary off, standby on after a detection delay).",
    }
    for name in FIGURES:
        if name == "bode_current_loop":
            parts.append("<h2>Open-loop Bode plots across temperature</h2>")
        if name == "step_responses":
            parts.append("<h2>Step responses</h2>")
        if name == "margin_maps":
            parts.append("<h2>Margins over the grid</h2>")
        if name == "velocity_poles":
            parts.append("<h2>Velocity loop poles over temperature</h2>")
        if name == "friction_slopes":
            parts.append("<h2>Friction: Stribeck region</h2>")
        if name == "switching_transient":
            parts.append("<h2>Active/standby switch-over</h2>")
        if name in figures:
            b64 = base64.b64encode(figures[name]).decode("ascii")
            parts.append(f"<figure id='fig-{name}'><img alt='{name}' src='data:image/png;base64,{b64}'>"
                         f"<figcaption>{html.escape(captions[name])}</figcaption></figure>")
        else:
            parts.append(f"<p class='note' id='fig-{name}'>{name}: not computed (switch-over analysis not run).</p>")
        if name == "margin_maps":
            for loop in LOOPS:
                parts.append(f"<details {'open' if loop == 'velocity_loop' else ''}><summary>"
                             f"Table: {_LOOP_TITLE[loop]} at every grid point</summary>")
                parts.append(_margin_table(result, loop))
                parts.append("</details>")
        if name == "friction_slopes":
            rows = []
            for k in np.flatnonzero(a.valid & (lin.stribeck | (lin.net_damping < 0))):
                vl = a.loops["velocity_loop"]
                rows.append([html.escape(a.conditions[k].label()), _fmt(lin.friction_slope[k] * 1e3),
                             _fmt(lin.net_damping[k] * 1e3), "yes" if lin.net_damping[k] < 0 else "no",
                             _fmt(vl.margins.phase_margin_deg[k]), _fmt(vl.margins.gain_margin_db[k]),
                             _fmt(vl.step_info.overshoot_percent[k])])
            parts.append(_table("stribeck_points", ["point", "friction slope [mN m s/rad]",
                                                    "net damping [mN m s/rad]", "unstable mechanical mode",
                                                    "velocity PM [deg]", "velocity GM [dB]", "velocity overshoot [%]"],
                                rows, caption=f"{len(rows)} valid points with a negative friction slope or net "
                                              "damping (destabilising; the velocity loop must stabilise them)."))
        if name == "switching_transient" and result.switching is not None:
            cases = list(result.switching.cases)
            delays = sorted({c.delay_s for c in cases})
            rows = []
            for dl in delays:
                row = [f"{dl * 1e3:g}"]
                for hand in (False, True):
                    c = next((c for c in cases if c.delay_s == dl and c.handover == hand), None)
                    row += ["-"] * 3 if c is None else [_fmt(c.recovery_time_s * 1e3),
                                                       _fmt(c.peak_speed_error_m_s * 1e3),
                                                       _fmt(c.peak_position_error_m * 1e3)]
                rows.append(row)
            parts.append(_table("switching_recovery", [
                "detection delay [ms]", "recovery [ms]", "peak speed error [mm/s]", "peak position error [mm]",
                "recovery, hand-over [ms]", "peak speed error, hand-over [mm/s]",
                "peak position error, hand-over [mm]"], rows,
                caption="Recovery: from the fault until the speed error stays within the tolerance of the command "
                        "(papers: about 150 ms with a 15 ms delay)."))
        elif name == "switching_transient":
            parts.append("<p class='note' id='table-switching_recovery'>switching_recovery: not computed.</p>")
    # configurations (linear side of the switch-over)
    parts.append("<h2>Active/standby configurations (linear models)</h2>")
    if result.configurations is not None:
        rows, classes = [], []
        for name, la in (("primary active, standby dragged", result.configurations.primary),
                         ("standby active, primary dragged", result.configurations.standby)):
            chk = check_requirements(la)
            bad = {(v.loop, v.index) for v in chk.violations}
            for loop, lm in la.loops.items():
                for k, c in enumerate(la.conditions):
                    ok = (loop, k) not in bad and bool(lm.stable[k])
                    f = _fmt if la.valid[k] else (lambda _x: "-")
                    rows.append([html.escape(name), loop, html.escape(c.label()), f(lm.margins.crossover_hz[k]),
                                 f(lm.margins.phase_margin_deg[k]), f(lm.margins.gain_margin_db[k]),
                                 f(lm.margins.bandwidth_hz[k]), f(lm.margins.ms[k]),
                                 "yes" if lm.stable[k] else "NO",
                                 ("PASS" if ok else "FAIL") if loop in d.requirements and la.valid[k] else "-"])
                    classes.append(("" if la.valid[k] else "invalid", [""] * 9 + ["" if ok else "fail"]))
        parts.append(_table("configurations", ["configuration", "loop", "point", "crossover [Hz]", "PM [deg]",
                                               "GM [dB]", "bandwidth [Hz]", "Ms", "stable", "requirements"],
                            rows, classes,
                            caption="Both plants carry two rotors (standby_motor effect): the design, derived for "
                                    "one rotor, sees about twice the inertia."))
    else:
        parts.append("<p class='note' id='table-configurations'>configurations: not computed.</p>")
    # invalid points
    rows = [[html.escape(c.label()), html.escape(" | ".join(reasons))] for c, reasons in a.invalid_points()]
    parts.append("<h2>Invalid operating points</h2>")
    parts.append(_table("invalid_points", ["point", "why the linear model is not valid there"], rows,
                        caption=f"{len(rows)} points: a linear model there would be silently wrong."))
    # limit cycles
    rows = [[c.loop, c.nonlinearity, html.escape(c.condition.label()), "yes" if c.predicted else "no",
             _fmt(c.amplitude), html.escape(c.amplitude_unit), _fmt(c.frequency_hz), html.escape(c.note)]
            for c in result.limit_cycles]
    parts.append("<h2>Describing functions: predicted limit cycles</h2>")
    parts.append(_table("limit_cycles", ["loop", "nonlinearity", "condition", "limit cycle", "amplitude", "unit",
                                         "frequency [Hz]", "note"], rows,
                        caption="Friction: the plant's set-valued friction vs motor speed around zero speed; "
                                "backlash: the load-path play (2 x backlash) in the position feedback."))
    from .tuning_report import tuning_section  # before/after of a tuned design (issue #9)
    parts.append(tuning_section(d))
    notes = "; ".join(f"{k} {v:.2f} s" for k, v in result.timings.items())
    parts.append(f"<p class='note'>Computed in: {html.escape(notes)}.</p></body></html>")
    return "\n".join(parts)


def write_analysis_report(result: DesignAnalysis, out_dir: str | Path) -> Path:
    """Write ``report.html`` (figures embedded), ``analysis.json`` and ``figures/*.png`` to ``out_dir``.

    The folder is replaced atomically: on failure nothing is written.

    Parameters
    ----------
    result : DesignAnalysis
    out_dir : path-like

    Returns
    -------
    pathlib.Path
        The folder written.
    """
    figures = {
        "bode_current_loop": _png(plot_loop_bode(result.loops, "current_loop")),
        "bode_velocity_loop": _png(plot_loop_bode(result.loops, "velocity_loop")),
        "bode_position_loop": _png(plot_loop_bode(result.loops, "position_loop")),
        "step_responses": _png(plot_steps(result.loops)),
        "velocity_poles": _png(plot_velocity_poles(result.loops)),
        "friction_slopes": _png(plot_friction_slopes(result.loops)),
    }
    if result.loops.grid is not None:
        figures["margin_maps"] = _png(plot_margin_maps(result.loops))
    if result.switching is not None:
        figures["switching_transient"] = _png(plot_switching(result.switching))
    doc = analysis_to_dict(result)
    page = _html(result, figures)
    with atomic_folder(out_dir) as tmp:
        (tmp / "figures").mkdir()
        for name, data in figures.items():
            (tmp / "figures" / f"{name}.png").write_bytes(data)
        (tmp / "report.html").write_text(page, encoding="utf-8")
        write_json(tmp / "analysis.json", doc)
    return Path(out_dir).resolve()
