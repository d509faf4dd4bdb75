"""Figures and the report of faults and monitoring (issue #10).

Draws :class:`~thsa_control.faults.analysis.FaultAnalysis` and fault runs;
computes no physics.  ``write_fault_report`` builds ``faults.json``,
``report.html`` (self-contained) and one PNG per figure in a temporary folder
renamed at the end (nothing half-written).
"""

from __future__ import annotations

import base64
import html
import math
import textwrap
from pathlib import Path

import numpy as np  # noqa: E402

from ..model.laws import kinematic_ratio  # noqa: E402
from ..data.units import display_unit, label, to_display
from .build import atomic_folder, write_json  # noqa: E402
from .figure import render_pngs, subplots

__all__ = ["plot_fault_run", "plot_fault_case", "plot_sweep", "fault_analysis_to_dict", "write_fault_report"]

_FLAGS = (("trip_discrepancy", "discrepancy trip"), ("trip_lvdt", "LVDT trip"), ("trip_speed", "speed trip"),
          ("standby_active", "standby active\n(monitor's take-over)"), ("energised_standby", "standby energised"),
          ("safed", "safed"), ("brakes_engaged", "brakes on"),
          ("limiter_slipping", "limiter slipping"))


def _panels(t, get, r, N, title, fault_times=()):
    fig, axes = subplots(5, 1, figsize=(10, 12), sharex=True, constrained_layout=True)
    ax = axes[0]
    ax.plot(t, get("speed_cmd") * 1e3, "k--", lw=1, label="command")
    ax.plot(t, get("measured_motor_speed") * r * 1e3, label="motor sensor (x lead/2 pi N)")
    ax.plot(t, get("screw_speed") * N * r * 1e3, lw=0.9, label="RVDT (screw, x lead/2 pi)")
    ax.plot(t, get("surface_speed") * 1e3, lw=0.8, label="surface")
    ax.set_ylabel("speed [mm/s]")
    ax = axes[1]
    ax.plot(t, get("motor_torque") * N, label="motor torque x N")
    ax.plot(t, get("limiter_torque"), label="limiter (transmitted)")
    slip_t = get("limiter_slip_torque")
    if np.any(slip_t > 0):
        ax.plot(t, slip_t, "r:", lw=1, label="limiter slip torque")
        ax.plot(t, -slip_t, "r:", lw=1)
    ax.set_ylabel("torque at screw [N m]")
    ax = axes[2]
    ax.plot(t, get("loadpath_force") * 1e-3, label="primary load path")
    ax.plot(t, get("primary_attachment_force") * 1e-3, lw=0.9, label="upper gimbal (primary)")
    ax.plot(t, get("secondary_path_force") * 1e-3, lw=0.9, label="secondary path")
    ax.plot(t, get("jam_force") * 1e-3, lw=0.9, label="jam")
    ax.set_ylabel("force [kN]")
    ax = axes[3]
    ax.plot(t, get("monitor_discrepancy"), label="motor - RVDT [rad at screw]")
    ax.plot(t, get("gimbal_displacement") * 1e3, label="LVDT [mm]")
    ax.plot(t, get("monitor_speed_error") / 100.0, lw=0.8, label="speed error [100 rad/s]")
    ax.set_ylabel("monitored")
    ax = axes[4]
    for k, (sig, name) in enumerate(_FLAGS):
        ax.step(t, get(sig) * 0.8 + k, where="post", label=name)
    ax.set_yticks(range(len(_FLAGS)), [lab for _, lab in _FLAGS], fontsize=8)
    ax.set_xlabel("time [s]")
    for a in axes:
        for tf in fault_times:
            a.axvline(tf, color="k", lw=0.8, alpha=0.5)
        a.grid(True, alpha=0.3)
        if a is not axes[4]:
            a.legend(loc="upper left", fontsize=7)
    fig.suptitle("\n".join(textwrap.fill(line, 110) for line in title.split("\n")), fontsize=11)
    return fig


def plot_fault_run(result, *, title: str | None = None):
    """Speeds (command, motor sensor, RVDT, surface), torques, path forces, monitored quantities and flags.

    ``result`` is a run of the fault loop (it has the monitor signals).
    """
    p = result.params
    N, r = p.value("gear.ratio"), kinematic_ratio(p)
    faults = [float(s.rsplit(" at ", 1)[1].split()[0]) for s in result.info.get("faults", [])]
    return _panels(np.asarray(result.time), lambda n: np.asarray(result[n]), r, N,
                   title or f"{result.name}: faults {', '.join(result.info.get('faults', [])) or 'none'}", faults)


def plot_fault_case(case, params):
    """The figure of one :class:`FaultCase` (from 0.1 s before the fault to 0.6 s after)."""
    N, r = params.value("gear.ratio"), kinematic_ratio(params)
    s = case.series
    title = f"{case.title}: {', '.join(case.faults)} at {case.fault_time_s:g} s"
    if case.takeover_source == "schedule":
        title += "\n(standby enabled by the scenario's schedule: the monitors only watch, their take-over flag stays low)"
    fig = _panels(s["time"], lambda n: np.asarray(s[n]) if n in s else np.zeros_like(s["time"]), r, N, title,
                  (case.fault_time_s,))
    fig.axes[0].plot(s["time"], s["nut_speed_no_fault"] * 1e3, color="0.5", lw=0.8, label="nut, no fault")
    fig.axes[0].legend(loc="upper left", fontsize=7)
    return fig


def plot_sweep(analysis, axes=None):
    """Detection time of each fault scenario vs threshold scale (false alarms marked); recovery vs take-over delay.

    ``axes``: two Axes (default a new figure).
    """
    pts = list(analysis.sweep)  # detection does not depend on the take-over delay: any point of the scale
    if axes is None:
        fig, (ax, ax2) = subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    else:
        ax, ax2 = list(np.ravel(axes))
        fig = ax.figure
    names = sorted({n for p in pts for n in p.detection_s})
    scales = sorted({p.scale for p in pts})
    for n in names:
        y = [next((p.detection_s.get(n, math.nan) for p in pts if p.scale == s and n in p.detection_s), math.nan)
             for s in scales]
        ax.semilogy(scales, [v * 1e3 if math.isfinite(v) else np.nan for v in y], "o-", label=n)
    for s in scales:
        if any(p.normal_trips for p in pts if p.scale == s):
            ax.axvspan(s - 0.05, s + 0.05, color="tab:red", alpha=0.2)
    ax.set_xlabel("thresholds x scale (red: a normal scenario trips)")
    ax.set_ylabel("first trip after the fault [ms] (gap: missed)")
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    delays = sorted({p.delay_s for p in analysis.sweep})
    for n in sorted({n for p in analysis.sweep for n in p.recovery_s}):
        y = [next((p.recovery_s[n] for p in analysis.sweep if p.delay_s == d and abs(p.scale - 1.0) < 1e-12
                   and n in p.recovery_s), math.nan) for d in delays]
        ax2.plot([d * 1e3 for d in delays], [to_display("time", v) if math.isfinite(v) else np.nan for v in y], "o-",
                 label=n)
    ax2.set_xlabel("take-over delay after detection [ms] (thresholds x 1; rigid drive train)")
    ax2.set_ylabel(label("recovery time", "time"))
    ax2.legend(fontsize=7)
    ax2.grid(True, alpha=0.3)
    return fig


#: Monitor -> quantity of its monitored signal (display-unit table).
_MONITOR_QUANTITY = {"discrepancy": "angle", "lvdt": "position", "speed": "rotational_speed"}
_MONITOR_WHAT = {"discrepancy": "motor - RVDT angle at the screw", "lvdt": "upper-gimbal displacement (LVDT)",
                 "speed": "speed reference - motor speed"}


def monitor_display(monitor: str):
    """Display unit of a monitor's signal and threshold."""
    return display_unit(_MONITOR_QUANTITY.get(monitor, "dimensionless"))


def _setting_rows(settings) -> list:
    """Monitor settings with their units (thresholds in the monitored signal's display unit, times in ms)."""
    rows = []
    for key, value in settings.as_dict().items():
        monitor = key.split("_")[0]
        if isinstance(value, bool):
            rows.append([key, "yes" if value else "no", "-", ""])
        elif key.endswith("_threshold"):
            du = monitor_display(monitor)
            rows.append([key, f"{du.to_display(value):.4g}", du.unit, _MONITOR_WHAT.get(monitor, "")])
        else:
            rows.append([key, f"{to_display('time', value):.4g}", display_unit("time").unit, ""])
    return rows


def _num(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None if math.isnan(v) else ("inf" if v > 0 else "-inf")
    return v


def _case_dict(c):
    return {"scenario": c.scenario, "faults": list(c.faults), "fault_time_s": c.fault_time_s,
            "detection_s": {k: _num(v) for k, v in c.detection_s.items()}, "first_monitor": c.first_monitor,
            "takeover_s": _num(c.takeover_s), "safed_s": _num(c.safed_s),
            "peaks_after_fault": c.peaks, "peaks_before_fault": c.peaks_before,
            "surface_displacement_m": c.surface_displacement_m, "surface_excursion_m": c.surface_excursion_m,
            "limiter_slip_rad": c.limiter_slip_rad, "recovery_s": _num(c.recovery_s),
            "peak_speed_error_m_s": c.peak_speed_error_m_s, "peak_position_error_m": c.peak_position_error_m,
            "energy_residual": c.energy_residual, "final_motor_speed_rad_s": c.final_motor_speed}


def fault_analysis_to_dict(a) -> dict:
    """JSON-able numbers of a :class:`FaultAnalysis` (inf as ``"inf"``, nan as null)."""
    return {
        "format": "thsa-faults/1", "level": a.level, "effects": list(a.effects), "monitors": a.monitors.as_dict(),
        "recovery_tolerance": a.tolerance, "recovery_smoothing_s": a.smooth_s,
        "cases": [_case_dict(c) for c in a.cases], "rigid_drive_train_cases": [_case_dict(c) for c in a.rigid_cases],
        "false_alarm_margins": [{"scenario": m.scenario, "monitor": m.monitor, "threshold": m.threshold,
                                 "persisted_level": m.persisted, "margin": _num(m.margin), "tripped": m.tripped}
                                for m in a.margins],
        "min_margin": {m: _num(a.min_margin(m)) for m in sorted({x.monitor for x in a.margins})},
        "sweep": [{"scale": p.scale, "takeover_delay_s": p.delay_s, "normal_trips": list(p.normal_trips),
                   "detection_s": {k: _num(v) for k, v in p.detection_s.items()},
                   "recovery_s": {k: _num(v) for k, v in p.recovery_s.items()}} for p in a.sweep],
        "normal_energy_residual": a.normal_energy_residual,
    }


def _ms(v):
    return "-" if not math.isfinite(v) else f"{v * 1e3:.1f}"


def _table(head, rows):
    out = ["<table border='1' cellspacing='0' cellpadding='3'><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>")
    return "\n".join(out) + "</table>"


def _case_rows(cases):
    rows = []
    for c in cases:
        takeover = _ms(c.takeover_s) + (" (scheduled)" if c.takeover_source == "schedule" else "")
        rows.append([c.scenario, ", ".join(c.faults), f"{c.fault_time_s:g}", _ms(c.detection_s["discrepancy"]),
                     _ms(c.detection_s["lvdt"]), _ms(c.detection_s["speed"]), takeover, _ms(c.safed_s),
                     f"{c.peaks['loadpath'] / 1e3:.1f}", f"{c.peaks['primary_attachment'] / 1e3:.1f}",
                     f"{c.peaks['secondary_path'] / 1e3:.1f}", f"{c.peaks['jam'] / 1e3:.1f}",
                     f"{c.peaks['limiter_torque']:.0f}", f"{to_display('angle', c.limiter_slip_rad):.1f}",
                     f"{c.surface_displacement_m * 1e3:.2f}", "-" if math.isnan(c.recovery_s) else _ms(c.recovery_s),
                     f"{c.energy_residual * 100:.3f}"])
    return rows


_CASE_HEAD = ["scenario", "faults", "onset [s]", "discrepancy trip [ms]", "LVDT trip [ms]", "speed trip [ms]",
              "take-over [ms]", "safed [ms]", "load path [kN]", "upper gimbal [kN]", "secondary [kN]", "jam [kN]",
              "limiter [N m]", "limiter slip [deg]", "surface displacement [mm]", "recovery [ms]", "energy residual [%]"]


def _sweep_block(analysis) -> str:
    """The sweep: one line for the false alarms when no normal scenario trips anywhere, then the table."""
    if not analysis.sweep:
        return "<p class='note'>Sweep not run (--no-sweep).</p>"
    any_trip = any(p.normal_trips for p in analysis.sweep)
    head = ["threshold scale [-]", "take-over delay [ms]"] + (["normal scenarios tripping"] if any_trip else []) + [
        "first trip [ms]", "recovery [ms]"]
    rows = [[f"{p.scale:g}", f"{p.delay_s * 1e3:g}"] + ([", ".join(p.normal_trips) or "none"] if any_trip else [])
            + ["; ".join(f"{k}: {_ms(v)}" for k, v in p.detection_s.items()),
               "; ".join(f"{k}: {_ms(v)}" for k, v in p.recovery_s.items())] for p in analysis.sweep]
    scales = sorted({p.scale for p in analysis.sweep})
    line = ("" if any_trip else f"<p>No normal scenario trips a monitor at any threshold scale "
            f"({', '.join(f'{x:g}' for x in scales)}) or take-over delay: no false alarm in the sweep.</p>")
    return line + _table(head, rows)


def write_fault_report(analysis, params, out_dir, *, progress=None, **folder_options) -> Path:
    """Write ``faults.json``, ``report.html`` and the figures (PNG) to ``out_dir`` (atomically).

    ``folder_options`` go to :func:`~thsa_control.report.build.atomic_folder` (``force``, ``inputs``);
    ``progress`` (a :class:`thsa_control.progress.Progress` or None) gets a line per figure.
    """
    with atomic_folder(out_dir, **folder_options) as tmp:
        figs = []  # (file name, caption, (function, arguments), progress text): drawn in parallel (figure.render_pngs)
        for c in analysis.cases + analysis.rigid_cases:
            name = f"case_{c.scenario}{'_rigid' if c in analysis.rigid_cases else ''}.png"
            figs.append((name, f"{c.title}: {', '.join(c.faults)}", (plot_fault_case, (c, params)),
                         f"figure of {c.title}: {c.scenario}"))
        if analysis.sweep:
            figs.append(("sweep.png", "monitor sweep", (plot_sweep, (analysis,)), "figure of the monitor sweep"))

        def done(i: int) -> None:
            if progress is not None:
                progress.step(i + 1, len(figs), figs[i][3])

        pngs = render_pngs([f[2] for f in figs], dpi=100, done=done)
        figs = [(name, png, caption) for (name, caption, _job, _text), png in zip(figs, pngs)]
        if progress is not None:
            progress.phase("faults.json and report.html (figures embedded)")
        for name, png, _caption in figs:  # each figure drawn once: the same PNG is the file and the page's image
            (tmp / name).write_bytes(png)
        write_json(tmp / "faults.json", fault_analysis_to_dict(analysis))
        m = analysis.monitors
        css = ("body{font-family:system-ui,Segoe UI,Helvetica,Arial,sans-serif;max-width:1250px;margin:1em auto;color:#222}"
               "table{border-collapse:collapse;margin:0.4em 0}td,th{font-size:12px;border:1px solid #ccc;padding:2px 6px}"
               "th{background:#f0f0f0}h2{font-size:1.15em;border-bottom:1px solid #ccc;scroll-margin-top:2.6em}"
               "nav{position:sticky;top:0;background:#fff;border-bottom:1px solid #ccc;padding:6px 0;font-size:13px}"
               "nav a{margin-right:1em;color:#1a4f8b;text-decoration:none}.note{font-size:12px;color:#555}"
               "img{max-width:100%}")
        nav = ("<nav><a href='#table-cases'>Fault cases</a><a href='#table-rigid'>Rigid drive train</a>"
               "<a href='#table-margins'>False-alarm margins</a><a href='#table-sweep'>Sweep</a>"
               "<a href='#settings'>Monitor settings</a><a href='#figures'>Figures</a></nav>")
        scheduled = [c.title for c in analysis.rigid_cases if c.takeover_source == "schedule"]
        worst_margin = min(((mon, analysis.min_margin(mon)) for mon in sorted({x.monitor for x in analysis.margins})),
                           key=lambda p: p[1], default=None)
        parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>Faults and monitoring</title>",
                 f"<style>{css}</style></head><body>", nav,
                 "<h1>Faults and monitoring (model F)</h1>",
                 f"<p>Plant: level {html.escape(analysis.level)} + {html.escape(', '.join(analysis.effects))}. "
                 "Monitors in the closed loop at the control period. Times from the fault onset, in ms. "
                 f"Recovery: centred {analysis.smooth_s * 1e3:.0f} ms average of the nut-speed error against the run "
                 f"without the fault within {analysis.tolerance * 100:.0f} % of the command."
                 + (f" Smallest false-alarm margin: <b>{html.escape(worst_margin[0])} {worst_margin[1]:.2f}</b> "
                    "(threshold / level held on a normal scenario; above 1: no false alarm)." if worst_margin else "")
                 + "</p>",
                 "<h2 id='table-cases'>Fault cases (fault plant)</h2>", _table(_CASE_HEAD, _case_rows(analysis.cases)),
                 "<h2 id='table-rigid'>Channel failures on a rigid drive train (papers' comparison; recovery without averaging)</h2>",
                 _table(_CASE_HEAD, _case_rows(analysis.rigid_cases)),
                 ("<p class='note'>The cases named <code>*_papers_15ms</code> enable the standby channel by the "
                  "scenario's schedule 15 ms after the fault, as the papers do, with the monitors watching only "
                  "(no reconfiguration): their flag 'standby active' is the reconfiguration logic's and stays low, "
                  "although the standby drives and the torque recovers; the take-over time shown is the schedule's "
                  "('scheduled'), and the figures show the channel's enable as 'standby energised'.</p>"
                  if scheduled else ""),
                 "<h2 id='table-margins'>False-alarm margins on the normal scenarios</h2>",
                 _table(["scenario", "monitor", "monitored signal", "threshold", "level held for the confirmation time",
                         "unit", "margin [-]", "tripped"],
                        [[x.scenario, x.monitor, _MONITOR_WHAT.get(x.monitor, ""),
                          f"{monitor_display(x.monitor).to_display(x.threshold):.4g}",
                          f"{monitor_display(x.monitor).to_display(x.persisted):.4g}", monitor_display(x.monitor).unit,
                          "inf" if not math.isfinite(x.margin) else f"{x.margin:.2f}", "yes" if x.tripped else "no"]
                         for x in analysis.margins]),
                 "<h2 id='table-sweep'>Sweep</h2>", _sweep_block(analysis),
                 "<h2 id='settings'>Monitor settings</h2>",
                 _table(["setting", "value", "unit", "monitored signal"], _setting_rows(m)),
                 "<h2 id='figures'>Figures</h2>"]
        for name, png, caption in figs:
            data = base64.b64encode(png).decode()
            parts.append(f"<figure id='fig-{html.escape(name[:-4])}'><img alt='{html.escape(caption)}' "
                         f"src='data:image/png;base64,{data}'><figcaption>{html.escape(caption)}</figcaption></figure>")
        parts.append("</body></html>\n")
        (tmp / "report.html").write_text("\n".join(parts), encoding="utf-8")
    return Path(out_dir)
