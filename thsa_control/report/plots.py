"""Figures of simulation results.  The only module of thsa-control that imports matplotlib.

Functions take results (data) and return a ``Figure``; they never compute
physics.  They use matplotlib's object API (:mod:`.figure`): no backend is chosen.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np  # noqa: E402

from ..data.rigformat import true_runs
from ..data.units import label, to_display
from .figure import subplots

__all__ = ["plot_run", "plot_levels", "close"]

_LEVEL_COLORS = {"A": "tab:gray", "B": "tab:blue", "C": "tab:orange", "D": "tab:green"}


def close(fig) -> None:
    """Release a figure's memory (figures live outside pyplot: drop the artists, nothing to unregister)."""
    fig.clear()


def _mark_stops(ax, result):
    t = np.asarray(result.time)
    off = np.asarray(result["energised_primary"]) + np.asarray(result["energised_standby"]) < 0.5
    for i, j in true_runs(off):
        ax.axvspan(t[i], t[j - 1], color="0.92", zorder=0, lw=0)


def plot_run(result, *, title: str | None = None, axes=None):
    """Four panels of one run: speeds, currents, forces, no-back (``axes``: four Axes, default a new figure).

    Grey bands mark the motors de-energised (trim stops, faults).
    """
    t = np.asarray(result.time)
    if axes is None:
        fig, axes = subplots(4, 1, figsize=(10, 10), sharex=True, constrained_layout=True)
    else:
        axes = list(np.ravel(axes))
        fig = axes[0].figure
    ax = axes[0]
    ax.plot(t, to_display("nut_speed", result["speed_cmd"]), "k--", lw=1, label="command")
    ax.plot(t, to_display("nut_speed", result["nut_speed"]), label="nut")
    if "loadpath_compliance" in result.effects:
        ax.plot(t, to_display("nut_speed", result["surface_speed"]), lw=0.8, label="surface")
    ax.set_ylabel(label("speed", "nut_speed"))
    ax = axes[1]
    ax.plot(t, result["motor_current"], label="primary")
    if "standby_motor" in result.effects:
        ax.plot(t, result["standby_current"], label="standby")
    ax.plot(t, result["current_ref"], "k:", lw=0.8, label="reference")
    ax.set_ylabel(label("q current", "current"))
    ax = axes[2]
    ax.plot(t, to_display("force", result["load_force"]), "k--", lw=1, label="load (+ compressive)")
    if "loadpath_compliance" in result.effects:
        ax.plot(t, to_display("force", result["loadpath_force"]), label="load path")
    ax.set_ylabel(label("force", "force"))
    ax = axes[3]
    ax.plot(t, result["noback_torque"], label="no-back torque at screw")
    ax.set_ylabel(label("no-back", "torque"))
    ax2 = ax.twinx()
    ax2.plot(t, result["pawl_engaged"], color="tab:red", lw=0.8, label="pawl engaged (loaded side)")
    ax2.set_ylim(-0.1, 1.1)
    ax2.set_ylabel("pawl engaged [-]")
    ax.set_xlabel(label("time", "duration"))
    for a in axes:
        _mark_stops(a, result)
        a.grid(True, alpha=0.3)
        a.legend(loc="upper right", fontsize=8)
    ax2.legend(loc="lower right", fontsize=8)
    fig.suptitle(title or f"{result.name}: effects {', '.join(result.effects) or '(level A)'}")
    return fig


def plot_levels(results: Mapping[str, object], *, title: str | None = None):
    """Levels side by side (one column each): speed, current, no-back torque.

    ``results`` maps a label (``"A"`` ...) to a result of the same scenario.
    Each panel has its own scale, so a level that runs away (level A has no
    no-back) does not flatten the others.
    """
    labels = list(results)
    fig, axes = subplots(3, len(labels), figsize=(4.2 * len(labels), 8), sharex=True, squeeze=False,
                             constrained_layout=True)
    for col, name in enumerate(labels):
        r = results[name]
        t = np.asarray(r.time)
        color = _LEVEL_COLORS.get(name, None)
        a = axes[0, col]
        a.plot(t, to_display("nut_speed", r["speed_cmd"]), "k--", lw=0.8, label="command")
        a.plot(t, to_display("nut_speed", r["nut_speed"]), color=color, label="nut")
        if "loadpath_compliance" in r.effects:
            a.plot(t, to_display("nut_speed", r["surface_speed"]), color="tab:purple", lw=0.7, label="surface")
        a.set_title(f"level {name}" if len(name) == 1 else name)
        a.set_ylabel(label("speed", "nut_speed") if col == 0 else "")
        a = axes[1, col]
        a.plot(t, r["motor_current"], color=color)
        a.set_ylabel(label("q current", "current") if col == 0 else "")
        a = axes[2, col]
        a.plot(t, r["noback_torque"], color=color)
        a.set_ylabel(label("no-back torque", "torque") if col == 0 else "")
        a.set_xlabel(label("time", "duration"))
        for row in range(3):
            _mark_stops(axes[row, col], r)
            axes[row, col].grid(True, alpha=0.3)
        axes[0, col].legend(fontsize=7, loc="lower left")
    fig.suptitle(title or f"{results[labels[0]].name}: model levels side by side (grey: motors de-energised)")
    return fig
