"""Scalar metrics of simulated or measured runs (numbers only, no drawing).

The phases of a run are found from its signals: a *plateau* is where the
shaped speed command is constant and non-zero, a *trim stop* where it is
exactly zero; the load *opposes* the motion when ``load_force * speed > 0``
and *aids* it when ``< 0`` (FORMAT.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..data.rigdata import true_runs  # maximal runs of True, (start, stop exclusive)

__all__ = ["Interval", "plateaus", "stops", "backdrive_metrics", "surface_speed_deviation", "BackdriveMetrics",
           "energy_residual"]


@dataclass(frozen=True)
class Interval:
    """A time interval [s] and its command level [m/s] and mean load [N]."""

    start: float
    end: float
    command: float
    load: float

    @property
    def quadrant(self) -> str:
        """``"opposing"``, ``"aiding"`` or ``"unloaded"``."""
        if abs(self.load) < 1.0 or self.command == 0:
            return "unloaded"
        return "opposing" if self.load * self.command > 0 else "aiding"


def plateaus(time, speed_cmd, load_force, *, min_duration: float = 0.2) -> list[Interval]:
    """Intervals of constant, non-zero speed command (at least ``min_duration`` [s])."""
    t, v, f = map(np.asarray, (time, speed_cmd, load_force))
    dv = np.abs(np.gradient(v, t))
    mask = (np.abs(v) > 0) & (dv < 1e-6)
    out = []
    for i, j in true_runs(mask):
        if t[j - 1] - t[i] >= min_duration:
            out.append(Interval(float(t[i]), float(t[j - 1]), float(np.median(v[i:j])), float(np.mean(f[i:j]))))
    return out


def stops(time, speed_cmd, load_force, *, min_duration: float = 0.05) -> list[Interval]:
    """Intervals where the speed command is exactly zero (trim stops)."""
    t, v, f = map(np.asarray, (time, speed_cmd, load_force))
    out = []
    for i, j in true_runs(v == 0):
        if t[j - 1] - t[i] >= min_duration:
            out.append(Interval(float(t[i]), float(t[j - 1]), 0.0, float(np.mean(f[i:j]))))
    return out


@dataclass(frozen=True)
class BackdriveMetrics:
    """Current and back-drive figures of a run with aiding and opposing plateaus.

    Currents [A], speeds [m/s], ratios [-].  ``aiding_drive_fraction`` is the
    fraction of the aiding plateau where current and speed have the same sign
    (the motor drives against the no-back); ``breakaway_peak`` the largest
    current magnitude in the first ``0.6 s`` after the aiding motion starts;
    ``stop_backdrive_peak`` the largest nut speed magnitude in each trim stop.
    """

    opposing_mean_current: float
    aiding_mean_current: float
    aiding_drive_fraction: float
    breakaway_peak: float
    command_amplitude: float
    stop_backdrive_peak: tuple[float, ...]

    @property
    def aiding_to_opposing(self) -> float:
        """Mean |current| aiding / opposing."""
        return self.aiding_mean_current / self.opposing_mean_current

    @property
    def breakaway_to_opposing(self) -> float:
        """Breakaway peak / opposing mean |current|."""
        return self.breakaway_peak / self.opposing_mean_current


def backdrive_metrics(result, *, settle: float = 0.3) -> BackdriveMetrics:
    """Metrics of a run with one opposing and one aiding plateau (e.g. ``backdrive_bipolar_ramp``).

    ``settle`` [s] is skipped at the start of each plateau for the means.

    Raises
    ------
    ValueError
        The run has no opposing or no aiding plateau.
    """
    t = np.asarray(result.time)
    v, f, i = (np.asarray(result[n]) for n in ("speed_cmd", "load_force", "motor_current"))
    if "standby_current" in result.names:
        i = i + np.asarray(result["standby_current"])
    ps = plateaus(t, v, f)
    opp = [p for p in ps if p.quadrant == "opposing"]
    aid = [p for p in ps if p.quadrant == "aiding"]
    if not opp or not aid:
        raise ValueError(f"run {result.name!r} needs an opposing and an aiding plateau; found {[p.quadrant for p in ps]}")

    def window(p):
        return (t >= p.start + settle) & (t <= p.end)

    o, a = opp[0], aid[0]
    sign = np.sign(a.command)
    start_aid = t[np.flatnonzero((t < a.start) & (v == 0))[-1]] if np.any((t < a.start) & (v == 0)) else a.start - 0.6
    bw = (t > start_aid) & (t <= start_aid + 0.6)
    nut = np.asarray(result["nut_speed"])
    return BackdriveMetrics(
        opposing_mean_current=float(np.mean(np.abs(i[window(o)]))),
        aiding_mean_current=float(np.mean(np.abs(i[window(a)]))),
        aiding_drive_fraction=float(np.mean(np.sign(i[window(a)]) == sign)),
        breakaway_peak=float(np.max(np.abs(i[bw]))),
        command_amplitude=float(max(abs(p.command) for p in ps)),
        stop_backdrive_peak=tuple(float(np.max(np.abs(nut[(t >= s.start) & (t <= s.end)])))
                                  for s in stops(t, v, f)),
    )


def surface_speed_deviation(result, *, t0: float | None = None, t1: float | None = None) -> float:
    """Largest |surface speed - speed command| on constant-command plateaus, relative to the command [-]."""
    t = np.asarray(result.time)
    v, f, vs = (np.asarray(result[n]) for n in ("speed_cmd", "load_force", "surface_speed"))
    worst = 0.0
    for p in plateaus(t, v, f):
        m = (t >= max(p.start + 0.3, t0 if t0 is not None else -np.inf)) & (t <= min(p.end, t1 if t1 is not None else np.inf))
        if np.any(m):
            worst = max(worst, float(np.max(np.abs(vs[m] - p.command)) / abs(p.command)))
    return worst


def current_in_load_band(result, low: float, high: float, *, settle: float = 0.3) -> float:
    """Mean |motor current| [A] on constant-command plateaus (``settle`` [s] after each start) while the load force
    is within ``low .. high`` [N] (compressive positive); NaN where the run never is."""
    t = np.asarray(result.time)
    v, f, i = (np.asarray(result[n]) for n in ("speed_cmd", "load_force", "motor_current"))
    m = np.zeros(t.shape, bool)
    for p in plateaus(t, v, f):
        m |= (t >= p.start + settle) & (t <= p.end)
    m &= (f >= low) & (f <= high)
    return float(np.mean(np.abs(i[m]))) if np.any(m) else math.nan


def energy_residual(result) -> float:
    """Energy balance of a run: (electrical energy in - losses - work on the load - change of stored
    energy) / electrical energy throughput [-].  Needs every control period in the result
    (``output_period=None``); the first-order scheme closes it to O(h)."""
    h = result.info["output_period_s"]
    e_in = np.sum(result["electrical_power"]) * h
    lost = np.sum(result["loss_power"]) * h
    to_load = np.sum(result["load_power"]) * h
    stored = result["stored_energy"][-1] - result["stored_energy"][0]
    scale = np.sum(np.abs(result["electrical_power"])) * h
    return float((e_in - lost - to_load - stored) / max(scale, 1e-300))
