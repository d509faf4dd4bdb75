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

from .figure import png_bytes, subplots

__all__ = ["plot_overlay", "plot_residual_channel", "plot_segments", "figure_png", "write_html_report",
           "write_residual_folder", "write_identification_folder"]

#: Display scale and unit per channel (SI -> display).
_DISPLAY = {"motor_speed": (60 / (2 * np.pi), "rpm"), "screw_speed": (60 / (2 * np.pi), "rpm"),
            "nut_position": (1e3, "mm"), "motor_current": (1.0, "A"), "nut_speed": (1e3, "mm/s"),
            "missing_torque": (1.0, "N m")}


def _scale(channel: str) -> tuple[float, str]:
    return _DISPLAY.get(channel, (1.0, "SI"))


def plot_overlay(time, measured: Mapping[str, np.ndarray], simulated: Mapping[str, Mapping[str, np.ndarray]],
                 *, channels: Sequence[str] | None = None, title: str = ""):
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

    Returns
    -------
    matplotlib.figure.Figure
    """
    channels = list(channels or measured)
    t = np.asarray(time)
    fig, axes = subplots(len(channels), 1, figsize=(10, 2.4 * len(channels) + 0.6), sharex=True,
                             squeeze=False, constrained_layout=True)
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


def plot_segments(prediction: Mapping, *, title: str = ""):
    """Multiple-shooting fit of one run: data, segment predictions before/after, segment starts."""
    t = np.asarray(prediction["time"])
    chans = list(prediction["measured"])
    fig = plot_overlay(t, prediction["measured"], {"initial": prediction["initial"], "identified": prediction["simulated"]},
                       channels=chans, title=title)
    for ax in fig.axes:
        for s in np.asarray(prediction["segment_starts"]):
            ax.axvline(s, color="0.85", lw=0.5, zorder=0)
    return fig


def plot_residual_channel(time, channel, *, title: str = ""):
    """Residual of one channel: time series, autocorrelation with its band, spectrum.

    ``channel`` is a :class:`thsa_control.fit.residuals.ChannelResiduals`.
    """
    k, unit = _scale(channel.name)
    fig, axes = subplots(3, 1, figsize=(10, 8), constrained_layout=True)
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
        ax.semilogy(sp.frequency, np.maximum(sp.psd, 1e-300))
        for p in sp.peaks:
            ax.axvline(p.frequency, color="tab:red", lw=0.6)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("PSD [SI^2/Hz]")
    for a in axes:
        a.grid(True, alpha=0.3)
    fig.suptitle(title)
    return fig


def figure_png(fig, dpi: int = 100) -> bytes:
    """PNG bytes of ``fig``; the figure is closed."""
    data = png_bytes(fig, dpi=dpi)
    fig.clear()
    return data


def write_html_report(path: str | Path, *, title: str, sections: Sequence[tuple[str, str]],
                      figures: Mapping[str, bytes]) -> Path:
    """Write one self-contained HTML page.

    Parameters
    ----------
    path : path
        Target file (its folder must exist; callers build in
        :func:`~thsa_control.report.build.atomic_folder`).
    title : str
    sections : sequence of (heading, preformatted text)
        Fit report, residual report, summaries.
    figures : mapping caption -> PNG bytes
        Embedded in order as base64 images.

    Returns
    -------
    Path
    """
    parts = [f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
             "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}"
             "pre{background:#f6f6f6;padding:1em;overflow-x:auto;font-size:12px}"
             "img{max-width:100%;border:1px solid #ddd}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>"]
    for heading, text in sections:
        parts.append(f"<h2>{html.escape(heading)}</h2>\n<pre>{html.escape(text)}</pre>")
    for caption, png in figures.items():
        data = base64.b64encode(png).decode("ascii")
        parts.append(f"<figure><img alt='{html.escape(caption)}' src='data:image/png;base64,{data}'>"
                     f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    parts.append("</body></html>\n")
    path = Path(path)
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


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
    from ..fit.residuals import format_residual_report
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
    write_html_report(folder / "report.html", title=title,
                      sections=[("Residual analysis", format_residual_report(analysis))], figures=figures)
    return summary


def write_identification_folder(folder: str | Path, result, before: Sequence, after: Sequence,
                                analyses: Sequence) -> dict:
    """``result.json``, ``parameters.toml`` and ``report.html`` of an identification in ``folder``.

    ``before`` / ``after`` are replays of each run at the initial and identified
    parameters, ``analyses`` the residual analyses of the ``after`` replays.
    """
    from ..fit.residuals import format_residual_report
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
    sections = [("Fit report", result.fit_report())]
    for b, a, an in zip(before, after, analyses):
        figures[f"{b.run_name}: {b.mode.replace('_', ' ')} replay before and after"] = figure_png(plot_overlay(
            b.time, b.measured, {"initial": b.simulated, "identified": a.simulated}, channels=list(b.fits),
            title=f"{b.run_name}: {b.mode.replace('_', ' ')} replay"))
        for c in an.channels.values():
            figures[f"{b.run_name}: residual of {c.name} (identified)"] = figure_png(
                plot_residual_channel(an.time, c, title=f"{b.run_name}: {c.name}, identified model"))
        lines = [f"{c}: fit {b.fits[c].fit_percent:.2f} % -> {a.fits[c].fit_percent:.2f} %, RMS {b.fits[c].rms:.4g} -> "
                 f"{a.fits[c].rms:.4g} [{a.fits[c].unit}]" for c in a.fits]
        sections.append((f"{b.run_name}: {b.mode.replace('_', ' ')} replay, initial -> identified", "\n".join(lines)))
        sections.append((f"{b.run_name}: residual analysis (identified)", format_residual_report(an)))
    write_html_report(folder / "report.html", title=f"Identification: {', '.join(result.runs)}",
                      sections=sections, figures=figures)
    return doc
