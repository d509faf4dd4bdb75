"""The ``thsa-rig-run/1`` format as data: columns, units, and the run records (for ``rigdata``).

Column specifications (FORMAT.md names, canonical signal names, units and
conversions to SI), the frozen records :class:`RigRun` and
:class:`RigController`, and small helpers shared by the reader, its checks and
the summary.  Imports numpy, the standard library and
:mod:`thsa_control.data.units` only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thsa_control.data.units import m_to_mm, mm_to_m, rad_s_to_rpm, rpm_to_rad_s

__all__ = ["FORMAT_TAG", "ColumnSpec", "COLUMNS", "VelocityLoopGains", "CurrentLoopGains", "RigController",
           "PositionLoopGains", "CurrentFeedForward",
           "RigRun", "DEFAULT_SCREW_LEAD_MM", "DEFAULT_GEAR_RATIO", "MAX_ROWS_LISTED", "motor_speed_from",
           "measured_motor_speed"]

FORMAT_TAG = "thsa-rig-run/1"
#: Seed kinematics of FORMAT.md, used when the JSON has no ``rig`` block.
DEFAULT_SCREW_LEAD_MM = 12.0
DEFAULT_GEAR_RATIO = 65.61
#: How many rows of one repeated problem are listed before they are counted.
MAX_ROWS_LISTED = 10
_MIN_ROWS = 2
_MIN_FIT_SAMPLES = 20
_MIN_R2 = 0.9
_MAX_TEMPERATURE_C = 150.0
_RAD_S_PER_RPM = float(rpm_to_rad_s(1.0))


def _identity(x):
    return np.asarray(x, dtype=float)


@dataclass(frozen=True)
class ColumnSpec:
    """One standard column of ``thsa-rig-run/1``.

    Parameters
    ----------
    column : str
        CSV column name of FORMAT.md.
    signal : str
        Canonical signal name in :attr:`RigRun.signals`.
    unit : str
        Unit in the CSV.
    si_unit : str
        Unit in :attr:`RigRun.signals`.
    role : str
        ``time``, ``required``, ``measured``, ``command`` or ``enable``.
    to_si, from_si : callable
        Conversions CSV unit <-> SI unit (from :mod:`thsa_control.data.units`).
    default : float or None
        Value of an absent enable flag.
    """

    column: str
    signal: str
    unit: str
    si_unit: str
    role: str
    to_si: Callable = _identity
    from_si: Callable = _identity
    default: float | None = None


_SPECS = (
    ColumnSpec("time_s", "time", "s", "s", "time"),
    ColumnSpec("speed_cmd_mm_s", "speed_cmd", "mm/s", "m/s", "required", mm_to_m, m_to_mm),
    ColumnSpec("load_force_N", "load_force", "N", "N", "required"),
    ColumnSpec("motor_speed_rpm", "motor_speed", "rpm", "rad/s", "measured",
               rpm_to_rad_s, rad_s_to_rpm),
    ColumnSpec("motor_current_A", "motor_current", "A", "A", "measured"),
    ColumnSpec("nut_position_mm", "nut_position", "mm", "m", "measured", mm_to_m, m_to_mm),
    ColumnSpec("screw_speed_rpm", "screw_speed", "rpm", "rad/s", "measured",
               rpm_to_rad_s, rad_s_to_rpm),
    ColumnSpec("temperature_C", "temperature", "degC", "degC", "measured"),
    ColumnSpec("position_cmd_mm", "position_cmd", "mm", "m", "command", mm_to_m, m_to_mm),
    ColumnSpec("primary_enable", "primary_enable", "0/1", "0/1", "enable", default=1.0),
    ColumnSpec("standby_enable", "standby_enable", "0/1", "0/1", "enable", default=0.0),
)
#: Standard columns by CSV name, in FORMAT.md order.
COLUMNS: dict[str, ColumnSpec] = {s.column: s for s in _SPECS}
_BY_SIGNAL = {s.signal: s for s in _SPECS}
_SPEED_COLUMNS = ("motor_speed_rpm", "screw_speed_rpm")


# --------------------------------------------------------------------- results
@dataclass(frozen=True)
class VelocityLoopGains:
    """Velocity PI of the rig (on motor speed, output current reference).

    Parameters
    ----------
    kp : float
        Proportional gain [A/(rad/s)], >= 0.
    ki : float
        Integral gain [A/rad], >= 0.
    current_limit : float
        Clamp of the current reference [A], > 0.
    extra : dict
        Unknown keys of the JSON block, kept.
    """

    kp: float
    ki: float
    current_limit: float
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class CurrentLoopGains:
    """Current PI of the rig (on quadrature current, output motor voltage).

    Parameters
    ----------
    kp : float
        Proportional gain [V/A], >= 0.
    ki : float
        Integral gain [V/(A s)], >= 0.
    voltage_limit : float
        Clamp of the voltage [V], > 0.
    extra : dict
        Unknown keys of the JSON block, kept.
    """

    kp: float
    ki: float
    voltage_limit: float
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class PositionLoopGains:
    """Position P loop of the rig around its velocity loop (JSON ``controller.position_loop``, an extension).

    The target nut speed is ``kp (position_cmd - nut_position)``, capped at
    ``max_speed`` and by the speed from which ``accel_limit`` brakes to rest
    within the error, then rate limited to ``accel_limit`` and acceleration
    limited to ``jerk_limit`` (the cascade of
    :mod:`thsa_control.loops.controllers`).  The command is the CSV's
    ``position_cmd_mm`` column.

    Parameters
    ----------
    kp : float
        Proportional gain [1/s], > 0 (``kp_1_per_s``).
    max_speed : float
        Speed cap [m/s], > 0 (``max_speed_mm_s``; default unlimited).
    accel_limit : float
        Rate limit of the speed target [m/s^2], > 0 (``accel_limit_mm_s2``; default unlimited).
    jerk_limit : float
        Its acceleration limit [m/s^3], > 0 (``jerk_limit_mm_s3``; default unlimited).
    extra : dict
        Unknown keys of the block, kept.
    """

    kp: float
    max_speed: float = math.inf
    accel_limit: float = math.inf
    jerk_limit: float = math.inf
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class CurrentFeedForward:
    """Current added at the velocity loop's output (JSON ``controller.current_feedforward``, an extension).

    ``i_ref = PI(speed error) + offset + column(t)``, then clamped to the
    current limit: a feed-forward, or a disturbance injected at the
    controller output.

    Parameters
    ----------
    offset : float
        Constant current [A] (``offset_A``; default 0).
    column : str or None
        CSV column [A] added sample by sample (``column``; default none).
    extra : dict
        Unknown keys of the block, kept.
    """

    offset: float = 0.0
    column: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class RigController:
    """The rig's cascade as it ran (JSON ``controller`` block).

    Parameters
    ----------
    velocity_loop : VelocityLoopGains
    current_loop : CurrentLoopGains
    control_period : float
        Controller sample period [s], > 0.
    extra : dict
        Unknown keys of the block, kept.
    position_loop : PositionLoopGains or None
        The position P loop, when the run closed it (extension of FORMAT.md).
    current_feedforward : CurrentFeedForward or None
        Current added at the velocity loop's output (extension of FORMAT.md).
    """

    velocity_loop: VelocityLoopGains
    current_loop: CurrentLoopGains
    control_period: float
    extra: dict[str, Any] = field(default_factory=dict)
    position_loop: PositionLoopGains | None = None
    current_feedforward: CurrentFeedForward | None = None


@dataclass(frozen=True, eq=False)
class RigRun:
    """One validated rig run, in SI.

    Parameters
    ----------
    name : str
        JSON ``name``, else the file stem.
    csv_path, json_path : Path
        The two files read.
    metadata : dict
        The whole JSON object, unknown keys included.
    time : ndarray
        Sample times [s], strictly increasing.
    signals : dict of str to ndarray
        Canonical signals: ``speed_cmd`` [m/s], ``load_force`` [N, > 0
        compressive], ``motor_speed`` [rad/s], ``motor_current`` [A],
        ``nut_position`` [m], ``screw_speed`` [rad/s], ``temperature`` [degC,
        the one non-SI signal; constant from the JSON when the CSV has no
        column], ``position_cmd`` [m], ``primary_enable`` and
        ``standby_enable`` [0/1, default 1 and 0 when absent].  Speeds and
        positions are positive when the actuator extends.  An isolated missing
        sample of a measured signal is NaN (see :attr:`warnings`).
    extra : dict of str to ndarray
        Unknown CSV columns by their CSV names, raw.
    controller : RigController or None
        The JSON ``controller`` block, or None when absent.
    motor_disabled_when_cmd_zero : bool
        Motors de-energised while the speed command is exactly 0.
    warnings : tuple of str
        Non-fatal findings (isolated gaps, undecided unit checks).
    screw_lead : float
        Screw lead [m] used for the kinematic checks.
    gear_ratio : float
        Motor-to-screw gear ratio [-].
    kinematics_stated : tuple of str
        Which of ``screw_lead_mm``, ``gear_ratio`` the JSON's ``rig`` block
        states; the others are FORMAT.md's seed values, to be replaced by the
        parameter set's (:func:`thsa_control.fit.kinematics.run_kinematics`).
    source_columns : dict of str to str
        Canonical signal -> CSV column it was read from (original name).

    Notes
    -----
    Arrays are read-only.  Instances compare by identity.
    """

    name: str
    csv_path: Path
    json_path: Path
    metadata: dict[str, Any]
    time: np.ndarray
    signals: dict[str, np.ndarray]
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    controller: RigController | None = None
    motor_disabled_when_cmd_zero: bool = False
    warnings: tuple[str, ...] = ()
    screw_lead: float = mm_to_m(DEFAULT_SCREW_LEAD_MM)
    gear_ratio: float = DEFAULT_GEAR_RATIO
    source_columns: dict[str, str] = field(default_factory=dict)
    kinematics_stated: tuple[str, ...] = ()

    @property
    def sample_rate_hz(self) -> float:
        """Nominal sample rate [Hz]: JSON ``sample_rate_hz``, else 1 / median dt."""
        nominal = _number(self.metadata.get("sample_rate_hz"))
        if nominal is not None and nominal > 0:
            return nominal
        return 1.0 / float(np.median(np.diff(self.time)))

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample [s]."""
        return float(self.time[-1] - self.time[0])

    def has(self, name: str) -> bool:
        """True when ``name`` is a signal (defaults included) or an extra column."""
        return name in self.signals or name in self.extra

    def measured_motor_speed(self) -> np.ndarray | None:
        """:func:`measured_motor_speed` of this run."""
        return measured_motor_speed(self)


def measured_motor_speed(run) -> np.ndarray | None:
    """Motor speed [rad/s] per sample of a run as measured: the motor speed sensor, else gear ratio x
    the screw speed (RVDT), else None (missing samples stay NaN)."""
    return motor_speed_from(
        lambda c: np.asarray(run.signals[c], float) if c in run.source_columns else None, run.gear_ratio)


def stop_band(speed) -> float:
    """The speed under which the drive counts as stopped (the tracer's starts, stops and reversals, a run's moving
    samples): 5 % of the record's largest speed (of at least 1e-9)."""
    return 0.05 * max(float(np.max(np.abs(speed))), 1e-9)


def motion_sign(speed, band: float | None = None) -> np.ndarray:
    """Per sample, the direction of motion: +1 / -1 beyond ``band`` [the speed's unit] (default the
    :func:`stop_band`), 0 inside it (stopped)."""
    dv = stop_band(speed) if band is None else band
    return np.where(speed > dv, 1, np.where(speed < -dv, -1, 0))


def drive_on(run) -> np.ndarray:
    """Per sample of a run, whether the drive is energised: either motor enabled (``primary_enable``,
    ``standby_enable``) and, on a rig whose motors are de-energised while the speed command is exactly 0
    (``motor_disabled_when_cmd_zero``), the command not 0.  The one rule, for every tool that asks."""
    on = (np.asarray(run.signals["primary_enable"]) > 0.5) | (np.asarray(run.signals["standby_enable"]) > 0.5)
    if run.motor_disabled_when_cmd_zero:
        on &= np.asarray(run.signals["speed_cmd"]) != 0
    return on


def speed_integral(time, speed) -> np.ndarray:
    """The angle [rad] (or travel) a speed covers from the first sample: the trapezoid rule over the samples, 0 at
    the first one.  The one integration of a measured speed, for every tool that needs a motor angle or a travel."""
    t, w = np.asarray(time, dtype=float), np.asarray(speed, dtype=float)
    return np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])


def motor_speed_from(get: Callable[[str], Any], gear_ratio: float):
    """A motor speed as measured: ``get("motor_speed")``, else ``gear_ratio * get("screw_speed")``, else None.

    ``get(channel)`` returns the channel's measurement (an array, or one
    sample) or None where the channel is not measured: a run's columns, a
    dict of measured signals (``dict.get``), a sample near a time.  The one
    rule of a run's motor speed, for every tool that reads one.
    """
    w = get("motor_speed")
    if w is not None:
        return w
    ws = get("screw_speed")
    return None if ws is None else ws * gear_ratio


# --------------------------------------------------------------------- helpers
def _number(value: Any) -> float | None:
    """A finite JSON number as float, else None (booleans are not numbers)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True as (start, stop) with stop exclusive."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def _add_rows(problems: list, label: str, rows: np.ndarray, message: Callable[[int], str]) -> None:
    """One problem per 0-based row index, the first MAX_ROWS_LISTED listed."""
    rows = np.asarray(rows, dtype=int)
    for i in rows[:MAX_ROWS_LISTED]:
        problems.append((label, int(i) + 1, message(int(i))))
    if rows.size > MAX_ROWS_LISTED:
        rest = rows[MAX_ROWS_LISTED:]
        problems.append((label, int(rest[0]) + 1,
                         f"... and {rest.size} more row(s) with the same problem "
                         f"(rows {rest[0] + 1} to {rest[-1] + 1})"))


# --------------------------------------------------------------------- speed sensors as difference quotients
#: Channels whose sensor may be a difference quotient of an angle (JSON column name -> canonical signal).
SPEED_SENSOR_COLUMNS = {"motor_speed_rpm": "motor_speed", "screw_speed_rpm": "screw_speed"}

_SAMPLE_WORDS = ("sample", "samples")


def speed_interval_from(value: Any, where: str) -> float | str | None:
    """A declared difference interval: seconds (> 0), ``"sample"`` (one logged sample), or None (instantaneous)."""
    if value is None or value == "instantaneous":
        return None
    if isinstance(value, str) and value.strip().lower() in _SAMPLE_WORDS:
        return "sample"
    v = _number(value)
    if v is None or not (v > 0 and math.isfinite(v)):
        raise ValueError(f"{where} = {value!r}: give a difference interval in seconds (> 0), \"sample\" or "
                         "\"instantaneous\"")
    return float(v)


def _interval_from_text(text: str) -> float | str | None:
    """The fallback: a difference interval read from a free-text sensor description (rig-sim writes "speed =
    angle difference over 1 ms", "RVDT angle differentiated over one sample"); None when the text says none."""
    import re

    t = text.lower()
    if not re.search(r"differen(ce|tiated)", t):
        return None
    if re.search(r"over (one|1|a) (logged )?sample", t):
        return "sample"
    m = re.search(r"over ([0-9]*\.?[0-9]+) ?(ms|s)\b", t)
    if m:
        return float(m.group(1)) * (1e-3 if m.group(2) == "ms" else 1.0)
    return None


def speed_sensor_intervals(run, override=None) -> dict[str, dict]:
    """How each speed sensor of ``run`` reads: ``{signal: {"interval": s | "sample" | None, "source": ...}}``.

    The reading of a difference-quotient sensor is the angle difference over the interval divided by it (a
    resolver's speed estimate over 1 ms, an RVDT angle differentiated over one logged sample), not the
    instantaneous speed.  Sources, in order: ``override`` (signal or column name -> interval: the caller's
    explicit option), the run JSON's structured ``speed_sensors`` object (column name -> interval in seconds,
    ``"sample"`` or ``"instantaneous"``; proposed extension of FORMAT.md, free metadata there), and as a
    fallback, reported as such, the free text of the JSON's ``sensors`` object.  Default: instantaneous.

    Raises
    ------
    ValueError
        A malformed interval (names the field and the value).
    """
    override = dict(override or {})
    declared = run.metadata.get("speed_sensors") if isinstance(run.metadata, dict) else None
    texts = run.metadata.get("sensors") if isinstance(run.metadata, dict) else None
    out = {}
    for col, sig in SPEED_SENSOR_COLUMNS.items():
        if sig not in run.source_columns:
            continue
        if sig in override or col in override:
            key = sig if sig in override else col
            out[sig] = {"interval": speed_interval_from(override[key], f"speed sensor option {key}"),
                        "source": "explicit option"}
        elif isinstance(declared, dict) and col in declared:
            out[sig] = {"interval": speed_interval_from(declared[col], f"{run.json_path}: speed_sensors.{col}"),
                        "source": "run JSON speed_sensors"}
        elif isinstance(texts, dict) and isinstance(texts.get(col), str) and _interval_from_text(texts[col]):
            out[sig] = {"interval": _interval_from_text(texts[col]),
                        "source": f"fallback: read from the run JSON's sensors text {texts[col]!r}"}
        else:
            out[sig] = {"interval": None, "source": "default: instantaneous"}
    return out


def speed_sensor_delays(run, override=None) -> dict[str, float]:
    """The delay [s] each speed sensor of ``run`` reads with (:func:`speed_sensor_intervals`): a difference quotient
    of an angle over ``T`` is the mean speed over the last ``T``, the instantaneous speed ``T / 2`` earlier (``"sample"``:
    one logged sample, the run's median sampling interval); 0 for an instantaneous sensor.  What two redundant
    sensors' relative lag is expected to be when both are healthy."""
    t = np.asarray(run.time, dtype=float)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    out = {}
    for sig, d in speed_sensor_intervals(run, override).items():
        iv = d["interval"]
        out[sig] = 0.0 if iv is None else 0.5 * (dt if iv == "sample" else float(iv))
    return out

