"""Summary of a ``thsa-rig-run/1`` run: what ``thsa check-data`` prints.

Duration, sample rate, channels and their ranges, gaps, the phases where the
load aids or opposes the motion (FORMAT.md: opposes when
``load_force * speed > 0``), motor-off phases and direction reversals.  Works
on a :class:`~thsa_control.data.rigdata.RigRun`; parses no file itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from thsa_control.data.rigdata import _SPECS, RigRun, _number, true_runs
from thsa_control.data.units import m_to_mm

__all__ = ["SummarySettings", "ChannelRange", "Gap", "Interval", "LoadPhase", "Reversal", "RunSummary",
           "summarize_run", "format_summary"]


# --------------------------------------------------------------------- summary
@dataclass(frozen=True)
class SummarySettings:
    """Dead bands of :func:`summarize_run`.

    Parameters
    ----------
    speed_deadband : float
        Speed command below which there is no motion [m/s], >= 0.
    force_deadband : float
        Load below which the load neither aids nor opposes [N], >= 0; the
        default is 4x the 50 N rms noise of the rig's force sensor.
    min_phase : float
        Shortest aiding/opposing phase reported [s], >= 0; shorter ones are
        sensor chatter at a boundary.
    """

    speed_deadband: float = 1e-4
    force_deadband: float = 200.0
    min_phase: float = 0.05

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first negative or non-finite field."""
        for name in ("speed_deadband", "force_deadband", "min_phase"):
            value = getattr(self, name)
            if _number(value) is None or value < 0:
                raise ValueError(f"SummarySettings.{name} must be a finite number >= 0, "
                                 f"got {value!r}")


@dataclass(frozen=True)
class ChannelRange:
    """Range of one channel in FORMAT units (``source``: csv, json, default, extra)."""

    column: str
    unit: str
    minimum: float
    maximum: float
    n_missing: int
    source: str


@dataclass(frozen=True)
class Gap:
    """Missing samples: first ``row`` (from 1), its time [s] and ``length`` [samples]."""

    column: str
    row: int
    time_s: float
    length: int


@dataclass(frozen=True)
class Interval:
    """A time interval [s], from the first sample to the end of the last one."""

    start_s: float
    end_s: float

    @property
    def duration_s(self) -> float:
        """Length [s]."""
        return self.end_s - self.start_s


@dataclass(frozen=True)
class LoadPhase:
    """A phase where the load aids or opposes the motion.

    Parameters
    ----------
    kind : str
        ``aiding`` (``load_force_N * speed < 0``) or ``opposing`` (``> 0``).
    direction : str
        ``extend`` (speed command > 0) or ``retract``.
    start_s, end_s : float
        Interval [s].
    mean_speed_cmd_mm_s : float
        Mean speed command [mm/s].
    mean_load_force_N : float
        Mean load [N], positive compressive.
    """

    kind: str
    direction: str
    start_s: float
    end_s: float
    mean_speed_cmd_mm_s: float
    mean_load_force_N: float

    @property
    def duration_s(self) -> float:
        """Length [s]."""
        return self.end_s - self.start_s


@dataclass(frozen=True)
class Reversal:
    """The speed command changes direction at ``time_s`` [s], data ``row``, to ``direction``."""

    time_s: float
    row: int
    direction: str


@dataclass(frozen=True)
class RunSummary:
    """What ``thsa check-data RUN.csv`` tells about a run.

    Parameters
    ----------
    name : str
    csv_path : str
    n_samples : int
    duration_s : float
        [s].
    nominal_sample_rate_hz : float or None
        JSON ``sample_rate_hz`` [Hz].
    dt_min_s, dt_median_s, dt_max_s : float
        Actual time steps [s].
    channels : tuple of ChannelRange
        Standard channels (FORMAT order) then numeric extras.
    extra_columns : tuple of str
    gaps : tuple of Gap
    load_phases : tuple of LoadPhase
    aiding_duration_s, opposing_duration_s : float
        Sums over ``load_phases`` [s].
    motor_off : tuple of Interval
        Speed command exactly 0 with ``motor_disabled_when_cmd_zero``, or both
        enable flags 0.
    motor_off_duration_s : float
        [s].
    reversals : tuple of Reversal
    warnings : tuple of str
        The run's warnings.
    settings : SummarySettings
    """

    name: str
    csv_path: str
    n_samples: int
    duration_s: float
    nominal_sample_rate_hz: float | None
    dt_min_s: float
    dt_median_s: float
    dt_max_s: float
    channels: tuple[ChannelRange, ...]
    extra_columns: tuple[str, ...]
    gaps: tuple[Gap, ...]
    load_phases: tuple[LoadPhase, ...]
    aiding_duration_s: float
    opposing_duration_s: float
    motor_off: tuple[Interval, ...]
    motor_off_duration_s: float
    reversals: tuple[Reversal, ...]
    warnings: tuple[str, ...]
    settings: SummarySettings


def summarize_run(run: RigRun, settings: SummarySettings | None = None) -> RunSummary:
    """Summarise a run: timing, channel ranges, gaps, load phases, motor-off, reversals.

    Parameters
    ----------
    run : RigRun
    settings : SummarySettings, optional
        Dead bands; defaults 0.1 mm/s, 200 N, 0.05 s.

    Returns
    -------
    RunSummary

    Raises
    ------
    ValueError
        If ``settings`` is invalid.
    """
    settings = settings or SummarySettings()
    settings.validate()
    t = run.time
    dt = np.diff(t)
    ends = np.append(t[1:], t[-1] + np.median(dt))  # each sample holds until the next

    channels, gaps = [], []
    for spec in _SPECS:
        values = t if spec.role == "time" else run.signals.get(spec.signal)
        if values is None:
            continue
        src = "csv" if spec.role == "time" or spec.signal in run.source_columns else \
            ("json" if spec.signal == "temperature" else "default")
        channels.append(_channel(spec.column, spec.unit, spec.from_si(values), src))
        gaps += _gaps(run.source_columns.get(spec.signal, spec.column), values, t)
    for name, values in run.extra.items():
        if values.dtype.kind == "f":
            channels.append(_channel(name, "?", values, "extra"))
            gaps += _gaps(name, values, t)

    cmd, force = run.signals["speed_cmd"], run.signals["load_force"]
    direction = np.where(cmd > settings.speed_deadband, 1,
                         np.where(cmd < -settings.speed_deadband, -1, 0))
    loaded = np.abs(force) > settings.force_deadband
    kind = np.where(loaded & (direction != 0), np.sign(force) * direction, 0).astype(int)
    phases = []
    code = kind * 2 + (direction > 0)  # distinct per (kind, direction); 0/1 when kind == 0
    change = np.flatnonzero(np.diff(code)) + 1
    for start, stop in zip(np.r_[0, change], np.r_[change, t.size]):
        if kind[start] == 0 or ends[stop - 1] - t[start] < settings.min_phase:
            continue
        phases.append(LoadPhase("opposing" if kind[start] > 0 else "aiding",
                                "extend" if direction[start] > 0 else "retract",
                                float(t[start]), float(ends[stop - 1]),
                                float(m_to_mm(np.mean(cmd[start:stop]))),
                                float(np.mean(force[start:stop]))))
    off = (run.signals["primary_enable"] == 0) & (run.signals["standby_enable"] == 0)
    if run.motor_disabled_when_cmd_zero:
        off |= cmd == 0
    motor_off = tuple(Interval(float(t[a]), float(ends[b - 1])) for a, b in true_runs(off))
    moving = np.flatnonzero(direction)
    turns = moving[1:][direction[moving[1:]] != direction[moving[:-1]]]
    reversals = tuple(Reversal(float(t[i]), int(i) + 1, "extend" if direction[i] > 0
                               else "retract") for i in turns)
    nominal = _number(run.metadata.get("sample_rate_hz"))
    return RunSummary(
        name=run.name, csv_path=str(run.csv_path), n_samples=int(t.size),
        duration_s=run.duration_s, nominal_sample_rate_hz=nominal,
        dt_min_s=float(dt.min()), dt_median_s=float(np.median(dt)), dt_max_s=float(dt.max()),
        channels=tuple(channels), extra_columns=tuple(run.extra), gaps=tuple(gaps),
        load_phases=tuple(phases),
        aiding_duration_s=sum(p.duration_s for p in phases if p.kind == "aiding"),
        opposing_duration_s=sum(p.duration_s for p in phases if p.kind == "opposing"),
        motor_off=motor_off, motor_off_duration_s=sum(i.duration_s for i in motor_off),
        reversals=reversals, warnings=run.warnings, settings=settings)


def _channel(column: str, unit: str, values: np.ndarray, source: str) -> ChannelRange:
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (math.nan, math.nan)
    return ChannelRange(column, unit, lo, hi, int(np.isnan(values).sum()), source)


def _gaps(column: str, values: np.ndarray, t: np.ndarray) -> list[Gap]:
    return [Gap(column, a + 1, float(t[a]), b - a) for a, b in true_runs(np.isnan(values))]


def format_summary(summary: RunSummary) -> str:
    """Plain-text report of a :class:`RunSummary` (FORMAT units), for ``thsa check-data``.

    Parameters
    ----------
    summary : RunSummary

    Returns
    -------
    str
        Lines without a trailing newline.
    """
    s = summary
    rate = f"{s.nominal_sample_rate_hz:g} Hz nominal" if s.nominal_sample_rate_hz else \
        "no nominal rate in JSON"
    lines = [f"run '{s.name}' ({s.csv_path})",
             f"  {s.n_samples} samples over {s.duration_s:.6g} s; {rate}; "
             f"dt min {s.dt_min_s:.6g} s, median {s.dt_median_s:.6g} s, max {s.dt_max_s:.6g} s",
             "  channels (FORMAT units):"]
    width = max(len(c.column) for c in s.channels)
    for c in s.channels:
        span = f"{c.minimum:.6g}" if c.minimum == c.maximum else \
            f"{c.minimum:.6g} .. {c.maximum:.6g}"
        note = {"json": "  (from JSON, constant)", "default": "  (absent: default)",
                "extra": "  (extra column, kept)"}.get(c.source, "")
        missing = f"  [{c.n_missing} missing]" if c.n_missing else ""
        lines.append(f"    {c.column:<{width}}  {c.unit:<5} {span}{note}{missing}")
    numeric = {c.column for c in s.channels}
    text_extras = [e for e in s.extra_columns if e not in numeric]
    if text_extras:
        lines.append(f"  text extra columns (kept): {', '.join(text_extras)}")
    lines.append("  gaps: " + ("none" if not s.gaps else "; ".join(
        f"{g.column} row {g.row} (t = {g.time_s:.6g} s, {g.length} sample(s))" for g in s.gaps)))
    lines.append(f"  load vs motion (dead bands {m_to_mm(s.settings.speed_deadband):g} mm/s, "
                 f"{s.settings.force_deadband:g} N; opposes when load_force_N * speed > 0):")
    for p in s.load_phases:
        verb = "aids" if p.kind == "aiding" else "opposes"
        lines.append(f"    {p.start_s:.6g} .. {p.end_s:.6g} s ({p.duration_s:.6g} s): load "
                     f"{verb} the {p.mean_speed_cmd_mm_s:+.2g} mm/s motion ({p.direction}), "
                     f"mean load {p.mean_load_force_N:+.6g} N")
    if not s.load_phases:
        lines.append("    no loaded motion")
    lines.append(f"    total: load aids {s.aiding_duration_s:.6g} s, "
                 f"opposes {s.opposing_duration_s:.6g} s")
    lines.append("  motor off: " + ("none" if not s.motor_off else
                 "; ".join(f"{i.start_s:.6g} .. {i.end_s:.6g} s" for i in s.motor_off)
                 + f" (total {s.motor_off_duration_s:.6g} s)"))
    lines.append("  direction reversals: " + ("none" if not s.reversals else "; ".join(
        f"to {r.direction} at {r.time_s:.6g} s (row {r.row})" for r in s.reversals)))
    lines.append("  warnings: " + ("none" if not s.warnings else ""))
    lines += [f"    {w}" for w in s.warnings]
    return "\n".join(lines)
