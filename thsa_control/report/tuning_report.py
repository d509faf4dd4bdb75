"""Before/after section of a tuned design (``[tuning]`` provenance written by ``thsa tune``) for ``thsa report``.

Tables only, from the numbers the design file records: the objective and its
runs, the solver statistics of every start, the validation metrics of each run
(speed error in % as the papers define it, ISE, overshoot, settling, current
peak and rate) and the velocity-loop margins over temperature, source design
against tuned design.  A design without a ``[tuning]`` table gives no section.
"""

from __future__ import annotations

import html

__all__ = ["tuning_section", "plot_before_after"]

_METRICS = (("speed_error_percent", "speed error [%]"), ("ise", "ISE [(mm/s)^2 s]"),
            ("overshoot_percent", "overshoot [%]"), ("settling_time_s", "settling [s]"),
            ("current_peak_A", "current peak [A]"), ("current_rate_peak_A_per_s", "current rate peak [A/s]"))


def _f(x) -> str:
    if isinstance(x, (int, float)):
        return "never" if x == -1.0 else f"{x:.4g}"
    return html.escape(str(x))


def _table(tid: str, header, rows) -> str:
    out = [f'<table id="table-{tid}"><tr>' + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def tuning_section(design) -> str:
    """HTML of the before/after section of ``design`` (empty string when it was not tuned)."""
    t = getattr(design, "tuning", None) or {}
    if "objective_before" not in t:
        return ""
    parts = ["<h2 id='tuning'>Tuned design: before / after</h2>",
             f"<p>Tuned from <code>{html.escape(str(t.get('source_design')))}</code> by "
             f"{html.escape(str(t.get('written_by')))}: {html.escape(', '.join(t.get('tuned', [])))} on "
             f"{html.escape(', '.join(t.get('scenarios', [])))} at {_f(t.get('temperature_C'))} degC, level "
             f"{html.escape(str(t.get('level')))} + {html.escape(', '.join(t.get('effects', [])))}; margins kept at "
             f"{html.escape(', '.join(f'{x:g}' for x in t.get('robust_temperatures_C', [])))} degC. Objective: "
             f"{html.escape(str(t.get('objective')))}. Constraints: {html.escape(str(t.get('constraints')))}.</p>",
             f"<p>Objective {_f(t['objective_before'])} &rarr; {_f(t['objective_after'])} "
             f"(<b>{_f(t.get('reduction_percent'))} % lower</b>); {html.escape(str(t.get('solver')))}: "
             f"{html.escape(str(t.get('status')))}, {t.get('iterations')} iterations, {_f(t.get('wall_s'))} s "
             f"(all starts and checks); best start {html.escape(str(t.get('best_start')))}. Gains "
             + ", ".join(f"{html.escape(n)} {_f(b)} &rarr; {_f(a)}" for n, b, a in
                         zip(t.get("tuned", []), t.get("gains_before", []), t.get("gains_after", []))) + ".</p>"]
    rows = [[html.escape(s["start"]), html.escape(s["status"]), str(s["iterations"]), _f(s["wall_s"]),
             _f(s["relative_objective"]), ", ".join(_f(g) for g in s["initial_gains"]),
             ", ".join(_f(g) for g in s["gains"]), html.escape(s["worst_constraint"]),
             _f(s["worst_constraint_value"])] for s in t.get("starts", [])]
    parts.append(_table("tuning_starts", ["start", "IPOPT status", "iterations", "time [s]", "J / J0",
                                          "initial gains", "final gains", "closest constraint", "its value"], rows))
    mb, ma = t.get("metrics_before", {}), t.get("metrics_after", {})
    rows = []
    for run in mb:
        rows.append([html.escape(run)] + [f"{_f(mb[run][k])} &rarr; {_f(ma.get(run, {}).get(k, '-'))}"
                                          for k, _ in _METRICS])
    if rows:
        parts.append(_table("tuning_metrics", ["run (source → tuned)"] + [h for _, h in _METRICS], rows))
    rows = []
    for b, a in zip(t.get("margins_before", []), t.get("margins_after", [])):
        rows.append([_f(b["temperature_C"]), f"{_f(b['phase_margin_deg'])} &rarr; {_f(a['phase_margin_deg'])}",
                     f"{_f(b['gain_margin_db'])} &rarr; {_f(a['gain_margin_db'])}",
                     f"{_f(b['sensitivity_peak'])} &rarr; {_f(a['sensitivity_peak'])}", html.escape(a["worst_point"])])
    parts.append(_table("tuning_margins", ["temperature [degC]", "phase margin [deg]", "|gain margin| [dB]",
                                           "Ms", "worst point (tuned)"], rows))
    weaker = [f"{r['temperature_C']:g} degC phase margin" for r, s in
              zip(t.get("margins_after", []), t.get("margins_before", [])) if r["phase_margin_deg"] < s["phase_margin_deg"]]
    weaker += [f"{run}: {h}" for run in mb for k, h in _METRICS
               if k != "ise" and isinstance(ma.get(run, {}).get(k), float) and ma[run][k] > mb[run][k] * 1.001]
    if weaker:
        parts.append("<p class='note'>Where the tuned design is weaker than the source: "
                     + html.escape("; ".join(weaker)) + ".</p>")
    if "verdict" in t:
        parts.append(f"<p>Verdict of <code>thsa check</code> on every requirement when it was written: "
                     f"<b>{html.escape(str(t['verdict']))}</b> after {len(t.get('rounds', []))} round(s) "
                     "(the verdict section of this report, with --check, judges it again).</p>")
        rows = [[str(r["round"]), ", ".join(_f(g) for g in r["gains"]), html.escape("; ".join(r["constraint_runs"])),
                 html.escape(", ".join(r["failing"]) or "none")] for r in t.get("rounds", [])]
        parts.append(_table("tuning_rounds", ["round", "gains", "constraint runs", "requirements not met"], rows))
    rob = t.get("robustness")
    if rob:
        parts.append(f"<h3>Robustness beyond the grid</h3><p>Worst velocity-loop margins over the grid at "
                     f"{html.escape(', '.join(f'{x:g}' for x in rob['margin_temperatures_C']))} degC and the ISE of "
                     f"{html.escape(rob['scenario'])} at {_f(rob['temperature_C'])} degC, source and tuned design, "
                     "under each case.</p>")
        rows = [[html.escape(r["case"]), html.escape(r["design"]), _f(r["phase_margin_deg"]), _f(r["gain_margin_db"]),
                 _f(1e3 * r["delay_margin_s"]), _f(r["sensitivity_peak"]), str(r["unstable_points"]),
                 "-" if r["cold_ise"] == -1.0 else _f(r["cold_ise"])] for r in rob["rows"]]
        parts.append(_table("tuning_robustness", ["case", "design", "PM [deg]", "|GM| [dB]", "DM [ms]", "Ms",
                                                  "unstable points", "cold ISE [(mm/s)^2 s]"], rows))
        flags = rob.get("flagged", [])
        parts.append("<p class='note'>" + (("FLAG: " + html.escape("; ".join(flags))) if flags else
                                           "The tuned design keeps its advantage in every case.")
                     + "".join(f"<br>Note: {html.escape(n)}" for n in rob.get("notes", [])) + "</p>")
    return "\n".join(parts)


def plot_before_after(before, after, *, signals=("nut_speed", "motor_current"), axes=None):
    """Runs of the source and tuned designs over each other: the speed against its command, the current.

    ``before``/``after``: sequences of :class:`~thsa_control.sim.simulate.SimulationResult` of the same runs.
    Returns the figure.
    """
    from .figure import subplots

    n = len(before)
    if axes is None:
        fig, axes = subplots(len(signals), n, figsize=(4.2 * n, 2.6 * len(signals)), squeeze=False,
                                 constrained_layout=True)
    else:
        fig = axes[0][0].figure
    for j, (b, a) in enumerate(zip(before, after)):
        for i, sig in enumerate(signals):
            ax = axes[i][j]
            scale, unit = (1e3, "mm/s") if sig.endswith("speed") else (1.0, b.units.get(sig, ""))
            if sig == "nut_speed":
                ax.plot(b.time, b["speed_cmd"] * scale, "k--", lw=0.8, label="command")
            ax.plot(b.time, b[sig] * scale, lw=1.0, label=f"source ({b.design.name})")
            ax.plot(a.time, a[sig] * scale, lw=1.0, label=f"tuned ({a.design.name})")
            ax.set_ylabel(f"{sig} [{unit}]")
            if i == 0:
                ax.set_title(b.name)
            if i == len(signals) - 1:
                ax.set_xlabel("time [s]")
            ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=7)
    return fig
