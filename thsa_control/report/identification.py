"""Identification and residual reports: figures and one self-contained HTML page.

Draws results computed elsewhere (:mod:`thsa_control.fit.replay`,
:mod:`thsa_control.fit.identify`, :mod:`thsa_control.fit.residuals`); computes no
physics.  Figures embed in the HTML as base64 PNG, so the page is one file.
Only ``thsa_control.report`` imports matplotlib.
"""

from __future__ import annotations

import base64
import html
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np  # noqa: E402

from ..data.units import signal_display
from .display import fmt
from .figure import png_bytes, subplots

__all__ = ["plot_overlay", "plot_residual_channel", "plot_segments", "figure_png", "write_html_report", "Html",
           "html_table", "residual_tables", "identification_tables",
           "write_residual_folder", "write_identification_folder"]

def _scale(channel: str) -> tuple[float, str]:
    """(factor SI -> display, display unit) of a channel, from the display-unit table."""
    du = signal_display(channel)
    return du.factor, du.unit


def plot_overlay(time, measured: Mapping[str, np.ndarray], simulated: Mapping[str, Mapping[str, np.ndarray]],
                 *, channels: Sequence[str] | None = None, title: str = "", axes=None):
    """Measured channels with one or more simulated versions overlaid, one panel per channel.

    Parameters
    ----------
    time : array_like
        [s].
    measured : mapping channel -> array (SI)
    simulated : mapping label -> mapping channel -> array (SI)
        E.g. ``{"before": ..., "after": ...}``.
    channels : sequence of str, optional
        Default: the measured channels.
    axes : sequence of Axes, optional
        One per channel; default a new figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    channels = list(channels or measured)
    t = np.asarray(time)
    if axes is None:
        fig, axes = subplots(len(channels), 1, figsize=(10, 2.4 * len(channels) + 0.6), sharex=True,
                             squeeze=False, constrained_layout=True)
    else:
        axes = np.asarray(list(np.ravel(axes)), dtype=object).reshape(-1, 1)
        fig = axes[0, 0].figure
    styles = ["tab:orange", "tab:blue", "tab:green", "tab:red"]
    for ax, c in zip(axes[:, 0], channels):
        k, unit = _scale(c)
        torque = c == "missing_torque"  # its two lines: what the measured motion needs, what the current gives
        ax.plot(t, np.asarray(measured[c]) * k, color="0.55", lw=0.8,
                label="needed by the measured motion" if torque else "measured")
        for (label, sim), color in zip(simulated.items(), styles):
            if c in sim:
                ax.plot(t, np.asarray(sim[c]) * k, color=color, lw=0.9,
                        label=f"given by the measured current ({label})" if torque else label)
        ax.set_ylabel("motor torque [N m]\n(missing = needed - given)" if torque else f"{c} [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(textwrap.fill(title, 100))  # a long replay description stays inside the figure
    return fig


def plot_segments(prediction: Mapping, *, title: str = "", axes=None):
    """Multiple-shooting fit of one run: data, segment predictions before/after, segment starts."""
    t = np.asarray(prediction["time"])
    chans = list(prediction["measured"])
    fig = plot_overlay(t, prediction["measured"], {"initial": prediction["initial"], "identified": prediction["simulated"]},
                       channels=chans, title=title, axes=axes)
    for ax in (fig.axes if axes is None else list(np.ravel(axes))):
        for s in np.asarray(prediction["segment_starts"]):
            ax.axvline(s, color="0.85", lw=0.5, zorder=0)
    return fig


def plot_residual_channel(time, channel, *, title: str = "", axes=None):
    """Residual of one channel: time series, autocorrelation with its band, spectrum (display units).

    ``channel`` is a :class:`thsa_control.fit.residuals.ChannelResiduals`; ``axes`` three Axes (default a new figure).
    """
    k, unit = _scale(channel.name)
    if axes is None:
        fig, axes = subplots(3, 1, figsize=(10, 8), constrained_layout=True)
    else:
        axes = list(np.ravel(axes))
        fig = axes[0].figure
    ax = axes[0]
    ax.plot(np.asarray(time), np.asarray(channel.residual) * k, lw=0.6)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"residual [{unit}]")
    ax.set_title(f"{channel.name}: RMS {channel.rms * k:.4g} {unit}, fit {channel.fit_percent:.2f} %")
    ax = axes[1]
    w = channel.whiteness
    ax.stem(w.lags, w.acf, basefmt=" ")
    ax.axhspan(-w.band, w.band, color="tab:blue", alpha=0.15, label="95 % band")
    ax.set_xlabel("lag [samples]")
    ax.set_ylabel("autocorrelation")
    ax.set_title(f"whiteness: Ljung-Box p = {w.ljung_box_p:.3g} ({'white' if w.white else 'NOT white'})")
    ax.legend(fontsize=8)
    ax = axes[2]
    sp = channel.spectrum
    if len(sp.frequency):
        ax.semilogy(sp.frequency, np.maximum(np.asarray(sp.psd) * k ** 2, 1e-300))  # display unit^2 / Hz
        for p in sp.peaks:
            ax.axvline(p.frequency, color="tab:red", lw=0.6)
        ax.set_title("spectrum of the residual (red: peaks)")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"PSD [{unit}^2/Hz]" if unit not in ("", "-") else "PSD [1/Hz]")
    for a in axes:
        a.grid(True, alpha=0.3)
    fig.suptitle(title)
    return fig


def figure_png(fig, dpi: int = 100) -> bytes:
    """PNG bytes of ``fig``; the figure is closed."""
    data = png_bytes(fig, dpi=dpi)
    fig.clear()
    return data


class Html(str):
    """A section body that is already HTML (tables); a plain ``str`` is shown as preformatted text."""


_PAGE_CSS = ("body{font-family:system-ui,Segoe UI,Helvetica,Arial,sans-serif;max-width:1150px;margin:1.2em auto;"
             "color:#222}h1{font-size:1.45em}h2{font-size:1.15em;border-bottom:1px solid #ccc;margin-top:1.6em;"
             "scroll-margin-top:2.6em}pre{background:#f6f6f6;padding:1em;overflow-x:auto;font-size:12px;white-space:pre-wrap;overflow-wrap:anywhere}"
             "img{max-width:100%;border:1px solid #ddd}table{border-collapse:collapse;font-size:13px;margin:0.4em 0}"
             "td,th{border:1px solid #ccc;padding:2px 7px;text-align:right;vertical-align:top}th{background:#f0f0f0}"
             "td.l,th.l{text-align:left}td.bad{background:#fde7e6}td.ok{background:#e3f4e5}td.warn{background:#fff3c4}"
             "caption{caption-side:top;text-align:left;font-size:12px;color:#555}.note{font-size:12px;color:#555}"
             "nav{position:sticky;top:0;background:#fff;border-bottom:1px solid #ccc;padding:6px 0;z-index:5;"
             "font-size:13px;display:flex;flex-wrap:wrap;row-gap:2px}nav a{margin-right:1em;color:#1a4f8b;text-decoration:none;white-space:nowrap}"
             "figure{margin:0.6em 0}figcaption{font-size:12px;color:#555}")


def _anchor(text: str) -> str:
    return "s-" + "".join(ch if ch.isalnum() else "-" for ch in text.lower()).strip("-")[:60]


def html_table(header: Sequence[str], rows: Sequence[Sequence], *, caption: str = "", classes=None,
               left: Sequence[int] = (0,)) -> Html:
    """An HTML table; cells are escaped unless they are :class:`Html`; ``classes[i][j]`` a cell class."""
    out = ["<table>"]
    if caption:
        out.append(f"<caption>{html.escape(caption)}</caption>")
    out.append("<tr>" + "".join(f"<th class='l'>{html.escape(h)}</th>" if j in left else f"<th>{html.escape(h)}</th>"
                                 for j, h in enumerate(header)) + "</tr>")
    for i, row in enumerate(rows):
        cells = []
        for j, cell in enumerate(row):
            text = cell if isinstance(cell, Html) else html.escape(str(cell))
            cls = [c for c in (("l" if j in left else ""), (classes[i][j] if classes else "")) if c]
            cells.append(f"<td class='{' '.join(cls)}'>{text}</td>" if cls else f"<td>{text}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return Html("\n".join(out))


def write_html_report(path: str | Path, *, title: str, sections: Sequence[tuple[str, str]],
                      figures: Mapping[str, bytes], figures_first: bool = True, lead: str = "") -> Path:
    """Write one self-contained HTML page: a navigation bar, then the figures and the sections.

    Parameters
    ----------
    path : path
        Target file (its folder must exist; callers build in
        :func:`~thsa_control.report.build.atomic_folder`).
    title : str
    sections : sequence of (heading, body)
        A body of type :class:`Html` (tables) is inserted as it is; a plain ``str``
        (an lmfit-style text report) is shown preformatted.
    figures : mapping caption -> PNG bytes
        Embedded in order as base64 images.
    figures_first : bool
        Figures before the sections (what a reader looks at first), else after.
    lead : str
        One line of HTML under the title (the verdict).

    Returns
    -------
    Path
    """
    body_sections = []
    for heading, text in sections:
        body = text if isinstance(text, Html) else f"<pre>{html.escape(text)}</pre>"
        body_sections.append((heading, f"<h2 id='{_anchor(heading)}'>{html.escape(heading)}</h2>\n{body}"))
    figs = []
    for caption, png in figures.items():
        data = base64.b64encode(png).decode("ascii")
        figs.append(f"<figure><img alt='{html.escape(caption)}' src='data:image/png;base64,{data}'>"
                    f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    links = [(_anchor(h), h) for h, _ in sections]
    fig_block = ("<h2 id='figures'>Figures</h2>\n" + "\n".join(figs)) if figs else ""
    if figs:
        links = [("figures", "Figures")] + links if figures_first else links + [("figures", "Figures")]
    nav = "<nav>" + "".join(f"<a href='#{a}'>{html.escape(t if len(t) < 48 else t[:45] + '...')}</a>"
                            for a, t in links) + "</nav>"
    parts = [f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
             f"<style>{_PAGE_CSS}</style></head><body>", nav, f"<h1>{html.escape(title)}</h1>"]
    if lead:
        parts.append(f"<p>{lead}</p>")
    if figures_first:
        parts.append(fig_block)
    parts += [b for _, b in body_sections]
    if not figures_first:
        parts.append(fig_block)
    parts.append("</body></html>\n")
    path = Path(path)
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


def _p(p) -> str:
    return "-" if p is None or not np.isfinite(p) else ("< 1e-4" if p < 1e-4 else f"{p:.3g}")


def residual_tables(analysis) -> list[tuple[str, Html]]:
    """The residual analysis as HTML tables: per channel, then where the residual concentrates."""
    rows, classes = [], []
    for c in analysis.channels.values():
        k, unit = _scale(c.name)
        w = c.whiteness
        corr = [n for n, x in c.cross.items() if x.correlated]
        rows.append([c.name, unit, fmt(c.rms * k), fmt(c.mean * k), f"{fmt(c.max_abs * k)} at {c.time_of_max:.3g} s",
                     fmt(c.nrmse), f"{c.fit_percent:.2f}", f"{'white' if w.white else 'NOT white'} (p {_p(w.ljung_box_p)})",
                     ", ".join(corr) or "none"])
        classes.append([""] * 7 + ["ok" if w.white else "bad", "bad" if corr else "ok"])
    out = [("Residual per channel", html_table(
        ["channel", "unit", "RMS", "mean (bias)", "max |residual|", "NRMSE [-]", "fit [%]", "whiteness (Ljung-Box)",
         "correlated with inputs"], rows, classes=classes, left=(0, 1, 8),
        caption=f"residual = measured - simulated; {analysis.time.size} samples, confidence "
                f"{100 * analysis.settings.confidence:g} %. Channels in display units (data/units.py)."))]
    rows, quiet = [], []
    for c in analysis.channels.values():
        k, unit = _scale(c.name)
        for v in sorted(c.conditioned.values(), key=lambda v: -v.eta_squared):
            sig = [b for b in v.bins if b.significant]
            if not sig:
                quiet.append(f"{c.name} / {v.signal}")
                continue
            du = signal_display(v.signal)
            for b in sig:
                if v.binning == "categorical":  # a named category (quadrant, direction) or one numeric value
                    numeric = np.isfinite(b.low) and b.label == f"{b.low:g}"
                    where = f"{du.to_display(b.low):.4g} {du.unit}" if numeric else b.label
                else:
                    where = f"{du.to_display(b.low):.4g} .. {du.to_display(b.high):.4g} {du.unit}"
                rows.append([c.name, v.signal, where, str(b.count), f"{b.mean * k:+.4g} {unit}", f"{b.rms * k:.4g} {unit}",
                             f"{b.excess_ratio:.3g}", _p(b.excess_p), f"{v.eta_squared:.3f}"])
    caption = ("Operating conditions where the residual is significantly larger than elsewhere (F-test, "
               "Bonferroni-corrected): where the model fails. " +
               (f"No significant bin for: {', '.join(quiet)}." if quiet else ""))
    if rows:
        out.append(("Where the residual concentrates", html_table(
            ["channel", "conditioned on", "bin", "samples", "mean", "RMS", "mean-square ratio [-]", "p [-]", "eta^2 [-]"],
            rows, caption=caption, left=(0, 1, 2))))
    else:
        out.append(("Where the residual concentrates", Html(f"<p class='note'>{html.escape(caption)} "
                                                           "No bin of any conditioning signal stands out.</p>")))
    return out


def _text_block(summary: str, text: str) -> Html:
    return Html(f"<details><summary>{html.escape(summary)}</summary><pre>{html.escape(text)}</pre></details>")


def identification_tables(result) -> list[tuple[str, Html]]:
    """An :class:`~thsa_control.fit.identify.IdentificationResult` as HTML tables (lmfit's report, tabulated)."""
    flagged = set(result.not_identifiable)
    rows, classes = [], []
    for n, e in result.estimates.items():
        rel = e.relative_stderr
        pct = f"{100 * rel:.2g} %" if np.isfinite(rel) and rel < 1e3 else "-"
        lo, hi = e.interval() if np.isfinite(e.stderr) else (np.nan, np.nan)
        flags = []
        if e.at_bound:
            flags.append(f"at {e.at_bound} bound")
        if e.at_initial:
            flags.append("did not move")
        if n in flagged:
            flags.append("not identifiable")
        partners = [b if a == n else a for a, b, r in result.high_correlations if n in (a, b)]
        if partners:
            flags.append(f"correlated with {', '.join(partners)}")
        rows.append([n, fmt(e.value, 6), fmt(e.stderr, 3) if np.isfinite(e.stderr) else "undetermined", pct,
                     f"{fmt(lo)} .. {fmt(hi)}" if np.isfinite(lo) else "-", e.unit, fmt(e.init, 6),
                     f"{fmt(e.min)} .. {fmt(e.max)}", "; ".join(flags) or "ok"])
        classes.append([""] * 8 + ["bad" if (n in flagged or e.at_bound) else ("warn" if flags else "ok")])
    params = html_table(["parameter", "value", "standard error", "relative", "95 % interval", "unit", "initial",
                         "search bounds", "verdict"], rows, classes=classes, left=(0, 5, 8),
                        caption="Values in the parameter's own unit (SI). 'not identifiable': the data do not "
                                "determine it (standard error undetermined, or larger than the value); "
                                "'correlated with': the pair moves together (|rho| > "
                                f"{result.settings.correlation_threshold:g}), its standard error already counts it.")
    stats = html_table(["statistic", "value"], [
        ["method", f"{result.method} (effects: {', '.join(result.effects) or 'functional'})"],
        ["runs", ", ".join(result.runs)], ["solver", f"scipy least_squares trf: {result.status}"],
        ["converged", "yes" if result.converged else "NO: the estimates are the best point found before the limit"],
        ["function evaluations", f"{result.nfev} (jacobians {result.njev}), {result.time_s:.1f} s"],
        ["data points", str(result.n_data)],
        ["free variables", f"{result.n_free} parameters + {result.n_varys - result.n_free} segment states"],
        ["chi-square / reduced", f"{result.chisqr:.6g} / {result.redchi:.6g}"],
        ["AIC / BIC", f"{result.aic:.6g} / {result.bic:.6g}"]], left=(0, 1))
    names = list(result.names)
    pairs = sorted(((names[i], names[j], result.correlation[i, j]) for i in range(len(names))
                    for j in range(i + 1, len(names)) if np.isfinite(result.correlation[i, j])),
                   key=lambda p: -abs(p[2]))
    corr = html_table(["pair", "correlation [-]"], [[f"{a} / {b}", f"{r:+.4f}"] for a, b, r in pairs],
                      classes=[["", "warn" if abs(r) > result.settings.correlation_threshold else ""]
                               for _, _, r in pairs]) if pairs else Html("<p class='note'>One free parameter.</p>")
    rows = []
    for run, chans in result.channel_fits.items():
        for c, f in chans.items():
            f0 = result.initial_channel_fits[run][c]
            k, unit = _scale(c)
            rows.append([run, c, unit, fmt(f0.rms * k), fmt(f.rms * k), fmt(f0.nrmse), fmt(f.nrmse),
                         f"{f0.fit_percent:.2f}", f"{f.fit_percent:.2f}"])
    chans = html_table(["run", "channel", "unit", "RMS initial", "RMS identified", "NRMSE initial [-]",
                        "NRMSE identified [-]", "fit initial [%]", "fit identified [%]"], rows, left=(0, 1, 2),
                       caption="Multiple-shooting segment predictions, initial and identified parameters.")
    return [("Parameters", params), ("Channels", chans), ("Correlations", corr), ("Fit statistics", stats)]


def _fits(replay_result) -> dict:
    return {c: f.to_dict() for c, f in replay_result.fits.items()}


def write_residual_folder(folder: str | Path, replay_result, analysis, *, title: str | None = None) -> dict:
    """``residuals.json``, ``report.html`` (overlay, residual figures, residual report) in ``folder``.

    ``residuals.json``: ``run``, ``mode`` (``closed_loop`` / ``open_loop``),
    ``effects``, ``fits`` (per channel: RMS, NRMSE, fit %), ``residuals``
    (:meth:`ResidualAnalysis.summary`), and for an open-loop replay
    ``open_loop_replay`` (``segmented``: restarted from the measured state
    every ``segment_s`` seconds, ``segments`` of them, with the inverse-model
    channel ``missing_torque`` [N m] and ``reflected_inertia_median``
    [kg m^2]; ``whole_run``: one replay, ``segment_s`` null).

    Returns the JSON content.
    """
    from .build import write_json

    folder = Path(folder)
    r = replay_result
    how = r.mode.replace("_", " ")
    if r.info.get("open_loop_replay") == "segmented":
        how += f" (restarted from the measured state every {r.info['segment_s']:.4g} s)"
    elif r.info.get("open_loop_replay") == "whole_run":
        how += " (whole run, not restarted)"
    title = title or f"Residuals of {r.run_name}: {how} replay, effects {', '.join(r.effects) or 'level A'}"
    summary = {"run": r.run_name, "mode": r.mode, "effects": list(r.effects), "fits": _fits(r),
               "residuals": analysis.summary()}
    if r.mode == "open_loop":  # which open-loop replay: segmented (one-segment prediction errors) or whole run
        summary["open_loop_replay"] = r.info.get("open_loop_replay", "whole_run")
        summary["segment_s"] = r.info.get("segment_s")
        summary["segments"] = r.info.get("segments", 1)
        if "reflected_inertia_median" in r.info:
            summary["reflected_inertia_median"] = r.info["reflected_inertia_median"]
    write_json(folder / "residuals.json", summary)
    figures = {"measured and simulated": figure_png(plot_overlay(r.time, r.measured, {r.mode: {**r.simulated, **r.compared}},
                                                                 channels=list(r.fits), title=title))}
    for c in analysis.channels.values():
        figures[f"residual of {c.name}"] = figure_png(plot_residual_channel(analysis.time, c, title=f"{r.run_name}: {c.name}"))
    sections = residual_tables(analysis) + [("Full residual analysis (text)", _text_block(
        "click to open the full text report (every conditioning signal and bin)", analysis.report()))]
    worst = min(analysis.channels.values(), key=lambda c: c.fit_percent, default=None)
    lead = (f"Lowest fit: <b>{html.escape(worst.name)} {worst.fit_percent:.1f} %</b>; residual "
            f"{'white' if worst.whiteness.white else '<b>not white</b>'} on that channel." if worst else "")
    write_html_report(folder / "report.html", title=title, sections=sections, figures=figures, lead=lead)
    return summary


def write_identification_folder(folder: str | Path, result, before: Sequence, after: Sequence,
                                analyses: Sequence) -> dict:
    """``result.json``, ``parameters.toml`` and ``report.html`` of an identification in ``folder``.

    ``before`` / ``after`` are replays of each run at the initial and identified
    parameters, ``analyses`` the residual analyses of the ``after`` replays.
    """
    from .build import write_json

    folder = Path(folder)
    doc = result.to_dict()
    doc["replays"] = {b.run_name: {"mode": b.mode, "before": _fits(b), "after": _fits(a),
                                   "residuals": an.summary()} for b, a, an in zip(before, after, analyses)}
    write_json(folder / "result.json", doc)
    result.save_parameters(folder / "parameters.toml")
    figures = {}
    for name, pred in result.predictions.items():
        figures[f"{name}: multiple-shooting segments, initial and identified"] = figure_png(
            plot_segments(pred, title=f"{name}: segment predictions (grey lines: segment starts)"))
    sections = identification_tables(result)
    for b, a, an in zip(before, after, analyses):
        figures[f"{b.run_name}: {b.mode.replace('_', ' ')} replay before and after"] = figure_png(plot_overlay(
            b.time, b.measured, {"initial": b.simulated, "identified": a.simulated}, channels=list(b.fits),
            title=f"{b.run_name}: {b.mode.replace('_', ' ')} replay"))
        for c in an.channels.values():
            figures[f"{b.run_name}: residual of {c.name} (identified)"] = figure_png(
                plot_residual_channel(an.time, c, title=f"{b.run_name}: {c.name}, identified model"))
        rows = []
        for c in a.fits:
            k, unit = _scale(c)
            rows.append([c, unit, f"{b.fits[c].fit_percent:.2f}", f"{a.fits[c].fit_percent:.2f}",
                         fmt(b.fits[c].rms * k), fmt(a.fits[c].rms * k)])
        sections.append((f"{b.run_name}: {b.mode.replace('_', ' ')} replay, initial -> identified", html_table(
            ["channel", "unit", "fit initial [%]", "fit identified [%]", "RMS initial", "RMS identified"], rows,
            left=(0, 1))))
        for heading, table in residual_tables(an):
            sections.append((f"{b.run_name}: {heading.lower()} (identified)", table))
    sections.append(("Full fit report (text)", _text_block("click to open the lmfit-style text report",
                                                           result.fit_report())))
    flagged = [n for n in result.estimates if n in result.not_identifiable]
    values = "; ".join(
        f"<b>{html.escape(n)} = {e.value:.4g}</b> {html.escape(e.unit)}"
        + (f" &plusmn; {100 * e.relative_stderr:.2g} %" if np.isfinite(e.relative_stderr) and e.relative_stderr < 1e3
           else " (standard error undetermined)") for n, e in result.estimates.items())
    lead = (f"{values}.<br>{len(result.estimates)} parameter(s) fitted, "
            f"{'converged' if result.converged else '<b>NOT converged</b>'}"
            + (f"; <b>not identifiable from these runs: {html.escape(', '.join(flagged))}</b>" if flagged else
               "; every parameter determined by the data") + " (tables under the figures).")
    write_html_report(folder / "report.html", title=f"Identification: {', '.join(result.runs)}",
                      sections=sections, figures=figures, lead=lead)
    return doc
