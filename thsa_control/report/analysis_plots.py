"""Figures of the loop-analysis report (matplotlib; re-exported by :mod:`.analysis_report`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import ListedColormap
from matplotlib.patches import Patch, Rectangle
from matplotlib.ticker import MultipleLocator

from ..data.units import display_unit, label
from ..loops.catalog import LOOPS, METRIC_LABELS
from .display import (
    STATUS_COLORS,
    STATUS_LABELS,
    gain_margins_text,
    metric_display,
    requirement_for,
    requirement_limit_text,
    requirement_status,
)
from .figure import colormap, new_figure, subplots

if TYPE_CHECKING:  # annotations only: the loop analysis calls this module, not the reverse
    from ..loops.loop_analysis import LoopAnalysis

__all__ = ["plot_loop_bode", "plot_steps", "plot_margin_maps", "plot_velocity_poles", "plot_friction_slopes",
           "plot_switching"]

_LOOP_TITLE = {"current_loop": "current loop", "velocity_loop": "velocity loop", "position_loop": "position loop"}
_CMAP = colormap("coolwarm")


def _tcolor(t: float):
    return _CMAP((t + 55.0) / 125.0)


def _hz(w):
    return np.asarray(w) / (2 * np.pi)


# ----------------------------------------------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------------------------------------------
def _phase_branches(L: np.ndarray, f: np.ndarray, crossover_hz: np.ndarray) -> np.ndarray:
    """Unwrapped phase [deg] of each curve on the branch where its gain-crossover phase is in (-360, 0].

    The last sample (Nyquist, where a sampled response is real) is dropped (nan) when the phase turns by
    more than 30 deg over the last grid interval: a zero or pole near ``z = -1`` that the log grid does
    not resolve, which would otherwise draw a vertical jump.
    """
    ph = np.degrees(np.unwrap(np.angle(L), axis=1))
    jc = np.where(np.isfinite(crossover_hz),
                  np.argmin(np.abs(f[None, :] - np.nan_to_num(crossover_hz)[:, None]), axis=1), f.size - 1)
    ph -= 360 * np.ceil(ph[np.arange(len(ph)), jc] / 360)[:, None]
    jump = np.abs(ph[:, -1] - ph[:, -2]) > 30
    ph[jump, -1] = np.nan
    return ph


def _phase_crossings(L: np.ndarray, f: np.ndarray) -> list[tuple[float, float]]:
    """``(frequency [Hz], gain margin [dB])`` of every crossing of the negative real axis of one curve.

    Grid resolution (the analysis refines the margins it reports); Nyquist included when ``L`` is
    negative there.
    """
    im, re = L.imag, L.real
    out = []
    for j in np.flatnonzero((np.signbit(im[:-2]) != np.signbit(im[1:-1])) & ((re[:-2] < 0) | (re[1:-1] < 0))):
        t = im[j] / (im[j] - im[j + 1])  # linear interpolation in the grid interval
        x = L[j] + t * (L[j + 1] - L[j])
        if x.real < 0:
            out.append((float(f[j] + t * (f[j + 1] - f[j])), float(-20 * np.log10(abs(x)))))
    if re[-1] < 0:
        out.append((float(f[-1]), float(-20 * np.log10(abs(L[-1])))))
    return out


def plot_loop_bode(analysis: LoopAnalysis, loop: str, axes=None):
    """Open-loop Bode plot of ``loop`` across the grid, the worst point highlighted.

    Grey: every valid grid point; colour: the reference point at each
    temperature; black: the point of the worst phase margin, with its gain
    crossover, its -180 deg crossings and the gain margin at each of them
    (a negative one, below 0 dB, is a lower gain margin: the loop is
    conditionally stable there).  The phase is unwrapped along each curve and
    put on the branch where the phase margin reads as ``phase + 180``; the
    axis is limited to -405..+45 deg (curves beyond it leave the plot).

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
        fig, axes = subplots(2, 1, figsize=(9, 6.8), sharex=True, constrained_layout=True)
    else:
        fig = axes[0].figure
    ax_m, ax_p = axes
    lm = analysis.loops[loop]
    mg = lm.margins
    f = _hz(mg.omega)
    L = mg.L
    with np.errstate(divide="ignore"):
        mag = 20 * np.log10(np.abs(L))
    ph = _phase_branches(L, f, mg.crossover_hz)
    ks = np.flatnonzero(analysis.valid)
    ax_m.add_collection(LineCollection([np.column_stack([f, mag[k]]) for k in ks], colors="0.82", lw=0.5, zorder=1))
    ax_p.add_collection(LineCollection([np.column_stack([f, ph[k]]) for k in ks], colors="0.82", lw=0.5, zorder=1))
    ax_m.set_xscale("log")
    ax_m.set_xlim(f[0], f[-1] * 1.05)
    refs = analysis.reference_indices()
    for temp, k in refs.items():
        c = _tcolor(temp)
        ax_m.semilogx(f, mag[k], color=c, lw=1.3,
                      label=f"{temp:g} degC: PM {mg.phase_margin_deg[k]:.1f} deg at {mg.crossover_hz[k]:.3g} Hz",
                      zorder=3)
        ax_p.semilogx(f, ph[k], color=c, lw=1.3, zorder=3)
    # the worst case, highlighted, with its crossings and margins
    w = analysis.worst(loop, "phase_margin_deg")
    wg = analysis.worst(loop, "gain_margin_db")  # the gain margin nearest 0 dB: its point may differ from the PM's
    if w is not None:
        k = w.index
        where = "every valid point alike" if w.uniform else w.condition.label()
        also = (f" and worst GM ({gain_margins_text(mg.gain_margin_lower_db[k], mg.gain_margin_upper_db[k])})"
                if wg is not None and wg.index == k else "")
        ax_m.semilogx(f, mag[k], color="k", lw=2.2, zorder=5, label=f"worst PM {w.value:.1f} deg{also}: {where}")
        ax_p.semilogx(f, ph[k], color="k", lw=2.2, zorder=5)
        wc = mg.crossover_hz[k]
        if np.isfinite(wc):
            ax_m.plot([wc], [0.0], "o", color="k", ms=6, zorder=6)
            ph_c = np.interp(np.log(wc), np.log(f), ph[k])
            ax_p.plot([wc, wc], [-180 + 360 * round((ph_c + 180) / 360), ph_c], color="tab:green", lw=2.5, zorder=6)
            ax_p.annotate(f"PM {w.value:.1f} deg", (wc, ph_c), xytext=(6, 6), textcoords="offset points",
                          fontsize=8, color="tab:green", zorder=8,
                          bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.85))
    m_lo = max(np.nanpercentile(mag[ks], 1) - 5, -120) if ks.size else -120
    if wg is not None:
        k = wg.index
        color = "k" if (w is not None and w.index == k) else "tab:purple"
        if color != "k":
            where = "every valid point alike" if wg.uniform else wg.condition.label()
            ax_m.semilogx(f, mag[k], color=color, lw=1.8, ls="--", zorder=4,
                          label=f"worst gain margin ({gain_margins_text(mg.gain_margin_lower_db[k], mg.gain_margin_upper_db[k])}): {where}")
            ax_p.semilogx(f, ph[k], color=color, lw=1.8, ls="--", zorder=4)
        for fc, gm in _phase_crossings(L[k], f):
            if not -gm > m_lo or (fc == f[-1] and np.isnan(ph[k][-1])):
                continue  # off the magnitude axis (a zero near z = -1), or at an unresolved Nyquist turn
            ph_x = np.interp(np.log(fc), np.log(f), ph[k])
            ax_p.plot([fc], [ph_x], "X", color="tab:red", ms=8, zorder=7)
            m_x = -gm
            ax_m.plot([fc, fc], [min(m_x, 0.0), max(m_x, 0.0)], color="tab:red", lw=2.5, zorder=6)
            ax_m.plot([fc], [m_x], "X", color="tab:red", ms=8, zorder=7)
            kind = "lower GM" if gm < 0 else "upper GM"
            ax_m.annotate(f"{kind} {gm:+.1f} dB", (fc, m_x), xytext=(-8, 8 if gm > 0 else -16),
                          textcoords="offset points", ha="right", fontsize=8, color="tab:red", zorder=8,
                          bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.85))
    ax_m.axhline(0, color="k", lw=0.7)
    for y in (-180.0, -540.0, 180.0):
        ax_p.axhline(y, color="k", lw=0.7)
    ax_p.axvline(f[-1], color="0.5", lw=0.7, ls=":")
    finite = mag[ks][np.isfinite(mag[ks])] if ks.size else np.array([-60.0, 60.0])
    lo, hi = np.percentile(finite, [1, 99]) if finite.size else (-60, 60)
    ax_m.set_ylim(max(lo - 5, -120), min(hi + 10, 150))
    ax_m.set_ylabel("|L| [dB]")
    ax_p.set_ylabel("phase of L [deg]")
    ax_p.set_xlabel("frequency [Hz] (dotted: Nyquist)")
    ph_ok = ph[ks][np.isfinite(ph[ks])] if ks.size else np.array([-180.0])
    ax_p.set_ylim(max(np.min(ph_ok) - 15, -405), min(np.max(ph_ok) + 15, 45))
    ax_p.yaxis.set_major_locator(MultipleLocator(90))
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    ref = analysis.conditions[next(iter(refs.values()))] if refs else None
    where = f"{ref.nut_speed * 1e3:g} mm/s, {ref.load_force * 1e-3:g} kN" if ref else "-"
    ax_m.legend(fontsize=7, loc="lower left", title=f"reference point {where}", title_fontsize=7)
    ax_m.set_title(f"{_LOOP_TITLE[loop]}: open loop L(z); grey: every valid grid point; black: worst phase margin"
                   f"{'' if wg is None or (w is not None and w.index == wg.index) else '; dashed: worst gain margin'}"
                   "\nred: -180 deg crossings at the worst gain margin (lower GM < 0 dB: the gain may fall that much; "
                   "upper: rise)", fontsize=9)
    return fig


def plot_steps(analysis: LoopAnalysis):
    """Step responses: reference steps per temperature, velocity steps over the grid, load steps.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, axes = subplots(2, 3, figsize=(14, 7.5), constrained_layout=True)
    refs = analysis.reference_indices()
    scale = {"current_loop": (1e3, "ms"), "velocity_loop": (1e3, "ms"), "position_loop": (1.0, "s")}
    for j, loop in enumerate(LOOPS):
        lm = analysis.loops[loop]
        ax = axes[0, j]
        s, unit = scale[loop]
        for temp, k in refs.items():  # the current loop's step drawn as the sampled staircase it is
            ax.plot(lm.step_time * s, lm.step[k], color=_tcolor(temp), label=f"{temp:g} degC",
                    drawstyle="steps-post" if loop == "current_loop" else "default")
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
    for j, (loop, quantity, what) in enumerate((("velocity_loop", "velocity_load_step", "nut speed"),
                                                ("position_loop", "position_load_step", "nut position"))):
        factor, unit = display_unit(quantity).factor, label(what, quantity)
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
                     metrics=("phase_margin_deg", "gain_margin_db", "ms"), requirements: dict | None = None):
    """Maps of ``metrics`` of ``loop`` over speed x load, one column per temperature, coloured by the requirement.

    Each cell is coloured against the design's requirement on that metric,
    not scaled to the data: red fails, amber passes within
    :data:`~thsa_control.report.display.NEAR_FRACTION` of the limit, green
    passes with room, blue-grey has no requirement.  The cell shows the value
    (a gain margin signed: negative is the lower margin of a conditionally
    stable loop, compared by magnitude).  Invalid points are hatched; the worst
    valid point of each metric is framed.  Needs a grid analysis.

    Parameters
    ----------
    requirements : dict, optional
        The loop's requirement table; default ``analysis.design.requirements[loop]``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    grid = analysis.grid
    if grid is None:
        raise ValueError("plot_margin_maps needs an analysis over a ConditionGrid")
    if requirements is None:
        requirements = dict(getattr(analysis.design, "requirements", {}).get(loop, {}))
    nT, nV, nF = grid.shape
    fig, axes = subplots(len(metrics), nT, figsize=(2.9 * nT + 0.6, 2.7 * len(metrics) + 1.1), squeeze=False)
    valid = analysis.valid.reshape(nT, nV, nF)
    cmap = ListedColormap(STATUS_COLORS)
    for i, name in enumerate(metrics):
        vals = np.asarray(analysis.metric(loop, name), float).reshape(nT, nV, nF)
        req = requirement_for(requirements, name)
        status = requirement_status(vals, *(req[1:] if req else (None, None))).astype(float)
        status[~valid] = np.nan
        w = analysis.worst(loop, name)
        du = metric_display(loop, name)
        for t in range(nT):
            ax = axes[i, t]
            ax.imshow(status[t], origin="lower", aspect="auto", cmap=cmap, vmin=-0.5, vmax=3.5,
                      interpolation="nearest")
            for a in range(nV):
                for b in range(nF):
                    if not valid[t, a, b]:
                        ax.add_patch(Rectangle((b - 0.5, a - 0.5), 1, 1, fill=False, hatch="///", color="0.7", lw=0))
                    elif np.isfinite(vals[t, a, b]):
                        v = du.to_display(vals[t, a, b])
                        text = f"{v:+.1f}" if name.startswith("gain_margin") else f"{v:.3g}"
                        ax.text(b, a, text, ha="center", va="center", fontsize=8.5)
            if w is not None and not w.uniform and w.index // (nV * nF) == t:
                a, b = divmod(w.index % (nV * nF), nF)
                ax.add_patch(Rectangle((b - 0.5, a - 0.5), 1, 1, fill=False, lw=2.4, color="k"))
            ax.set_xticks(range(nF), [f"{f * 1e-3:g}" for f in grid.load_forces], fontsize=8)
            ax.set_yticks(range(nV), [f"{v * 1e3:g}" for v in grid.nut_speeds], fontsize=8)
            if i == len(metrics) - 1:
                ax.set_xlabel(label("load", "force") + " (< 0 aids)", fontsize=9)
            if t == 0:
                limit = f"\nrequired {requirement_limit_text(loop, req[0], req[1])}" if req else "\n(no requirement)"
                ax.set_ylabel(f"{du.label(METRIC_LABELS[name])}{limit}\n\n" + label("speed", "nut_speed"),
                              fontsize=9)
            if i == 0:
                ax.set_title(f"{grid.temperatures[t]:g} {display_unit('temperature').unit}", fontsize=10)
    handles = [Patch(facecolor=c, edgecolor="0.5", label=lab) for c, lab in zip(STATUS_COLORS, STATUS_LABELS)]
    handles.append(Patch(facecolor="white", edgecolor="0.6", hatch="///", label="not analysed (see invalid points)"))
    handles.append(Patch(facecolor="white", edgecolor="k", lw=2, label="worst valid point"))
    fig.legend(handles=handles, loc="outside lower center", ncol=3, fontsize=9, frameon=False)
    note = "; gain margin signed (< 0: lower margin, conditionally stable), compared by magnitude" \
        if "gain_margin_db" in metrics else ""
    fig.suptitle(f"{_LOOP_TITLE[loop]} over the grid, coloured against the design's requirements{note}", fontsize=11)
    return fig


def plot_velocity_poles(analysis: LoopAnalysis, ax=None):
    """Closed-loop poles of the velocity loop over temperature: z-plane and continuous equivalent.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if ax is None:
        fig, ax = subplots(1, 2, figsize=(12, 5.2), constrained_layout=True)
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
    fig, axes = subplots(2, len(loads), figsize=(3.2 * len(loads) + 1, 6), sharex=True, squeeze=False,
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
    fig = new_figure(figsize=(13, 7.5), constrained_layout=True)
    gs = fig.add_gridspec(2, 2, height_ratios=(2.2, 1))
    cases = list(switching.cases)
    delays = sorted({c.delay_s for c in cases})
    cmap = colormap("viridis")
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
        if ax.get_legend_handles_labels()[0]:
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
