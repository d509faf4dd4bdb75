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
import re
from pathlib import Path

import numpy as np  # noqa: E402

from ..data.units import display_unit, label, to_display
from ..loops.analysis import (  # noqa: E402
    LOOPS,
    METRIC_LABELS,
    DesignAnalysis,
    check_requirements,
)
from ..loops.requirements import REQUIREMENT_METRICS
from .analysis_json import ANALYSIS_FORMAT, analysis_to_dict  # noqa: E402
from .analysis_plots import (  # noqa: E402
    _LOOP_TITLE,
    plot_friction_slopes,
    plot_loop_bode,
    plot_margin_maps,
    plot_steps,
    plot_switching,
    plot_velocity_poles,
)
from .build import atomic_folder, write_json  # noqa: E402
from .display import (
    GAIN_MARGIN_MEANING,
    NEAR_FRACTION,
    fmt,
    fmt_metric,
    gain_margins_text,
    metric_display,
    metric_heading,
    requirement_status,
    requirement_text,
)
from .figure import render_pngs

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

#: Figures of the report (HTML ids ``fig-<name>``, files ``figures/<name>.png``).
FIGURES = ("requirements_spare", "bode_current_loop", "bode_velocity_loop", "bode_position_loop", "step_responses", "margin_maps",
           "velocity_poles", "friction_slopes", "switching_transient")
#: Tables of the report (HTML ids ``table-<name>``).
TABLES = ("at_a_glance", "requirements", "worst_points", "margins_current_loop", "margins_velocity_loop", "margins_position_loop",
          "invalid_points", "stribeck_points", "limit_cycles", "configurations", "switching_recovery")

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
details{margin:0.5em 0}summary{cursor:pointer;font-weight:600}.note{font-size:12px;color:#555}
.scroll{overflow-x:auto;max-width:100%}th{max-width:11em;white-space:normal;vertical-align:bottom}
td.why{max-width:28em;white-space:normal;text-align:left;color:#555}
nav{position:sticky;top:0;background:#fff;border-bottom:1px solid #ccc;padding:6px 0;z-index:5;font-size:13px}
nav a{margin-right:1.1em;color:#1a4f8b;text-decoration:none;white-space:nowrap}nav a:hover{text-decoration:underline}
.verdict{font-size:1.15em;padding:8px 12px;border-radius:4px;display:inline-block;margin:0.3em 0}
.verdict.ok{background:#e3f4e5;border:1px solid #a5d6a7}.verdict.bad{background:#fde7e6;border:1px solid #ef9a9a}
td.near{background:#fff3c4}h2{scroll-margin-top:2.6em}p.fold{font-size:13px;margin:0.3em 0}
"""


_fmt = fmt
#: A cell that reads as a number (right-aligned); anything else is text (left-aligned).
_NUMBER = re.compile(r"^\s*([-+]?(\d|\.\d|inf)[\w.+\-%/ ]{0,14}|-|yes|no|NO|PASS|FAIL)\s*$")

#: Sections of the page: (HTML id, title in the navigation bar).
SECTIONS = (("summary", "Summary"), ("requirements", "Requirements"), ("worst", "Worst points"),
            ("bode", "Bode"), ("steps", "Steps"), ("maps", "Margin maps"), ("poles", "Poles"),
            ("friction", "Friction"), ("switching", "Switch-over"), ("configurations", "Active/standby"),
            ("invalid", "Invalid points"), ("limit-cycles", "Limit cycles"))


def _nav(extra=()) -> str:
    links = "".join(f"<a href='#{i}'>{html.escape(t)}</a>" for i, t in tuple(SECTIONS) + tuple(extra))
    return f"<nav id='toc'>{links}</nav>"


def _h2(section: str, title: str) -> str:
    return f"<h2 id='{section}'>{html.escape(title)}</h2>"


def _folded(line: str, body: str) -> str:
    """A table folded into one line (empty or uniform): the line shows, the table opens on a click."""
    return f"<details class='fold'><summary>{html.escape(line)}</summary>\n{body}\n</details>"


def _table(name: str, header, rows, classes=None, caption: str = "", left=()) -> str:
    """HTML table; ``rows`` of cells (str), ``classes`` per row: (row class, [cell classes])."""
    out = [f'<div class="scroll"><table id="table-{name}">']
    if caption:
        out.append(f"<caption class='note' style='caption-side:top;text-align:left'>{html.escape(caption)}</caption>")
    out.append("<tr>" + "".join(f"<th class='l'>{html.escape(h)}</th>" if i == 0 or i in left else f"<th>{html.escape(h)}</th>"
                                 for i, h in enumerate(header)) + "</tr>")
    for i, row in enumerate(rows):
        rcls, ccls = (classes[i] if classes else ("", None))
        cells = []
        for j, cell in enumerate(row):
            cls = [] if ccls is None or not ccls[j] else [ccls[j]]
            if j == 0 or j in left or (isinstance(cell, str) and not _NUMBER.match(cell)):
                cls.append("l")
            attr = f" class='{' '.join(cls)}'" if cls else ""
            cells.append(f"<td{attr}>{cell}</td>")
        out.append(f"<tr class='{rcls}'>" + "".join(cells) + "</tr>")
    out.append("</table></div>")
    return "\n".join(out)


_MARGIN_COLUMNS = ("crossover_hz", "phase_margin_deg", "gain_margin_lower_db", "gain_margin_upper_db",
                   "delay_margin_s", "bandwidth_hz", "ms", "rise_time_s", "settling_time_s", "overshoot_percent",
                   "load_step_peak", "load_step_recovery_s")


def _details(summary: str, body: str, *, open_: bool = False) -> str:
    """A collapsible section (long per-point tables)."""
    return (f"<details{' open' if open_ else ''}><summary>{html.escape(summary)}</summary>\n{body}\n</details>")


def _header(loop: str, name: str) -> str:
    return metric_heading(loop, name)


def _margin_table(result: DesignAnalysis, loop: str) -> str:
    a = result.loops
    lm = a.loops[loop]
    cols = [c for c in _MARGIN_COLUMNS if not (loop == "current_loop" and c.startswith("load_step"))]
    fails: dict[int, set[str]] = {}
    gm = lm.margins.gain_margin_db
    for v in result.requirements.violations:
        if v.loop == loop:
            metric = v.metric
            if metric == "gain_margin_db":  # the margin nearest 0 dB: the lower one when negative
                metric = "gain_margin_lower_db" if gm[v.index] < 0 else "gain_margin_upper_db"
            fails.setdefault(v.index, set()).add(metric)
    worst = {name: a.worst(loop, name) for name in cols}
    worst_pm = worst.get("phase_margin_deg")
    rows, classes = [], []
    for k, c in enumerate(a.conditions):
        row = [html.escape(f"{c.nut_speed * 1e3:g}"), html.escape(f"{c.load_force * 1e-3:g}"),
               html.escape(f"{c.temperature:g}"), "yes" if a.valid[k] else "no",
               html.escape("; ".join(r.split(":")[0] for r in a.reasons[k])) or "-",
               ("yes" if lm.stable[k] else "NO") if a.valid[k] else "-"]
        ccls = ["", "", "", "", "why", ""]
        if not lm.stable[k] and a.valid[k]:
            ccls[5] = "fail"
        for name in cols:
            val = lm.metric(name)[k]
            row.append(fmt_metric(loop, name, val) if a.valid[k] else "-")
            cl = ""
            if a.valid[k] and name in fails.get(k, ()):
                cl = "fail"
            w = worst.get(name)
            if w is not None and w.index == k and not w.uniform:
                cl = (cl + " worst").strip()
            ccls.append(cl)
        rcls = "invalid" if not a.valid[k] else ("worstrow" if worst_pm is not None and worst_pm.index == k
                                                    and not worst_pm.uniform else "")
        rows.append(row)
        classes.append((rcls, ccls))
    header = [label("speed", "nut_speed"), label("load", "force"), label("T", "temperature"), "valid",
              "invalid because", "stable"] + [
        _header(loop, n) for n in cols]
    cap = (f"{_LOOP_TITLE[loop]}: every grid point. Red: requirement not met; bold yellow: worst valid point of the "
           "column; framed row: worst phase margin; grey rows: not analysed (invalid linearisation or saturated "
           "controller; no numbers, not checked).")
    return _table(f"margins_{loop}", header, rows, classes, cap)


def _glance(result: DesignAnalysis) -> str:
    """The table a reader sees first: per loop, the worst margins and where."""
    a = result.loops
    rows = []
    for loop in LOOPS:
        lm = a.loops[loop]
        m = lm.margins

        def worst(name, digits=4):
            w = a.worst(loop, name)
            if w is None:
                return "-", ""
            where = "every point" if w.uniform else w.condition.label()
            return fmt_metric(loop, name, w.value, digits, unit=True), where
        pm, pm_at = worst("phase_margin_deg")
        wg = a.worst(loop, "gain_margin_db")
        gm = gain_margins_text(m.gain_margin_lower_db[wg.index], m.gain_margin_upper_db[wg.index]) if wg else "-"
        gm_at = ("every point" if wg.uniform else wg.condition.label()) if wg else ""
        ms, ms_at = worst("ms")
        bw, _ = worst("bandwidth_hz")
        xo, _ = worst("crossover_hz")
        rows.append([_LOOP_TITLE[loop], xo, bw, f"{pm}<br><span class='note'>{html.escape(pm_at)}</span>",
                     f"{html.escape(gm)}<br><span class='note'>{html.escape(gm_at)}</span>",
                     f"{ms}<br><span class='note'>{html.escape(ms_at)}</span>"])
    return _table("at_a_glance", ["loop", "lowest gain crossover", "lowest bandwidth", "worst phase margin",
                                  "worst gain margins", "worst sensitivity peak Ms"], rows,
                  caption="Worst valid point of each margin over the grid (the point under each value). "
                          + GAIN_MARGIN_MEANING)


def _requirement_rows(result: DesignAnalysis):
    a, check = result.loops, result.requirements
    rows, classes = [], []
    for r in check.rows:
        where = "same at every valid point" if r.uniform else (r.worst_condition.label() if r.worst_condition else "-")
        if r.metric == "gain_margin_db" and r.worst_condition is not None:
            m = a.loops[r.loop].margins
            worst = gain_margins_text(m.gain_margin_lower_db[r.worst_index], m.gain_margin_upper_db[r.worst_index])
            if r.worst_value < 0:
                worst += " (lower: conditionally stable)"
        else:
            worst = fmt_metric(r.loop, r.metric, r.worst_value, unit=True)
        status = requirement_status([r.worst_value], r.limit, REQUIREMENT_METRICS[r.requirement][1])[0]
        verdict = "FAIL" if not r.passed else ("PASS (close to the limit)" if status == 1 else "PASS")
        rows.append([_LOOP_TITLE[r.loop], html.escape(requirement_text(r.loop, r.requirement, r.limit)),
                     html.escape(worst), html.escape(where), str(r.n_failed), verdict])
        classes.append(("", [""] * 5 + ["fail" if not r.passed else ("near" if status == 1 else "")]))
    return rows, classes


def _html(result: DesignAnalysis, figures: dict[str, bytes], verdict=None) -> str:
    a, d, check = result.loops, result.design, result.requirements
    lin = a.linearization
    extra_nav = (("tuning", "Tuning"),) if "objective_before" in (getattr(d, "tuning", None) or {}) else ()
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>THSA loop analysis: {html.escape(d.name)}"
             f"</title><style>{_CSS}</style></head><body>", _nav(extra_nav)]
    status = "<span class='pass'>PASS</span>" if check.passed else "<span class='failtxt'>FAIL</span>"
    parts.append(f"<h1 id='summary'>THSA loop analysis: design <code>{html.escape(d.name)}</code></h1>")
    n_fail = sum(1 for r in check.rows if not r.passed)
    parts.append(
        f"<p class='verdict {'ok' if check.passed else 'bad'}'>Requirements at every valid grid point: {status} "
        f"&mdash; {len(check.rows) - n_fail} of {len(check.rows)} requirements met at the "
        f"{check.checked_points} analysed points; {check.skipped_points} "
        f"point{'' if check.skipped_points == 1 else 's'} not analysed "
        f"(<a href='#invalid'>why</a>).</p>")
    if not check.passed:
        parts.append("<pre>" + html.escape(check.summary()) + "</pre>")
    if verdict is not None:  # --check: the verdict of thsa check on every requirement (linear + validation runs)
        from .check_report import verdict_section

        parts.append(verdict_section(verdict))
    parts.append(_glance(result))
    parts.append(
        f"<p class='note'>Design file <code>{html.escape(d.source)}</code>; control period "
        f"{d.control_period * 1e6:g} us, computation delay {d.computation_delay_samples} sample(s). Plant: "
        f"{html.escape(lin.model.describe())}. Grid: {len(a)} points ({int(a.valid.sum())} valid): speeds "
        f"{', '.join(f'{v:g}' for v in to_display('nut_speed', result.settings.nut_speeds))} "
        f"{display_unit('nut_speed').unit}, loads "
        f"{', '.join(f'{f:g}' for f in to_display('force', result.settings.load_forces))} "
        f"{display_unit('force').unit} (compressive positive: negative loads aid the positive motion), temperatures "
        f"{', '.join(f'{t:g}' for t in result.settings.temperatures)} {display_unit('temperature').unit}. "
        "Units: SI in <code>analysis.json</code> (each key names its unit), display units here.</p>")
    # requirements table
    rows, classes = _requirement_rows(result)
    parts.append(_h2("requirements", "Requirements"))
    parts.append(_table("requirements", ["loop", "requirement", "worst value", "worst point",
                                         "failing points", "result"], rows, classes, left=(1, 2, 3, 5), caption=
                        "Each requirement at every valid grid point. Amber: met within "
                        f"{NEAR_FRACTION:.0%} of the limit. A closed-loop-unstable valid point fails every "
                        "requirement. " + GAIN_MARGIN_MEANING))
    if "requirements_spare" in figures:
        b64 = base64.b64encode(figures["requirements_spare"]).decode("ascii")
        parts.append("<details><summary>Figure: how far each requirement's worst point is from its limit (click to "
                     f"open)</summary><figure id='fig-requirements_spare'><img alt='requirements_spare' "
                     f"src='data:image/png;base64,{b64}'><figcaption>Spare at the worst valid point, as a fraction of "
                     "the limit (below 0 fails; amber within "
                     f"{NEAR_FRACTION:.0%}).</figcaption></figure></details>")
    # worst points
    rows = []
    for w in a.worst_points():
        du = metric_display(w.loop, w.metric)
        rows.append([_LOOP_TITLE[w.loop], html.escape(METRIC_LABELS[w.metric]), fmt_metric(w.loop, w.metric, w.value),
                     html.escape(du.unit), "same at every valid point" if w.uniform else html.escape(w.condition.label()),
                     html.escape(w.note)])
    parts.append(_h2("worst", "Worst operating point of each metric"))
    parts.append(_details(f"Table: worst valid point of each metric ({len(rows)} rows; click to open)",
                          _table("worst_points", ["loop", "metric", "value", "unit", "where", "note"], rows)))
    # figures
    captions = {
        "bode_current_loop": "Current loop: discrete PI around the ZOH RL plant of the linearisation.",
        "bode_velocity_loop": "Velocity loop: discrete PI around current reference -> motor speed, closed current "
                              "loop, ZOH and back-EMF inside.",
        "bode_position_loop": "Position-monitoring loop: P gain and the shaper's one-sample delay around the closed "
                              "velocity loop and the nut kinematics.",
        "step_responses": "Step responses of the three loops (linear, discrete) and the response to a load step.",
        "margin_maps": "Velocity-loop phase margin, gain margin and Ms over speed and load at each temperature, "
                       "coloured against the design's requirements (red fails, amber within "
                       f"{NEAR_FRACTION:.0%} of the limit, green passes with room).",
        "velocity_poles": "Closed-loop poles of the velocity loop at every valid grid point, coloured by temperature.",
        "friction_slopes": "Local friction slope and net damping at the motor shaft: negative slopes (Stribeck "
                           "region) remove damping and destabilise the mechanical mode.",
        "switching_transient": "Nonlinear switch-over transient (primary off, standby on after a detection delay).",
    }
    for name in FIGURES:
        if name == "requirements_spare":
            continue  # in the requirements section
        if name == "bode_current_loop":
            parts.append(_h2("bode", "Open-loop Bode plots across temperature"))
        if name == "step_responses":
            parts.append(_h2("steps", "Step responses"))
        if name == "margin_maps":
            parts.append(_h2("maps", "Margins over the grid"))
        if name == "velocity_poles":
            parts.append(_h2("poles", "Velocity loop poles over temperature"))
        if name == "friction_slopes":
            parts.append(_h2("friction", "Friction: Stribeck region"))
        if name == "switching_transient":
            parts.append(_h2("switching", "Active/standby switch-over"))
        if name in figures:
            b64 = base64.b64encode(figures[name]).decode("ascii")
            parts.append(f"<figure id='fig-{name}'><img alt='{name}' src='data:image/png;base64,{b64}'>"
                         f"<figcaption>{html.escape(captions[name])}</figcaption></figure>")
        else:
            parts.append(f"<p class='note' id='fig-{name}'>{name}: not computed (switch-over analysis not run).</p>")
        if name == "margin_maps":
            for loop in LOOPS:
                parts.append(_details(f"Table: {_LOOP_TITLE[loop]} at every grid point ({len(a)} rows; "
                                      "click to open)", _margin_table(result, loop)))
        if name == "friction_slopes":
            rows = []
            for k in np.flatnonzero(a.valid & (lin.stribeck | (lin.net_damping < 0))):
                vl = a.loops["velocity_loop"]
                rows.append([html.escape(a.conditions[k].label()), _fmt(lin.friction_slope[k] * 1e3),
                             _fmt(lin.net_damping[k] * 1e3), "yes" if lin.net_damping[k] < 0 else "no",
                             _fmt(vl.margins.phase_margin_deg[k]), _fmt(vl.margins.gain_margin_db[k]),
                             _fmt(vl.step_info.overshoot_percent[k])])
            fold = (f"No valid point with a negative friction slope or net damping ({int(a.valid.sum())} points)."
                    if not rows else f"Table: Stribeck points ({len(rows)} rows; click to open)")
            parts.append(_details(fold, _table(
                "stribeck_points", ["point", "friction slope [mN m s/rad]", "net damping [mN m s/rad]",
                                    "unstable mechanical mode", "velocity PM [deg]",
                                    "velocity GM nearest 0 dB [dB]", "velocity overshoot [%]"],
                rows, caption=f"{len(rows)} valid points with a negative friction slope or net "
                              "damping (destabilising; the velocity loop must stabilise them).")))
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
    parts.append(_h2("configurations", "Active/standby configurations (linear models)"))
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
                    why = "; ".join(r.split(":")[0] for r in la.reasons[k])
                    rows.append([html.escape(name), loop, html.escape(c.label()), html.escape(why) or "-",
                                 f(lm.margins.crossover_hz[k]), f(lm.margins.phase_margin_deg[k]),
                                 f(lm.margins.gain_margin_lower_db[k]), f(lm.margins.gain_margin_upper_db[k]),
                                 f(lm.margins.bandwidth_hz[k]), f(lm.margins.ms[k]),
                                 ("yes" if lm.stable[k] else "NO") if la.valid[k] else "-",
                                 ("PASS" if ok else "FAIL") if loop in d.requirements and la.valid[k] else "-"])
                    classes.append(("" if la.valid[k] else "invalid",
                                    ["", "", "", "why"] + [""] * 7 + ["" if ok or not la.valid[k] else "fail"]))
        parts.append(_details(f"Table: both configurations at every point ({len(rows)} rows)", _table(
            "configurations", ["configuration", "loop", "point", "invalid because", "gain crossover [Hz]",
                               "phase margin [deg]", "lower gain margin [dB]", "upper gain margin [dB]",
                               "closed-loop bandwidth [Hz]", "sensitivity peak Ms", "stable", "requirements"],
            rows, classes, caption="Both plants carry two rotors (standby_motor effect): the design, derived for "
                                   "one rotor, sees about twice the inertia.")))
    else:
        parts.append("<p class='note' id='table-configurations'>configurations: not computed.</p>")
    # invalid points
    rows = [[html.escape(c.label()), html.escape(" | ".join(reasons))] for c, reasons in a.invalid_points()]
    parts.append(_h2("invalid", "Invalid operating points"))
    parts.append(_details(f"Table: invalid points ({len(rows)} rows)", _table(
        "invalid_points", ["point", "why the linear model is not valid there"], rows,
        caption=f"{len(rows)} points: a linear model there would be silently wrong.")))
    # limit cycles
    rows = [[c.loop, c.nonlinearity, html.escape(c.condition.label()), "yes" if c.predicted else "no",
             _fmt(c.amplitude), html.escape(c.amplitude_unit), _fmt(c.frequency_hz), html.escape(c.note)]
            for c in result.limit_cycles]
    parts.append(_h2("limit-cycles", "Describing functions: predicted limit cycles"))
    predicted = [c for c in result.limit_cycles if c.predicted]
    table = _table(
        "limit_cycles", ["loop", "nonlinearity", "condition", "limit cycle", "amplitude", "unit", "frequency [Hz]",
                         "note"], rows,
        caption="Friction: the plant's set-valued friction vs motor speed around zero speed; "
                "backlash: the load-path play (2 x backlash) in the position feedback.")
    if predicted or not rows:
        parts.append(_details(f"Table: limit cycles ({len(rows)} rows, {len(predicted)} predicted)", table,
                              open_=bool(predicted)))
    else:  # uniform: one line
        kinds = sorted({f"{c.loop.replace('_', ' ')} / {c.nonlinearity}" for c in result.limit_cycles})
        parts.append(_folded(f"No limit cycle predicted at any of the {len(rows)} points checked "
                             f"({'; '.join(kinds)}). Click for the table.", table))
    from .tuning_report import (
        tuning_section,  # before/after of a tuned design (issue #9)
    )
    parts.append(tuning_section(d))
    notes = "; ".join(f"{k} {v:.2f} s" for k, v in result.timings.items())
    parts.append(f"<p class='note'>Computed in: {html.escape(notes)}.</p></body></html>")
    return "\n".join(parts)


def write_analysis_report(result: DesignAnalysis, out_dir: str | Path, *, force: bool = False,
                          inputs: tuple | list = (), verdict=None) -> Path:
    """Write ``report.html`` (figures embedded), ``analysis.json`` and ``figures/*.png`` to ``out_dir``.

    With ``verdict`` (:class:`thsa_control.verdict.Verdict`, ``thsa report --check``) the page shows it and
    ``check.json`` holds it, as ``thsa check --out`` writes it.

    The folder is replaced atomically: on failure nothing is written.

    Parameters
    ----------
    result : DesignAnalysis
    out_dir : path-like
    force, inputs
        Passed to :func:`~thsa_control.report.build.atomic_folder` (which folders may be replaced).

    Returns
    -------
    pathlib.Path
        The folder written.
    """
    jobs = {  # figure name -> (function, arguments); drawn in parallel processes (figure.render_pngs)
        "requirements_spare": (result.requirements.plot, ()),
        "bode_current_loop": (plot_loop_bode, (result.loops, "current_loop")),
        "bode_velocity_loop": (plot_loop_bode, (result.loops, "velocity_loop")),
        "bode_position_loop": (plot_loop_bode, (result.loops, "position_loop")),
        "step_responses": (plot_steps, (result.loops,)),
        "velocity_poles": (plot_velocity_poles, (result.loops,)),
        "friction_slopes": (plot_friction_slopes, (result.loops,)),
    }
    if result.loops.grid is not None:
        jobs["margin_maps"] = (plot_margin_maps, (result.loops,))
    if result.switching is not None:
        jobs["switching_transient"] = (plot_switching, (result.switching,))
    figures = dict(zip(jobs, render_pngs(jobs.values(), dpi=100)))
    doc = analysis_to_dict(result)
    page = _html(result, figures, verdict)
    with atomic_folder(out_dir, force=force, inputs=inputs, command="thsa report") as tmp:
        (tmp / "figures").mkdir()
        for name, data in figures.items():
            (tmp / "figures" / f"{name}.png").write_bytes(data)
        (tmp / "report.html").write_text(page, encoding="utf-8")
        write_json(tmp / "analysis.json", doc)
        if verdict is not None:
            write_json(tmp / "check.json", verdict.as_dict())
    return Path(out_dir).resolve()
