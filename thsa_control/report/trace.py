"""HTML report and ``trace.json`` of a residual trace (:func:`thsa_control.trace.trace`)."""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np  # noqa: E402

from .build import write_json  # noqa: E402
from .figure import subplots  # noqa: E402
from .identification import Html, figure_png, write_html_report  # noqa: E402

__all__ = ["write_trace_folder", "format_trace_summary", "plot_residual_before_after", "conclusion_table_html",
           "plot_candidate_drops", "plot_signature", "plot_periodicity", "plot_holding"]


def _num(x, fmt=".4g"):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def plot_residual_before_after(before: dict, after: dict, run_name: str, channel: str = "motor_speed"):
    """Segment residual of ``channel`` before and after the added effects."""
    from ..data.rigformat import COLUMNS

    spec = next((c for c in COLUMNS.values() if c.signal == channel), None)  # the rig format's unit (rpm, mm)
    fig, ax = subplots(figsize=(10, 3.2))
    for label, fit, kw in (("declared model", before, {"color": "0.6"}), ("with added effects", after, {"color": "C3"})):
        p = fit["predictions"][run_name]
        if channel not in p["measured"]:
            continue
        e = np.asarray(p["measured"][channel]) - np.asarray(p["simulated"][channel])
        ax.plot(p["time"][:e.size], spec.from_si(e) if spec else e, lw=0.7, label=label, **kw)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{channel} residual [{spec.unit if spec else 'SI'}]")
    ax.set_title(f"{run_name}: {channel} residual of the multiple-shooting segments")
    ax.legend(loc="upper right")
    return fig


def _outside(p: dict) -> str:
    """A determined parameter outside its assumed range (trace.json ``outside_assumed_range``), said beside it."""
    if not p.get("outside_assumed_range"):
        return ""
    lo, hi = p["assumed_range"]
    return f" (outside the assumed {_num(lo)}..{_num(hi)})"


def _ci(p: dict) -> str:
    ci = p.get("ci95")
    return f" [{_num(ci[0])}, {_num(ci[1])}]" if ci else ""


def conclusion_table_html(doc: dict) -> str:
    """The conclusion as a table: base corrections, found and implied effects, with parameters and intervals,
    each channel's error before -> after and what the run did not determine."""
    rows = []
    esc = html.escape
    for h in doc.get("declared_not_determined") or []:  # the declared model's own parameters the runs do not fix
        rows.append(("declared model", doc.get("base_model") or "functional",  # the first two cells escaped below
                     f"{esc(h['parameter'])} = {_num(h['held_at'])} {esc(h['unit'])} (held)", "-", "-",
                     f"{esc(h['parameter'])} held at {_num(h['held_at'])} {esc(h['unit'])}: {esc(h['reason'])}"))
    final = doc.get("final_parameters") or {}
    before = doc.get("declared_fit_before_base_step") or {}
    for n in doc.get("uncertain_parameters") or []:  # the declared uncertain set, as the final model has it
        if n not in final:
            continue
        p = final[n]
        b = before.get(n)
        was = (f"<br><small>fitted on the declared model alone, before the base step: {_num(b['value'])} "
               f"{esc(b['unit'])}</small>") if b and b["value"] != p["value"] else ""
        rows.append(("declared model (final values)", doc.get("base_model") or "functional",
                     f"{esc(n)} = {_num(p['value'])} {esc(p['unit'])}{_ci(p)}"
                     + (" (held)" if p.get("source") == "held" else "") + was, "-", "-", "-"))
    bc = doc.get("base_corrections") or {}
    if bc.get("accepted"):
        for c in bc.get("corrections", []):
            rows.append(("base correction", c["effect"],
                         (f"{c['parameter']} = {_num(c['value'])} {c['unit']}{_ci(c)}"
                          f"{' (at its plausible bound)' if c['at_plausible_bound'] else ''}<br><small>bound "
                          f"[{_num(c['bound'][0])}, {_num(c['bound'][1])}]: {esc(c['bound_source'])}</small>"),
                         _errors_cell(bc.get("error_before", {}), bc.get("error_after", {})), "", ""))
    for e in doc["effects_added"]:
        kind = f"implied by {e['implied_by']}" if e.get("implied_by") else (
            "found effect (beyond a base correction)" if e.get("beyond_base_correction") else
            f"declared component detailed ({', '.join(e['refines_declared'])}; base step, what the base contains)"
            if e.get("refines_declared") and e.get("base_step") else
            f"detailed declared {', '.join(e['refines_declared'])}" if e.get("refines_declared") else "found effect")
        if e.get("fault"):
            kind = f"FAULT ({kind}): {e['fault']['text']}"
        pars = "<br>".join(f"{esc(n)} = {_num(p['value'])} {esc(p['unit'])}{_ci(p)}"
                           + (" (profiled)" if p.get("profiled") else "") + (" (held)" if p.get("held") else "")
                           + (f"<br><small>{esc(p['range_end']['reason'])}</small>" if p.get("range_end") else "")
                           + _outside(p) for n, p in e["parameters"].items())
        pars += "".join(f"<br>{esc(t)}" for t in _amplitude_lines(e))
        if e.get("changed_after_added"):
            pars += f"<br><small>{esc(_final_text(e))}</small>"
        pars += "".join(f"<br><small>{esc(w)}</small>" for w in _weights_text(e.get("weight_check"))
                        + _every_segment_text(e) + _segments_text(e))
        nro = not_ruled_out_text(e)
        if nro:
            pars += f"<br><b>{esc(nro)}</b>"
        nd = "<br>".join([f"{esc(h['parameter'])} held at {_num(h['held_at'])} {esc(h['unit'])}: {esc(h['reason'])}"
                          for h in e.get("not_determined", [])]
                         + [esc(determined_later_text(h)) for h in e.get("determined_later", [])]
                         + [f"part not shown by this run (kept at its fit): {esc(w)}"
                            for w in e.get("parts_not_shown", [])])
        win = e.get("window_reduction") or {}
        wtxt = esc(", ".join(f"{c} {100 * v:+.0f} %" + (" (all samples)" if c in (e.get("window_on_all_samples") or {})
                                                        else "") for c, v in win.items()))
        if e.get("window_on_all_samples"):  # its events fell in training segments (scoring.window_reductions)
            wtxt += f"<br><small>{esc(_on_all_text(e['window_on_all_samples']))}</small>"
        if e.get("contribution"):  # the part beyond the bound (above) and the whole effect with its bounded share
            wtxt += f"<br><small>{esc(_contribution_text(e['contribution']))}</small>"
        rows.append((kind, e["name"], pars, _errors_cell(e["error_before"], e["error_after"]), wtxt,
                     nd or "-"))
    for r in doc.get("effects_removed") or []:
        rows.append(("removed (backward check)", r["name"],
                     esc(_removed_sentence(r)), "-", "-", "-"))
    if not rows:
        return ("<p>Nothing added: no base correction and no candidate effect is significant."
                + "".join(f"<br>{esc(m.strip())}" for m in beyond_base_lines(doc)) + "</p>")
    head = ("<table><tr><th>kind</th><th>effect</th><th>parameters (95 % interval)</th>"
            "<th>channel RMS before &rarr; after</th><th>error drop in its window</th>"
            "<th>not determined by this run</th></tr>")
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in (esc(r[0]), esc(r[1]), *r[2:])) + "</tr>" for r in rows)
    joints = [(r["round"], r["joint_lift"]) for r in doc.get("rounds", []) if r.get("joint_lift")]
    if joints:  # constant torques beyond a plausible base: the whole set lifted together, per round
        body += "".join(f"<tr><td>joint lift (round {k})</td><td>base corrections beyond their bounds</td>"
                        f"<td colspan='4'>{esc(_joint_text(j))}</td></tr>" for k, j in joints)
    base_like = doc["residual_signature"].get("base_like") or []
    misfit = misfit_shapes(doc["residual_signature"])
    tail = (f"<p>unexplained: <b>{doc['unexplained']}</b>"
            + (f" (structured: {esc(', '.join(doc['residual_signature']['structured']))})" if doc["unexplained"] else "")
            + "".join(f"<br>{esc(m.strip())}" for m in beyond_base_lines(doc) + holding_lines(doc))
            + "".join(f"<br><small>{esc(m)}</small>" for m in misfit + not_tested_lines(doc["residual_signature"])
                      + why_base_lines(doc["residual_signature"]))
            + (f"<br><small>left as a declared model of another rig's base leaves it (starts, stops, reversals, "
               f"quadrant; not counted as unexplained): {esc('; '.join(base_like))}</small>" if base_like else "")
            + "</p>")
    order = doc.get("order")
    otxt = (f"<p><small>Found effects in the order of what each explains given the others ({esc(order['measure'])}): "
            + esc(", ".join(f"{c['name']} {_num(c['holdout_chi2_drop_given_others'], '.4g')} (added in round "
                            f"{c['round_added']} with {_num(c['holdout_chi2_drop_when_added'], '.4g')})"
                            for c in order["contributions"]))
            + "</small></p>") if order else ""
    return head + body + "</table>" + otxt + tail


def _removed_sentence(r: dict) -> str:
    """One removal by the backward check, in words with its numbers."""
    return (f"{r['name']} removed after round {r['removed_after_round']} (added in round {r['round_added']}): no longer "
            f"earns its place given {', '.join(r['explained_by']) or 'the others'}; held-out chi2 drop "
            f"{_num(r['holdout_chi2_drop_when_added'], '.4g')} when added, {_num(r['holdout_chi2_drop_given_others'], '.4g')}"
            f" given the others (threshold {_num(r['chi2_threshold'], '.3g')}, null {_num(r.get('null_chi2_drop'), '.3g')}): "
            + "; ".join(r["why"]))


def separability_table_html(doc: dict) -> str:
    """The constant-torque explainers: how much of each one's torque the model's other explainers reproduce on this
    record (variance inflation), with whom, and the inflation on a record completed by each kind of operating
    point; then the plain sentences."""
    import html as _h

    sep = doc.get("separability") or {}
    kinds = sep.get("record_kinds", {})
    lim = sep.get("vif_limit", 10.0)
    singles = [k for k in kinds]
    head = "".join(f"<th>+ {_h.escape(kinds[k])}</th>" for k in singles)
    rows = []
    for t, e in sep.get("explainers", {}).items():
        cells = "".join(
            f"<td>{'<b>' if e['separated_by'].get(k, math.inf) <= lim else ''}{_num(e['separated_by'].get(k), '.3g')}"
            f"{'</b>' if e['separated_by'].get(k, math.inf) <= lim else ''}</td>" for k in singles)
        rows.append(f"<tr><td>{_h.escape(e['effect'])}: {_h.escape(t)}</td><td>{_num(100 * e['r2'], '.1f')} %</td>"
                    f"<td>{_num(e['vif'], '.3g')}</td><td>{_h.escape(', '.join(e['same_part_as']) or '-')}</td>{cells}</tr>")
    text = "".join(f"<p>{_h.escape(x)}</p>" for x in sep.get("sentences", []))
    return (f"<p>Variance inflation of each constant-torque explainer against the model's others over the record's "
            f"{sep.get('points', 0)} moving operating points (above {lim:g}: the record cannot tell them apart; bold: "
            f"a record completed with that kind of operating point would).</p>"
            f"<table><tr><th>explainer</th><th>reproduced by the others</th><th>inflation</th><th>same part as</th>"
            f"{head}</tr>{''.join(rows)}</table>{text}")


def _errors_cell(before: dict, after: dict) -> str:
    return "<br>".join(f"{html.escape(c)}: {_num(b.get('rms'))} &rarr; {_num(after.get(c, {}).get('rms'))} "
                       f"{html.escape(b.get('unit', ''))}" for c, b in before.items())


def plot_candidate_drops(doc: dict):
    """Each round's candidates: held-out chi2 drop (log scale, significant ones coloured)."""
    rounds = doc["rounds"]
    fig, axes = subplots(len(rounds), 1, figsize=(9, 0.5 + 2.6 * len(rounds)), squeeze=False)
    for ax, r in zip(axes[:, 0], rounds):
        cands = [c for c in r["candidates"] if c.get("holdout_chi2_drop") is not None]
        chosen = {e["name"] for e in doc["effects_added"]} if r is rounds[-1] else set(rounds[rounds.index(r) + 1]["model"])
        names = [c["name"] + (" (beyond base)" if c.get("beyond_base_correction") else "")
                 + (" <- added" if c["name"] in chosen and c["name"] not in r["model"] else "") for c in cands]
        drops = [c["holdout_chi2_drop"] for c in cands]
        colors = ["C2" if c["significant"] else ("C3" if not c["plausible"] else "0.6") for c in cands]
        y = np.arange(len(cands))
        ax.barh(y, drops, color=colors)
        ax.set_yticks(y, names, fontsize=8)
        ax.invert_yaxis()
        ax.set_xscale("symlog", linthresh=10.0)  # negative: the candidate made the held-out error worse
        lo, hi = ax.get_xlim()  # at least one decade each side, so the ticks fall on decades, not on the data's ends
        ax.set_xlim(min(lo, -10.0), max(hi, 10.0))
        ax.axvline(0, color="0.3", lw=0.6)
        ax.set_xlabel("held-out chi2 drop, symmetric log (green: significant, red: implausible, grey: not significant)")
        ax.set_title(f"round {r['round']}"
                     + (f" (retry of round {r['retry']['of_round']}'s skipped candidates)" if r.get("retry") else "")
                     + f": model {', '.join(r['model']) or 'functional'}", fontsize=9, wrap=True)
    return fig


def _periodic_tests(doc: dict) -> list[tuple[int, dict]]:
    """(round, candidate) of the angle-periodic candidates whose repetition over the travel was tested."""
    return [(r["round"], c) for r in doc["rounds"] for c in r["candidates"]
            if (c.get("periodicity") or {}).get("drop_per_period")]


def plot_periodicity(doc: dict):
    """The repetition test of each angle-periodic candidate: its held-out chi2 drop per period of nut travel (a
    ripple gains in every lead, a fit to a local drag in one), the period left out and the rest against its
    threshold."""
    tests = _periodic_tests(doc)
    fig, axes = subplots(len(tests), 1, figsize=(9, 0.6 + 2.4 * len(tests)), squeeze=False)
    for ax, (rnd, c) in zip(axes[:, 0], tests):
        t = c["periodicity"]
        d = np.asarray(t["drop_per_period"], float)
        ax.bar(np.arange(d.size), d, color=["C2" if v > 0 else "C3" for v in d])
        ax.axhline(0, color="0.3", lw=0.6)
        starts = t.get("period_starts") or [math.nan] * d.size
        ax.set_xticks(np.arange(d.size), [f"{x * 1e3:.3g}..{(x + t['period']) * 1e3:.3g} mm" for x in starts],
                      fontsize=8)
        ax.set_xlabel("nut travel, one period each (from the lowest held-out position)", fontsize=8)
        ax.set_yscale("symlog", linthresh=10.0)
        lo, hi = ax.get_ylim()
        ax.set_ylim(min(lo, -10.0), max(hi, 10.0))
        ax.set_ylabel("held-out chi2 drop", fontsize=8)
        a, b = t["left_out"]
        verdict = "repeats" if t["repeats"] else "NOT periodic"
        ax.set_title(f"round {rnd}: {c['name']} ({t['period'] * 1e3:.3g} mm of travel per period): left out "
                     f"{a * 1e3:.3g}..{b * 1e3:.3g} mm ({_num(t['left_out_drop'], '.4g')}), rest "
                     f"{_num(t['rest_drop'], '.4g')} vs {_num(t['threshold'], '.3g')}: {verdict}", fontsize=9, wrap=True)
    return fig


def _binned(ax, c: dict, scale: float = 1.0, gap_bins: float = 1.5, **kw):
    """A binned curve with its standard errors; the line breaks where bins are empty (more than ``gap_bins``
    bin widths between centres) instead of drawing across data that do not exist."""
    x = scale * np.asarray(c["centre"], float)
    y = np.asarray(c["mean"], float)
    se = np.asarray(c["sd"], float) / np.sqrt(np.maximum(np.asarray(c["count"], float), 1.0))
    if x.size > 2:
        step = float(np.min(np.diff(x)))
        cut = np.flatnonzero(np.diff(x) > gap_bins * step) + 1
        x, y, se = (np.insert(a, cut, np.nan) for a in (x, y, se))
    return ax.errorbar(x, y, yerr=se, **kw)


def _position_test(sig: dict) -> dict | None:
    """The signature's pass-replicated nut-position test, where it ran."""
    return next((t for t in sig.get("tests", []) if t.get("variable") == "nut_position (repeated over passes)"), None)


def misfit_shapes(sig: dict) -> list[str]:
    """Sentences for an added periodic drag whose own shape the residual still holds (the pass-replicated position
    test's and the angle tests' ``added_shapes``): its fitted size is off, which is no effect the model lacks."""
    loc = _position_test(sig)
    out = []
    for name, a in ((loc or {}).get("added_shapes") or {}).items():
        if not a.get("significant"):
            continue
        ip, fit = a.get("in_phase"), a.get("fitted_amplitude")
        what = (f"in phase with the fit: the rig's is about {_num(fit + ip, '.2g')} N m against the "
                f"{_num(fit, '.2g')} fitted" if ip is not None and fit and abs(ip) >= 0.7 * a["amplitude"]
                else "not in phase with the fit")
        out.append(f"the residual still holds {_num(a['amplitude'], '.2g')} N m of the added {name}'s own shape "
                   f"(period {_num(1e3 * a['period'], '.3g')} mm, p {_num(a['p_value'], '.2g')}), {what}: its fitted "
                   "size is off, not an effect the model lacks (the position test is made beyond that shape)")
    # the angle tests: what the residual holds at an added ripple's or cogging's own harmonic (tested beyond it)
    for t in sig.get("tests", []):
        for name, a in (t.get("added_shapes") or {}).items() if t.get("kind") == "periodic" else ():
            if not a.get("significant"):
                continue
            fit = a.get("fitted_amplitude")
            share = f", {100 * a['amplitude'] / fit:.0f} % of the {_num(fit, '.2g')} N m fitted" if fit else ""
            out.append(f"the residual still holds {_num(a['amplitude'], '.2g')} N m at the added {name}'s own harmonic "
                       f"({a['harmonic']} per revolution of the {t['variable'].replace('_', ' ')}, p "
                       f"{_num(a['p_value'], '.2g')}{share}): its fitted size or phase is off, not an effect the model "
                       "lacks (the angle test is made beyond that harmonic)")
    return out


def segment_rate_text(t: dict) -> str:
    """`` beyond the segment rate's harmonic 24`` for an angle test that left harmonics at the segment rate out
    (:func:`~thsa_control.trace.signature.segment_rate_harmonics`), with what the second grid found there
    (``segment_rate_check``: ``; harmonic 24 on 0.065 s segments: 0.35 mN m, p 0.82``), else empty."""
    hs = t.get("segment_rate_harmonics") or []
    if not hs:
        return ""
    out = f" beyond the segment rate's harmonic{'s' if len(hs) > 1 else ''} {', '.join(str(h) for h in hs)}"
    chk = _second_grid_text(t)
    return out + (f"; {chk}" if chk else "")


def _second_grid_text(t: dict) -> str:
    """``harmonic 16 on 0.065 s segments: 0.35 mN m, p 0.82`` for an angle test whose harmonics at the segment rate
    were tested on the second grid (``segment_rate_check``), else empty."""
    chk = t.get("segment_rate_check") or {}
    if not chk.get("harmonics"):
        return ""
    return (f"harmonic{'s' if len(chk['harmonics']) > 1 else ''} {', '.join(str(h) for h in chk['harmonics'])} "
            f"on {chk['segment_s']:.3g} s segments: {', '.join(f'{1e3 * a:.2g}' for a in chk['amplitudes'])} mN m, "
            f"p {_num(chk['p_value'], '.2g')}{' (STRUCTURED)' if chk.get('significant') else ''}")


def _angle_note(sig: dict, name: str) -> str:
    """The angle test's verdict under its panel's title: its p-value, and where the model has a ripple or cogging in
    that angle, that the test is beyond its harmonic and what the residual holds at it (the panel shows it all)."""
    t = next((d for d in sig.get("tests", []) if d.get("variable") == name and d.get("kind") == "periodic"), None)
    if t is None:
        return ""
    flag = " (STRUCTURED)" if t.get("significant") and not t.get("flagged_by") else ""
    # the segment rate's harmonics left out on this line, what the second grid found there on a line of its own (a
    # title is not wrapped: one line held both and ran past the panel's edges)
    hs = t.get("segment_rate_harmonics") or []
    comb = f" beyond the segment rate's {', '.join(str(h) for h in hs)}" if hs else ""
    grid = _second_grid_text(t)
    grid = f"\nsecond grid: {grid}" if grid else ""
    if not t.get("beyond_added"):
        return f"\nharmonics{comb}: p {_num(t['p_value'], '.2g')}{flag}{grid}"
    own = t.get("added_shapes") or {}
    which = ", ".join(f"{k} (harmonic {a['harmonic']})" for k, a in own.items())
    lines = [f"\nbeyond {which}{comb}: p {_num(t['p_value'], '.2g')}{flag}{grid}"]
    for k, a in own.items():
        fit = a.get("fitted_amplitude")
        lines.append(f"\nleft at its harmonic: {_num(a['amplitude'], '.2g')} N m"
                     + (f", {100 * a['amplitude'] / fit:.0f} % of the fitted" if fit else ""))
    return "".join(lines)


def plot_signature(sig: dict):
    """The remaining residual's signature: binned by nut position, by motor and screw angle, the redundant
    sensors' cross-correlation, the per-segment torque against time (the drift test's data), the residual
    binned by the motor current (a torque-constant error), the load cell and the LVDT in the holds, and the current
    of comparable passes against time (the torque constant drifting)."""
    curves = sig.get("curves") or {}
    fig, axes = subplots(5, 2, figsize=(11, 16))
    ax = axes[0, 0]
    local_note = ""
    if "nut_position" in curves:
        c = curves["nut_position"]
        by_dir = c.get("by_direction") or {}
        _binned(ax, c, 1e3, fmt="o-", ms=2, lw=0.6, color="0.7", label="all samples")
        for (label, cd), col in zip(by_dir.items(), ("C0", "C1")):
            _binned(ax, cd, 1e3, fmt="o-", ms=3, lw=0.8, color=col, label=f"{label}, outside the base's transients")
        loc = _position_test(sig)
        if loc is not None:  # the pass-replicated test's peak bin, its law and p-value
            ax.axvspan(1e3 * loc["peak_bin"][0], 1e3 * loc["peak_bin"][1], color="C3" if loc["significant"] else "0.85",
                       alpha=0.25, lw=0)
            # under the title, where neither the legend nor the curves reach it
            local_note = (f"repeated over passes: p {_num(loc['p_value'], '.2g')}"
                          + (f" ({1e3 * loc['bin_width']:.2g} mm bins)" if loc.get("bin_width") else "")
                          + (f", {loc['law'].split(' ')[0]}" if loc.get("law") else "")
                          + (" beyond " + ", ".join(loc["added_shapes"]) + "'s shape" if loc.get("added_shapes") else "")
                          + (" (STRUCTURED)" if loc["significant"] else ""))
        else:
            local_note = "repeated over passes: not tested (fewer than three bins crossed by two passes)"
            one = next((t for t in sig.get("tests", []) if t.get("kind") == "local_one_pass"), None)
            if one is not None:  # the one-pass test's peak bin against the pass's other bins
                ax.axvspan(1e3 * one["peak_bin"][0], 1e3 * one["peak_bin"][1],
                           color="C3" if one["significant"] else "0.85", alpha=0.25, lw=0)
                local_note += (f"\none pass, a bin against the others: p {_num(one['p_value'], '.2g')}, "
                               f"{one['law'].split(' ')[0]}" + (" (STRUCTURED)" if one["significant"] else ""))
        bk = next((t for t in sig.get("tests", []) if t.get("kind") == "breakaway"), None)
        if bk is not None:  # the breakaway test's places (starts and reversals of one class), the one that stands out
            for pl in bk["places"]:
                ax.axvline(1e3 * pl["position"], color="C3" if pl["position"] == bk["peak_position"] and bk["significant"]
                           else "0.8", lw=0.8, ls=":")
            # under the title with the position test's note (inside the axes the legend covered it)
            local_note += (f"\nbreakaway current at starts/reversals: p {_num(bk['p_value'], '.2g')}"
                           + (" (STRUCTURED)" if bk["significant"] else "")
                           + f"\n{bk['peak_deviation']:+.2f} A at {1e3 * bk['peak_position']:.1f} mm against the same "
                           "kind of event elsewhere")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="best")
    else:  # trace.residual bins the nut position only over a travel of at least two bins
        ax.text(0.5, 0.5, "not binned: the nut travel of these runs\nis shorter than two position bins",
                ha="center", va="center", transform=ax.transAxes, fontsize=9, color="0.35")
    ax.axhline(0, color="0.5", lw=0.5)
    ax.set_xlabel("nut position [mm]")
    ax.set_ylabel("missing torque [N m]")
    ax.set_title("residual binned by nut position" + (f"\n{local_note}" if local_note else ""), fontsize=9)
    for ax, name in ((axes[0, 1], "motor_angle"), (axes[1, 0], "screw_angle")):
        c = curves.get(name)
        if c:
            _binned(ax, c, 180.0 / np.pi, fmt="o-", ms=3, lw=0.8)
        ax.axhline(0, color="0.5", lw=0.5)
        ax.set_xlabel(f"{name.replace('_', ' ')} modulo one revolution [deg]")
        ax.set_ylabel("missing torque less its level [N m]" if (c or {}).get("given_levels") else "missing torque [N m]")
        ax.set_title(f"residual binned by {name.replace('_', ' ')}" + _angle_note(sig, name), fontsize=9)
    ax = axes[1, 1]
    for label, c in (curves.get("cross_correlation") or {}).items():
        ax.plot(1e3 * np.asarray(c["lag_s"]), c["correlation"], lw=0.9, label=label.split(": ", 1)[-1])
    ax.axvline(0, color="0.5", lw=0.5)
    ax.set_xlabel("lag [ms]")
    ax.set_ylabel("correlation of the sample differences")
    ax.set_title("redundant sensors: cross-correlation", fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="lower left")
    ax = axes[2, 0]
    st = curves.get("segment_torque") or {}
    if st.get("time"):
        tm, tq, dr = (np.asarray(st[k], float) for k in ("time", "torque", "direction"))
        for sgn, label, col in ((1.0, "extending", "C0"), (-1.0, "retracting", "C1")):
            m = dr == sgn
            if m.any():
                ax.plot(tm[m], tq[m], "o", ms=2.5, color=col, label=label)
        dt_ = next((t for t in sig.get("tests", []) if t.get("variable") == "time (slow drift)"), None)
        if dt_ is not None:
            ax.text(0.02, 0.97, f"drift per pass: p {_num(dt_['p_value'], '.2g')}"
                    + (" (STRUCTURED)" if dt_["significant"] else ""), transform=ax.transAxes, va="top", fontsize=7)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="best")
    else:
        ax.text(0.5, 0.5, "no steady segment in motion", ha="center", va="center", transform=ax.transAxes,
                fontsize=9, color="0.35")
    ax.set_xlabel("time [s] (runs one after another)")
    ax.set_ylabel("missing torque per segment [N m]")
    ax.set_title("steady segments against time (slow drift)", fontsize=9)
    ax = axes[2, 1]
    c = curves.get("motor_current")
    if c:
        _binned(ax, c, fmt="o-", ms=3, lw=0.8, gap_bins=np.inf)  # quantile bins: unequal widths
    ax.axhline(0, color="0.5", lw=0.5)
    ax.set_xlabel("motor current [A]")
    ax.set_ylabel("missing torque [N m]")
    ax.set_title("residual binned by motor current (torque constant)", fontsize=9)
    _plot_holds(axes[3, 0], axes[3, 1], curves.get("hold_load"))
    _plot_current_drift(axes[4, 0], next((t for t in sig.get("tests", []) if t.get("kind") == "torque_constant_drift"),
                                         None))
    fig.delaxes(axes[4, 1])
    return fig


def _plot_current_drift(ax, test: dict | None) -> None:
    """The torque constant's test: each comparable pass's mean current relative to its operating point's level, against
    time, with the standard errors and the shared relative rate (the law every operating point follows)."""
    if not test:
        ax.text(0.5, 0.5, "no operating point repeated by three passes (or two by two)\nover the same nut positions: "
                "the torque constant's drift not tested", ha="center", va="center", transform=ax.transAxes, fontsize=8,
                color="0.35")
    else:
        for k, c in enumerate(test["classes"]):
            tm = np.array([p["time"] for p in c["passes"]])
            lv = np.array([p["level"] for p in c["passes"]])
            se = np.array([p["stderr"] for p in c["passes"]])
            lc, tc = c["level"], c["mean_time"]  # the test's weighted level and mean time of the class
            label = f"{'extending' if c['direction'] > 0 else 'retracting'} at {lc:.2f} A"
            ax.errorbar(tm, 1e3 * (lv / lc - 1), yerr=1e3 * se / abs(lc), fmt="o", ms=3, color=f"C{k}", label=label)
            tt = np.array([tm.min(), tm.max()])
            ax.plot(tt, 1e3 * test["relative_rate"] * (tt - tc), color=f"C{k}", lw=1.0)
        ax.text(0.02, 0.97, f"shared rate {1e3 * test['relative_rate']:+.2f}e-3 +- {1e3 * test['stderr']:.2f}e-3 /s, "
                f"p {_num(test['p_value'], '.2g')}: {test['verdict']}" + (" (STRUCTURED)" if test["significant"] else ""),
                transform=ax.transAxes, va="top", fontsize=7)
        ax.legend(fontsize=7, loc="lower left")
    ax.axhline(0, color="0.5", lw=0.5)
    ax.set_xlabel("time [s] (runs one after another)")
    ax.set_ylabel("pass current / level - 1 [1e-3]")
    ax.set_title("current of comparable passes (torque constant drifting)", fontsize=9)


def _plot_holds(ax_f, ax_x, hc: dict | None) -> None:
    """The load-cell drift test's data: the load reading and the LVDT in the holds (speed command 0, nut held,
    outside the base's transients) about each hold's mean, with the slope shared by the holds."""
    if not hc or not hc.get("time"):
        for ax in (ax_f, ax_x):
            ax.text(0.5, 0.5, "no hold of 0.2 s (speed command 0, nut still)\noutside the base's transients",
                    ha="center", va="center", transform=ax.transAxes, fontsize=9, color="0.35")
    else:
        tm, hold = np.asarray(hc["time"], float), np.asarray(hc["hold"], int)
        ax_f.plot(tm, hc["load_deviation"], ".", ms=1.5, color="0.55")
        for j, tc in enumerate(hc["hold_mean_time"]):
            tj = tm[hold == j]
            if tj.size:
                ax_f.plot([tj[0], tj[-1]], [hc["slope"] * (tj[0] - tc), hc["slope"] * (tj[-1] - tc)], color="C3", lw=1.5)
        ax_f.text(0.02, 0.97, f"slope shared by the holds {hc['slope']:.3g} N/s, p {_num(hc['p_value'], '.2g')}"
                  + (" (STRUCTURED)" if hc["significant"] else ""), transform=ax_f.transAxes, va="top", fontsize=7)
        if hc.get("lvdt_deviation") is not None:
            ax_x.plot(tm, 1e6 * np.asarray(hc["lvdt_deviation"], float), ".", ms=1.5, color="0.55")
        else:
            ax_x.text(0.5, 0.5, "no LVDT in these runs", ha="center", va="center", transform=ax_x.transAxes,
                      fontsize=9, color="0.35")
    for ax in (ax_f, ax_x):
        ax.axhline(0, color="0.5", lw=0.5)
        ax.set_xlabel("time [s] (runs one after another)")
    ax_f.set_ylabel("load reading - hold mean [N]")
    ax_f.set_title("load cell in the holds (slow drift)", fontsize=9)
    ax_x.set_ylabel("LVDT - hold mean [um]")
    ax_x.set_title("LVDT in the holds (a real load change deflects the structure)", fontsize=9)


def _ambiguity_hint(doc: dict, names) -> str:
    """What would tell ambiguous candidates apart, read off the trace's separability (the kinds of record that bring
    each one's variance inflation against the base's explainers below the limit); generic without it."""
    sep = doc.get("separability") or {}
    kinds, lim = sep.get("record_kinds", {}), sep.get("vif_limit", 10.0)
    parts = []
    for e in (sep.get("explainers") or {}).values():
        if e["effect"] not in names:
            continue
        good = sorted((v, k) for k, v in e["separated_by"].items() if v <= lim)
        if good:
            k = good[0][1]
            parts.append(f"{e['effect']} by {' together with '.join(kinds[x] for x in k.split('+'))}")
        else:
            parts.append(f"{e['effect']} by none of the kinds of record tried")
    if not parts:
        return " (another speed, load or direction would)."
    return "; from the torque sensitivities, a record would separate " + "; ".join(parts) + "."


def _contribution_text(c: dict) -> str:
    """One line: what an effect named beyond its base correction contributes in all, and the bounded share."""
    tot, bnd = c.get("total_window_reduction"), c.get("bounded_window_reduction")
    return (f"whole contribution ({c['parameter']} {_num(c['value'])} against 0, everything else as fitted): "
            f"{c['channel']} window error {_num(None if tot is None else 100 * tot, '.0f')} % lower with it; a base "
            f"correction at its plausible bound ({_num(c['bound'])}, {_num(None if c.get('bounded_share') is None else 100 * c['bounded_share'], '.0f')} % of the value) "
            f"would carry {_num(None if bnd is None else 100 * bnd, '.0f')} % of it; the window drop counted for the "
            "selection is what lies beyond the bound")


def _on_all_text(on_all: dict) -> str:
    """One line: the window drops taken over all the window's samples, and why (its events in training segments)."""
    return "; ".join(
        f"{c}: over all {v['samples']} samples of its window, training ones included: its {v['heldout_samples']} "
        f"held-out samples had {_num(v['heldout_error_ratio'], '.2g')} x the window's mean error (its events fell in "
        f"training segments; held-out drop {_num(100 * v['holdout_reduction'], '+.0f')} %)" for c, v in on_all.items())


def _joint_text(j: dict) -> str:
    """One line: the joint lift of the plausible set and its verdict."""
    if "error" in j:
        return f"joint lift of the base corrections: fit failed ({j['error']})"
    vals = ", ".join(f"{n} {_num(v)}" for n, v in (j.get("values") or {}).items())
    return (f"joint lift ({j['parameters_lifted']} base corrections freed beyond their plausible bounds together"
            f"{': ' + vals if vals else ''}): held-out chi2 drop {_num(j['holdout_chi2_drop'], '.4g')} (threshold "
            f"{_num(j['chi2_threshold'], '.3g')}"
            + (f"; the joint fit stopped at {_num(j['joint_fit_drop'], '.4g')}, below {j['joint_from']}, a special case "
               "of it" if j.get("joint_from") else "") + f"); {j['verdict']}")


def _start_text(start: dict) -> str:
    """One line: where a candidate's fit started, read off the runs (``start`` in trace.json)."""
    vals = ", ".join(f"{n} = {_num(v)}" for n, v in start["values"].items())
    return f"started at {vals}, read off the runs" + (f" ({start['why']})" if start.get("why") else "")


_WEIGHTING_NAMES = {"sensor_noise_weights": "sensor-noise weights (the search's)",
                    "residual_scales": "channels at their residual spread",
                    "without_structural_channels": "without {}"}


def _final_text(e: dict) -> str:
    """The found effect's parameters that moved once later effects were added (``changed_after_added``), as the
    final model has them, with their intervals."""
    ch, fin = e["changed_after_added"], e["parameters_final"]
    return ("in the final model (refitted with " + (", ".join(ch["with"]) or "the later fits") + "): "
            + ", ".join(f"{n} = {_num(fin[n]['value'])} {fin[n]['unit']}{_ci(fin[n])}" for n in ch["parameters"]))


def _amplitude_text(a: dict) -> str:
    """A ripple's amplitude with its interval and its phase, or that the run does not determine the phase (the
    parts' intervals then span zero although the amplitude is determined)."""
    ci = a.get("ci95")
    txt = f"amplitude {_num(a['value'])} {a['unit']}" + (f"  95 % CI [{_num(ci[0])}, {_num(ci[1])}]" if ci else "")
    if a.get("phase_determined"):
        return txt + f", phase {a['phase_deg']:.0f} +- {a['phase_stderr_deg']:.0f} deg"
    return txt + (", phase not determined by this run (the segments' start angles take it: the cosine and sine "
                  "parts' intervals span zero, the amplitude's does not)")


def _amplitude_lines(e: dict) -> list[str]:
    """A ripple's amplitude when it was added and, where the final model's differs (``amplitude_final``: the
    every-segment fit, the later effects), the final one."""
    a, f = e.get("amplitude"), e.get("amplitude_final")
    out = [_amplitude_text(a)] if a else []
    if f and (not a or _num(f["value"]) != _num(a["value"])):
        out.append("in the final model: " + _amplitude_text(f))
    return out


def _every_segment_text(e: dict) -> list[str]:
    """Lines: the found effect's parameters that the fit on every segment, the held-out ones too, moves
    (``every_segment``): the held-out segments' places decide them."""
    ev = e.get("every_segment") or {}
    out = []
    for n in ev.get("moved", []):
        p, q = (e.get("parameters_final") or e["parameters"])[n], ev["parameters"][n]
        t = (ev.get("training") or {}).get(n, p)  # a trace.json before "training" kept the search's value there
        lo, hi = p.get("range_over_segment_sets") or (None, None)
        out.append(f"{n} = {_num(q['value'])} {q['unit']}{_ci(q)} fitted on every segment, the held-out ones too "
                   f"({_num(t['value'])} on the training segments; range {_num(lo)} .. {_num(hi)}): the held-out "
                   "segments' places decide it" + ("; the final value is the every-segment fit's"
                                                   if ev.get("adopted") else ""))
    return out


#: a final value whose segment-clustered standard error exceeds its information's by this factor gets a line
SEGMENTS_WIDER = 2.0


def _segments_text(e: dict) -> list[str]:
    """Lines: the found effect's final values whose segment-clustered standard error (``stderr_segments``) is more
    than :data:`SEGMENTS_WIDER` times the information's: the interval the record's segments support
    (``ci95_segments``), the residual being structured there."""
    out = []
    for n, p in (e.get("parameters_final") or e.get("parameters") or {}).items():
        sd, ss, ci = p.get("stderr"), p.get("stderr_segments"), p.get("ci95_segments")
        if sd and ss and ci and ss > SEGMENTS_WIDER * sd:
            pulled = p.get("pulled_by") or []
            several = len({q["run"] for q in pulled}) > 1  # name the run where the pulls lie in more than one
            pulls = "; ".join(f"{'up' if q['moves_by_stderr'] > 0 else 'down'} by {abs(q['moves_by_stderr']):.2g} "
                              f"without {q['run'] + ' ' if several else ''}{q['t0']:.2f}-{q['t1']:.2f} s"
                              for q in pulled)
            out.append(f"{n} = {_num(p['value'])} {p['unit']} [{_num(ci[0])}, {_num(ci[1])}] over the record's "
                       f"segments (standard error {ss / sd:.3g} x the information's: the residual is structured, "
                       "a few events pull this value" + (f"; in standard errors, {pulls}" if pulls else "") + ")")
    return out


def _every_segment_other_text(doc: dict) -> list[str]:
    """Lines: the final model's other fitted parameters (base corrections, the declared uncertain set) that the fit
    on every segment moves (``every_segment.moved_other``), and whether the final values are that fit's."""
    ev = doc.get("every_segment") or {}
    out = []
    for n, m in (ev.get("moved_other") or {}).items():
        a, b = m["training"], m["every_segment"]
        out.append(f"{n} = {_num(b['value'])} {b['unit']}{_ci(b)} fitted on every segment, the held-out ones too "
                   f"({_num(a['value'])} on the training segments; range {_num(m['range'][0])} .. "
                   f"{_num(m['range'][1])}): the held-out segments' places decide it")
    if ev and "adopted" in ev:
        out.append("final values: the fit on every segment" if ev["adopted"] else
                   f"final values: the search's last fit ({ev.get('why', '')})")
    return out


def _weights_text(check: dict) -> list[str]:
    """Lines: the found effect's parameters whose estimate depends on the channel weights (``weight_check``)."""
    if not check or not check.get("depends_on_weights"):
        return []
    left = ", ".join(f"{c} at {_num(check['scale_over_noise'][c], '.2g')} x its noise"
                     for c in check.get("structural_channels", []))
    out = []
    for n in check["depends_on_weights"]:
        vals = "; ".join(f"{_WEIGHTING_NAMES.get(k, k).format(', '.join(check.get('structural_channels', [])))} "
                         f"{_num(v['value'])}" for k, v in check["parameters"][n].items())
        lo, hi = check["range"][n]
        out.append(f"{n} depends on the channel weights ({left or 'no channel beyond twice its noise'}): {vals}; "
                   f"range {_num(lo)} .. {_num(hi)}")
    return out


def why_base_lines(sig: dict) -> list[str]:
    """Why a significant test that would be structure is left as the base's (``why_base``: an angle spanned under two
    revolutions, a current-proportional torque that a lossier base carries), one line each."""
    return [f"{t['variable']} left as the base's: {t['why_base']}" for t in sig.get("tests") or []
            if t.get("significant") and t.get("remainder") == "base" and t.get("why_base")]


def not_tested_lines(sig: dict) -> list[str]:
    """The signature tests this record could not make, each with what it would have shown and why not: an
    ``unexplained: False`` says nothing of a current-sensor offset on a record whose drive is never off."""
    out = []
    for t in sig.get("not_tested") or []:
        where = f" on {t['run']}" if t.get("run") else ""
        out.append(f"not tested: {t['test']}{where} ({t['would_show']} would show there): {t['why']}")
    return out


def _bound_text(b) -> str:
    lo, hi = b
    return f"plausible {_num(hi)} at most" if lo == 0 else f"plausible {_num(lo)} .. {_num(hi)}"


def determined_later_text(h: dict) -> str:
    """One line for a parameter held as undecided when its effect was added and determined once a later one was in
    the model (``determined_later``)."""
    ci = h.get("ci95")
    return (f"determined once {h['determined_given']} was added: {h['parameter']} = {_num(h['value'])} {h['unit']}"
            + (f" [{_num(ci[0])}, {_num(ci[1])}]" if ci else "")
            + f" (held at {_num(h['held_at'])} when added: {h['reason']})")


def not_ruled_out_text(e: dict) -> str | None:
    """One line: the constant torques (or a lossier base) a named physical effect does not rule out on this record."""
    n = e.get("not_ruled_out")
    if not n:
        return None
    return ("this record does not rule out, in its place: " + "; ".join(
        f"{a['name']} (held-out drop {_num(a['holdout_chi2_drop'], '.4g')}"
        + (f", not named: {a['not_named_because']}" if a.get("not_named_because") else "") + ")"
        for a in n["alternatives"])
        + f" (its own drop on the constant torques' samples {_num(n['own_drop_on_constant_torque_samples'], '.4g')},"
        f" carry gap {_num(n['carry_gap'], '.3g')}: " + _why_named(e.get("given_the_lift")) + ")")


def _why_named(g: dict | None) -> str:
    """Why a physical effect was named beside the constant torques it does not rule out (engine._gate_weaker_physical)."""
    if not g:
        return "it was named as the physical effect that explains as much"
    if g.get("error"):
        return (f"it explains less than {g['best_lift']} lifted ({_num(g['best_lift_drop'], '.4g')}); its fit with the "
                f"joint lift failed ({g['error']}), so it was not judged against the lift")
    return (f"it explains less than {g['best_lift']} lifted ({_num(g['best_lift_drop'], '.4g')}) and was named because, "
            f"fitted with the joint lift, it still drops its window's held-out error by "
            f"{_num(g['holdout_chi2_drop'], '.4g')} against {_num(g['chi2_threshold'], '.3g')}")


def beyond_base_lines(doc: dict) -> list[str]:
    """The record's answer to "a constant torque beyond a plausible base?" (trace.json ``beyond_plausible_base``):
    a headline, and for a joint lift that passed, each single explanation with its own lifted values against the
    plausible bound and why it was not named."""
    b = doc.get("beyond_plausible_base")
    if not b:
        return []
    head = "beyond a plausible base (constant torques): "
    if b["status"] == "not_fitted" and b.get("base_step"):  # the plausible base holds the constant torques
        return [head + f"no ({b['why']})"]
    if b["status"] in ("not_fitted", "failed"):
        return [head + f"not tested: {b['why']}"]
    if "before" in b or "holdout_chi2_drop" not in b:  # judged through a later round, or not on the final model
        return [head + ("no: " if b["status"] == "within" else "NOT JUDGED ON THE FINAL MODEL: ") + b["verdict"]]
    lift = (f"round {b['round']}'s joint lift, held-out chi2 drop {_num(b['holdout_chi2_drop'], '.4g')} against "
            f"{_num(b['chi2_threshold'], '.3g')}" + ("" if b["on_final_model"] else
                                                     ", on the model before that round's addition"))
    if b["status"] == "within":
        return [head + f"no ({lift})" + (f": {b['verdict']}" if b.get("explained_inside_bounds_by") else "")]
    label = {"named": "NAMED", "not_named": "PRESENT, NOT ATTRIBUTED",
             "no_carrier": "A BASE MISMATCH BEYOND THE PLAUSIBLE SET, NO CONSTANT TORQUE"}
    what = ("what the base leaves exceeds its plausible corrections; each of these explains it alike (held-out "
            "drops within the joint lift's carry gap), so nothing is named:" if b["status"] == "not_named"
            else b["verdict"])
    lines = [head + f"{label.get(b['status'], b['status'])} ({lift}): {what}"]
    for c in b.get("carriers") or []:
        vals = ", ".join(f"{n} = {_num(v['value'])} {v.get('unit', '')}".rstrip()
                         + (f" [{_num(v['ci95'][0])}, {_num(v['ci95'][1])}]" if v.get("ci95") else "")
                         + (f" ({_bound_text(v['plausible_bound'])})" if v.get("plausible_bound") else "")
                         for n, v in c["values"].items())
        lines.append(f"    {'named' if c['named'] else 'or'}: {c['meaning']}"
                     + (f" ({c['name']})" if not c["base"] else "")
                     + f", held-out drop {_num(c['holdout_chi2_drop'], '.4g')}" + (f": {vals}" if vals else "")
                     + (f"; not named alone: {c['not_named_because']}" if c.get("not_named_because") else ""))
    short = b.get("too_few_segments") if b["status"] == "not_named" else None
    if short:
        lines.append(f"    the record is also too short for any of them to pass the robustness test of a constant torque: "
                     f"{short['segments']} held-out segments in their window, {short['needed']} needed to pass at all (its "
                     f"smallest p with {short['segments']} is {_num(short['smallest_p'], '.2g')}); about "
                     f"{_num(short['window_s_needed'], '.2g')} s of steady motion outside the base's transients "
                     "would hold them")
    if b["status"] == "not_named" and doc.get("separability"):
        lines.append("    the records that would tell them apart: under 'what this record cannot tell apart'")
    return lines


def holding_lines(doc: dict) -> list[str]:
    """Does the no-back hold: the record's drive-off stretches (model-free) and the final model's margin
    (:mod:`thsa_control.trace.holding`)."""
    h = doc.get("no_back_holding")
    if not h:
        return []
    o = h["observed"]
    if o["verdict"] == "not tested":
        lines = [f"no-back holding, observed with the drive off: not tested ({o['why']})"]
    else:
        parts = []
        for state in ("slips", "undecided", "holds"):
            st = [x for x in o["stretches"] if x["state"] == state]
            if st:
                parts.append(f"{state} in {len(st)} ("
                             + " / ".join(f"{abs(x['load_N']) / 1e3:.3g} kN {x['side']}: {x['nut_travel_mm']:.3g} mm "
                                         f"back-driven, {x['end_speed_mm_s']:.2g} mm/s at the end" for x in st) + ")")
        lines = [f"no-back holding, observed with the drive off: {o['verdict'].upper()}; " + "; ".join(parts)
                 + f" (pawl pitch {o['pawl_pitch_rad']:.4g} rad"
                 + (f", {o['pawl_pitch_mm']:.3g} mm of nut travel" if o.get("pawl_pitch_mm") is not None else "")
                 + f"; {o['sensor']})"]
    for m in h.get("margin", []):
        if not m.get("determined"):
            lines.append(f"    model margin, {m['side']} side: not determined: {m['why']}")
            continue
        lines.append(f"    model margin, {m['side']} side: {m['parameter']} {m['coefficient']:.3g} over the holding "
                     f"limit {m['limit']:.3g} N m/N = {m['margin']:.3g} (95 % {m['margin_ci95'][0]:.3g}.."
                     f"{m['margin_ci95'][1]:.3g}; {m['margin_range'][0]:.3g}..{m['margin_range'][1]:.3g} over "
                     f"{m['eta_source']}, {m['eta_range'][0]:.3g}..{m['eta_range'][1]:.3g}): {m['shown']}")
    lines += [f"    note: {n}" for n in h.get("notes", [])]
    return lines


def restart_text(r: dict) -> str:
    """One line on a declared component's detailed fit restarted from the corrections' optimum."""
    how = (f"the restart reached {_num(r.get('training_chi2_restart'), '.6g')}" if "training_chi2_restart" in r
           else f"the restart failed ({r.get('error')})")
    return (f"its joint fit from the file's values ended at training chi2 {_num(r['training_chi2_first'], '.6g')} "
            f"({r.get('first_status') or 'status unknown'}), above the corrections' own "
            f"{_num(r['training_chi2_corrections'], '.6g')}: fitted again from their optimum, {how}; "
            f"kept: {'the restart' if r.get('kept') == 'restart' else 'the first fit'}")


def format_trace_summary(doc: dict) -> str:
    """Console / report text: what was added, the ranking, the errors, the signature."""
    lines = [f"declared model: {doc['base_model']} ({', '.join(doc['declared_effects']) or 'functional'}), "
             f"uncertain set fitted: {', '.join(doc['uncertain_parameters']) or 'none'}"]
    for h in doc.get("declared_not_determined") or []:
        lines.append(f"    not determined by these runs: {h['parameter']} held at {_num(h['held_at'])} {h['unit']} "
                     f"({h['reason']})")
    for e, why in (doc.get("declared_from_runs") or {}).items():
        lines.append(f"    declared from the runs' rig description: {e} ({why}); hardware, not a finding")
    bc = doc.get("base_corrections")
    if bc:
        lines.append(f"base corrections ({'applied' if bc.get('accepted') else 'not significant'}; held-out chi2 drop "
                     f"{_num(bc.get('holdout_chi2_drop'), '.4g')}, threshold {_num(bc.get('chi2_threshold'), '.3g')}): "
                     "what every real drive has, within plausible bounds; not found effects")
        for c in bc.get("corrections", []):
            lines.append(f"    {c['effect']:<20} {c['parameter']} = {_num(c['value'])} {c['unit']}{_ci(c)}, bound "
                         f"[{_num(c['bound'][0])}, {_num(c['bound'][1])}]{'  AT BOUND' if c['at_plausible_bound'] else ''}")
    lines += [f"    {w}" for w in _every_segment_other_text(doc)]
    for d in (bc or {}).get("declared_components_detailed", []):
        lines.append(f"    declared component detailed: {d['name']} (for {', '.join(d.get('refines', []))}): "
                     f"{'kept' if d['accepted'] else 'not kept'}, {d.get('reason', '')}")
        if d.get("restart"):
            lines.append(f"        {restart_text(d['restart'])}")
        if d.get("offered_as_finding"):
            lines.append(f"        {d['offered_as_finding']}")
        for w in d.get("parts_not_shown") or []:
            lines.append("        part not shown by this run"
                         + (" (kept at its fit; the component is declared): " if d["accepted"] else ": ") + w)
    step = 0
    for e in doc["effects_added"]:
        if e.get("implied_by"):
            lines.append(f"    with it: {e['name']} (needed by {e['implied_by']}; parameters "
                         + (", ".join(f"{n} = {_num(p['value'])}" for n, p in e["parameters"].items()) or "at file values")
                         + ")")
            continue
        step += 1
        how = (" (beyond its base correction)" if e.get("beyond_base_correction") else
               " (base step: declared component detailed, counted as what the base contains)" if e.get("base_step")
               else "")
        lines.append(f"step {step}: added {e['name']}{how}"
                     + (f" in round {e['round_added']}" if e.get("round_added") and doc.get("order") else "")
                     + f" (score {_num(e['score'], '.3f')}, AIC drop {_num(e['aic_drop'], '.1f')}, "
                     f"BIC drop {_num(e['bic_drop'], '.1f')})")
        if e.get("fault"):
            lines.append(f"    FAULT: {e['fault']['text']}")
            lines += [f"        because {w}" for w in e["fault"].get("because", [])]
        for n, p in e["parameters"].items():
            ci = p["ci95"]
            lines.append(f"    {n} = {_num(p['value'])} {p['unit']}" + (f"  95 % CI [{_num(ci[0])}, {_num(ci[1])}]" if ci else "")
                         + (" (profiled)" if p.get("profiled") else "") + (" (held)" if p.get("held") else "")
                         + (f" ({p['range_end']['reason']})" if p.get("range_end") else "")
                         + _outside(p))
        lines += [f"    {t}" for t in _amplitude_lines(e)]
        nro = not_ruled_out_text(e)
        if nro:
            lines.append(f"    {nro}")
        for h in e.get("not_determined", []):
            lines.append(f"    not determined by this run: {h['parameter']} held at {_num(h['held_at'])} {h['unit']} "
                         f"({h['reason']})")
        lines += [f"    {determined_later_text(h)}" for h in e.get("determined_later", [])]
        if e.get("start"):
            lines.append(f"    {_start_text(e['start'])}")
        if e.get("changed_after_added"):
            lines.append(f"    {_final_text(e)}")
        lines += [f"    {w}" for w in _weights_text(e.get("weight_check")) + _every_segment_text(e)
                  + _segments_text(e)]
        for c, red in e["error_reduction"].items():
            b, a = e["error_before"].get(c, {}), e["error_after"].get(c, {})
            lines.append(f"    {c}: RMS {_num(b.get('rms'))} -> {_num(a.get('rms'))} ({100 * red:+.1f} % drop)")
        if e.get("contribution"):
            lines.append(f"    {_contribution_text(e['contribution'])}")
    order = doc.get("order")
    if order:
        lines.append("order of the found effects: " + ", ".join(
            f"{c['name']} (given the others {_num(c['holdout_chi2_drop_given_others'], '.4g')}, when added in round "
            f"{c['round_added']} {_num(c['holdout_chi2_drop_when_added'], '.4g')})" for c in order["contributions"])
            + f"; measure: {order['measure']}" + (" (not the order of addition)" if order.get("changed") else ""))
    for r in doc.get("effects_removed") or []:
        lines.append("backward check: " + _removed_sentence(r))
    for a in doc.get("ambiguous", []):
        drops = ", ".join(f"{n} {_num(v, '.4g')}" for n, v in a["holdout_chi2_drop"].items())
        lines.append(f"not named (round {a['round']}): {', '.join(a['candidates'])} explain the same part of the "
                     f"residual; held-out chi2 drops {drops} differ by less than {_num(a['indistinct_below'], '.3g')}. "
                     "The data cannot tell them apart"
                     + _ambiguity_hint(doc, a["candidates"]))
    if not doc["effects_added"] and not doc.get("ambiguous"):
        lines.append("no candidate effect is significant")
    sep = doc.get("separability") or {}
    if sep.get("sentences"):
        lines.append("what this record cannot tell apart (constant-torque explainers, from their torque "
                     "sensitivities over its moving samples):")
        lines += [f"    {x}" for x in sep["sentences"]]
    for r in doc["rounds"]:
        lines.append(f"round {r['round']} (model: {', '.join(r['model']) or 'functional'}): candidates"
                     + (f" skipped in round {r['retry']['of_round']}, fitted on the same model before stopping "
                        f"(decided with round {r['retry']['of_round']}'s: {', '.join(r['retry']['decided_with'])})"
                        if r.get("retry") else ""))
        for c in r["candidates"]:
            if "error" in c:
                lines.append(f"    {c['name']:<26} fit failed: {c['error']}")
                continue
            flag = "SIGNIFICANT" if c["significant"] else ("implausible: " + "; ".join(c["implausible_because"])
                                                           if not c["plausible"] else
                                                           "not significant" + (f": {c['not_robust']}"
                                                                                if c.get("not_robust") else "")
                                                           + (f": {c['joint_lift_refused']}"
                                                              if c.get("joint_lift_refused") else "")
                                                           + (f": {c['not_periodic']}" if c.get("not_periodic")
                                                              else ""))
            lines.append(f"    {c['name']:<26} held-out chi2 drop {_num(c['holdout_chi2_drop'], '.4g'):>10} "
                         f"(threshold {_num(c['chi2_threshold'], '.3g')}, null {_num(c.get('null_chi2_drop'), '.3g')}), "
                         f"score {_num(c['score'], '.3f')}  {flag}")
            for h in c.get("not_determined", []):
                lines.append(f"        not determined: {h['parameter']} held at {_num(h['held_at'])} {h['unit']}")
            if c.get("start"):
                lines.append(f"        {_start_text(c['start'])}")
        for s in r["skipped"]:
            lines.append(f"    {s['name']:<26} skipped: {s['reason']}")
        if r.get("joint_lift"):
            lines.append(f"    {_joint_text(r['joint_lift'])}")
    if doc.get("stop"):
        lines.append(f"search stopped: {doc['stop']['reason'].replace('_', ' ')} ({doc['stop']['detail']})")
    lines.append("error before -> after (all samples):")
    for c, b in doc["error_before"].items():
        a = doc["error_after"][c]
        lines.append(f"    {c}: RMS {_num(b['rms'])} -> {_num(a['rms'])} [{b['unit']}], fit {_num(b['fit_percent'], '.2f')} -> "
                     f"{_num(a['fit_percent'], '.2f')} %")
    sig = doc["residual_signature"]
    lines.append(f"unexplained: {doc['unexplained']}" + (f" (structured in: {', '.join(sig['structured'])})"
                                                         if doc["unexplained"] else ""))
    lines += beyond_base_lines(doc)
    lines += holding_lines(doc)
    if sig.get("base_like"):
        lines.append("left as a declared model of another rig's base leaves it (not unexplained): "
                     + "; ".join(sig["base_like"]))
    lines += misfit_shapes(sig)
    lines += not_tested_lines(sig)
    lines += why_base_lines(sig)
    for t in sig["tests"][:6] + sig["sensors"]:
        extra = ""
        if t["kind"] == "periodic":
            extra = (f", dominant harmonic {t['dominant_harmonic']} per revolution{segment_rate_text(t)}"
                     if t.get("dominant_harmonic")
                     else f", no harmonics over {t.get('why_no_harmonics', 'less than a revolution')}")
        elif t["kind"] == "local":
            extra = f", peak in {1e3 * t['peak_bin'][0]:.1f}..{1e3 * t['peak_bin'][1]:.1f} mm" + (
                f" of the {1e3 * t['tested_range'][0]:.1f}..{1e3 * t['tested_range'][1]:.1f} mm tested (the bins' "
                "effects are found up to a straight line in position: over a few bins the place is uncertain)"
                if t.get("tested_range") else "") + (
                f", {t['law']}" if t.get("law") else "")
        elif t["kind"] == "local_one_pass":
            extra = (f", peak in {1e3 * t['peak_bin'][0]:.1f}..{1e3 * t['peak_bin'][1]:.1f} mm "
                     f"{t['peak_mean']:+.3f} N m against the pass's other bins {t['rest_mean']:+.3f} +- "
                     f"{t['rest_sd']:.2g} ({t['compared']} bins compared, {t['law']}; one pass: a place or a moment)")
        elif t["kind"] == "drift":
            extra = ", slope per pass " + ", ".join(f"{v:.2g}+-{e:.1g}" for v, e in zip(t["slopes"], t["slope_stderr"])) \
                + f" N m/s over {t['segments']} segments" + (
                    f"; not a drift: {t['superseded_by']}" if t.get("superseded_by") else "") + (
                    f"; flagged by the {t['flagged_by']} (p {_num(t['time_or_position']['time_beyond_position']['p_value'], '.2g')})"
                    if t.get("flagged_by") else "")
        elif t["kind"] == "redundant_sensors":
            extra = f", gain {t['gain']:.4f} +- {t['gain_stderr']:.1g}, lag {1e3 * t['lag_s']:.1f}" + (
                f" +- {1e3 * t['lag_stderr']:.1g} ms (p {_num(t.get('lag_p_value'), '.2g')} against "
                f"+-{1e3 * t['lag_tolerance_s']:.1g} ms)" if t.get("lag_stderr") is not None else " ms") + (
                f" (the odd sensor: {t['odd_sensor']})" if t.get("odd_sensor") else "")
        elif t["kind"] == "time_or_position":
            extra = (f", position beyond time p {_num(t['position_beyond_time']['p_value'], '.2g')}, time beyond position"
                     f" p {_num(t['time_beyond_position']['p_value'], '.2g')} over {t['passes_per_direction']['extending']}"
                     f" + {t['passes_per_direction']['retracting']} passes: {t['verdict']}")
        elif t["kind"] == "breakaway":
            extra = (f", at {1e3 * t['peak_position']:.1f} mm {t['peak_deviation']:+.3f} A against the same kind of "
                     f"event elsewhere ({t['classes']} class(es) of starts/reversals seen at two places or more, "
                     f"{len(t['places'])} places, {t['replicate_dof']} replicate dof)")

        elif t["kind"] == "torque_constant_drift":
            extra = (f", current {1e3 * t['relative_rate']:+.2f}e-3 +- {1e3 * t['stderr']:.2f}e-3 /s of itself over "
                     f"{t['passes']} comparable passes ({len(t['classes'])} operating points): {t['verdict']}")
        elif t["kind"] == "sensor_offset":
            extra = f", offset {t['offset']:.3f} A over {t['samples']} samples"
        elif t["kind"] == "sensor_drift":
            extra = (f", load reading {t['slope']:.3g}+-{t['stderr']:.2g} N/s over {t['holds']} holds"
                     + (", the LVDT follows it: a real load change" if t.get("load_change_seen_by_lvdt") else "")
                     + ("" if t.get("witness", "lvdt") == "lvdt" else ", no LVDT: a real load change not excluded"))
        lines.append(f"    {t['variable']:<40} size {_num(t['size'], '.3g')} {t['unit']}, p {_num(t['p_value'], '.2g')}"
                     f"{extra}{'  <- STRUCTURED' if t['significant'] else ''}")
    return "\n".join(lines)


_STATE_COLOURS = {"slips": "C3", "undecided": "C1", "holds": "C2"}


def plot_holding(doc: dict):
    """Does the no-back hold: each drive-off stretch's nut travel back-driven by the load, against the time since
    the drive went off (:func:`~thsa_control.trace.holding.drive_off_holds`), coloured by its state, with the end
    window the state is read in shaded and one pawl pitch dashed; left the whole travel, right the first three
    pitches (a pawl's free travel and the braking after it)."""
    o = doc["no_back_holding"]["observed"]
    fig, axes = subplots(1, 2, figsize=(11, 3.8), squeeze=False)
    pitch = o.get("pawl_pitch_mm") or 0.0
    for k, ax in enumerate(axes[0]):
        seen: dict[str, int] = {}
        for s in o["stretches"]:
            c = s["curve"]
            n = seen[s["state"]] = seen.get(s["state"], -1) + 1  # stretches of one state told apart by line style
            line, = ax.plot(c["t_s"], c["mm"], color=_STATE_COLOURS[s["state"]], lw=1.2,
                            ls=("-", (0, (6, 2)), (0, (1, 1)), (0, (6, 2, 1, 2)))[n % 4],
                            label=f"{s['run']} {s['start']:.3g}..{s['end']:.3g} s, {abs(s['load_N']) / 1e3:.3g} kN "
                                  f"{s['side']}: {s['state']}" if k == 0 else None)
            if c["t_s"]:
                ax.axvspan(s["end_from_s"], c["t_s"][-1], color=line.get_color(), alpha=0.08, lw=0)
        if pitch > 0:
            ax.axhline(pitch, color="0.3", ls="--", lw=0.8, label="one pawl pitch" if k == 0 else None)
        ax.set_xlabel("time since the drive went off [s]", fontsize=8)
        ax.set_ylabel("nut travel back-driven by the load [mm]", fontsize=8)
        ax.axhline(0, color="0.6", lw=0.5)
    if pitch > 0:
        axes[0, 1].set_ylim(-0.3 * pitch, 3 * pitch)
        axes[0, 1].set_title("zoomed to three pawl pitches (shaded: the end window the state is read in)",
                             fontsize=9, wrap=True)
    else:
        axes[0, 1].set_visible(False)
    axes[0, 0].set_title(f"drive off, under load: {o['verdict'].upper()}", fontsize=9)
    axes[0, 0].legend(fontsize=7, loc="best")
    return fig


def write_trace_folder(folder: str | Path, result) -> dict:
    """``trace.json`` and ``report.html`` in ``folder`` (built inside an atomic folder by the caller)."""
    folder = Path(folder)
    doc = result.to_dict()
    write_json(folder / "trace.json", doc, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    figs = {}
    before, after = result.fits["before"], result.fits["after"]
    for run in doc["datasets"]:
        for ch in ("motor_speed", "nut_position"):
            if ch in before["predictions"][run["name"]]["measured"]:
                figs[f"{run['name']}: {ch} residual before and after"] = figure_png(
                    plot_residual_before_after(before, after, run["name"], ch))
    if doc["rounds"]:
        figs = {"candidates' held-out chi2 drops, per round": figure_png(plot_candidate_drops(doc)), **figs}
    if _periodic_tests(doc):
        figs["periodic candidates: held-out drop per period of nut travel (repetition test)"] = figure_png(
            plot_periodicity(doc))
    if ((doc.get("no_back_holding") or {}).get("observed") or {}).get("stretches"):
        figs["no-back holding: the nut travel the load back-drives with the drive off"] = figure_png(plot_holding(doc))
    figs["signature of the remaining residual (missing torque at the motor shaft)"] = figure_png(
        plot_signature(doc["residual_signature"]))
    write_html_report(folder / "report.html", title=f"Residual trace: {', '.join(d['name'] for d in doc['datasets'])}",
                      sections=[("Conclusion", Html(conclusion_table_html(doc))),
                                *([("What this record cannot tell apart", Html(separability_table_html(doc)))]
                                  if (doc.get("separability") or {}).get("explainers") else []),
                                ("Summary", format_trace_summary(doc))], figures=figs)
    return doc
