"""Reader and writer of ``thsa-rig-run/1`` test-rig runs (the summary is in ``rigsummary``).

This is the only module of thsa-control that parses rig-run files (component-rig
tables are read by ``component_id``).  It owns the
format of ``shared/rig-data/FORMAT.md``: a run is ``NAME.csv`` (samples, in
FORMAT units: mm, mm/s, rpm, N, A, degC) plus ``NAME.json`` (metadata).
Everything downstream receives a :class:`RigRun` whose signals are SI (the one
exception is ``temperature``, kept in degC as everywhere in the project).  It
imports numpy, the standard library, :mod:`thsa_control.errors` and
:mod:`thsa_control.data.units` only; never matplotlib.

Validation rules (decisions taken where FORMAT.md leaves room)
-----------------------------------------------------------------
* :func:`read_run` checks everything, collects every violation into one
  :class:`~thsa_control.errors.RigDataError` and returns nothing partial.
  Rows count data rows from 1 (the header is row 0).  A problem repeated on
  many rows is listed for the first ``MAX_ROWS_LISTED`` rows, then counted in
  one more line.  ``RigDataError.file`` is the CSV path when any problem is in
  the CSV, else the JSON path; problems of the JSON name their key as
  ``NAME.json:key.subkey`` in the column slot.
* Required columns: ``time_s``, ``speed_cmd_mm_s``, ``load_force_N`` and at
  least one speed measurement, ``motor_speed_rpm`` or ``screw_speed_rpm``
  (FORMAT.md's "at least one").
* JSON: ``format`` is required and must be ``thsa-rig-run/1``;
  ``temperature_C`` is required unless the CSV has that column;
  ``sample_rate_hz`` is optional (sampling may be non-uniform), positive if
  given; ``controller`` is optional (an open-loop run is plausible) but, when
  present, must hold all seven numbers, gains >= 0, limits and period > 0;
  ``motor_disabled_when_cmd_zero`` is optional (default false) and must be a
  JSON boolean; ``rig.screw_lead_mm`` / ``rig.gear_ratio`` are optional
  positive numbers (defaults 12 mm and 65.61).  Other keys are kept.
* Empty cells: in ``time_s``, ``speed_cmd_mm_s``, ``load_force_N``,
  ``position_cmd_mm`` and the enable flags any empty cell is an error.  In a
  measured column (motor speed and current, nut position, screw speed,
  temperature) one isolated empty cell is a warning and stays NaN (never
  interpolated); two or more consecutive empty cells are an error.  Literal
  ``nan``/``inf`` cells are errors everywhere (missing values are empty cells).
* Unknown extra columns are kept, unvalidated (FORMAT.md: "kept and ignored"),
  as float arrays (NaN for empty cells) or, if any cell is not a number, as
  string arrays.

Unit heuristics (each is skipped, never guessed, when it cannot decide)
-------------------------------------------------------------------------
* Speeds: during motion (``|speed_cmd| >= 25 %`` of its maximum, a channel
  enabled, at least 20 samples) the measured ``motor_speed_rpm`` is fitted as
  ``k * speed_cmd_mm_s * 60 N / p`` (328.05 with the seed kinematics), and
  ``screw_speed_rpm`` as ``k * speed_cmd_mm_s * 60 / p``.  Only a fit that
  explains at least 90 % of the signal decides: ``k`` within 25 % of
  ``1/9.549`` is rad/s (error); near 1 is fine; near 1000 points at a speed
  command in m/s; near -1 (sign) or anything else is a warning.  A stalled or
  lagging actuator gives a poor fit and no verdict.
* ``nut_position_mm``: fitted (with offset) against the time integral of
  ``speed_cmd_mm_s``; with a fit explaining 90 %, a slope within 30 % of 1/1000
  is metres (error), near 1000 points at a speed command in m/s, other slopes
  warn.  No motion, a blocked nut or backdrive without command: no verdict.
* ``speed_cmd_mm_s`` in m/s: an error only when a speed or position check says
  "x1000" and none says "consistent".
* ``temperature_C``: any value above 150 degC (CSV cell or JSON) is taken as
  kelvin (error); below -273.15 is impossible (error).
* ``time_s`` in ms: only with a JSON ``sample_rate_hz``; median dt within 20 %
  of ``1000 / sample_rate_hz`` is an error; any other disagreement by more
  than a factor 2 is a warning (sampling may be non-uniform).
* ``load_force_N`` in kN is **not** checked: an unloaded run legitimately reads
  tens of newtons, and the format carries no torque constant that would let
  the motor current predict the load.  No heuristic here is robust enough.

Examples
--------
>>> import tempfile, numpy as np
>>> t = np.arange(0.0, 1.0, 1e-3)
>>> v = np.where(t > 0.2, 2.0, 0.0)                        # [mm/s]
>>> cols = {"time_s": t, "speed_cmd_mm_s": v, "load_force_N": -5000.0 + 0 * t,
...         "motor_speed_rpm": 328.05 * v}
>>> with tempfile.TemporaryDirectory() as d:
...     csv_path, json_path = write_run(f"{d}/ramp", cols, {"temperature_C": 20.0})
...     run = read_run(csv_path)
>>> run.name, round(run.duration_s, 3), run.has("nut_position")
('ramp', 0.999, False)
>>> from thsa_control.data.rigsummary import summarize_run
>>> [(p.kind, p.direction) for p in summarize_run(run).load_phases]
[('aiding', 'extend')]
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thsa_control.errors import RigDataError
from thsa_control.data.units import m_to_mm, mm_to_m, rad_s_to_rpm, rpm_to_rad_s

__all__ = [
    "FORMAT_TAG",
    "ColumnSpec",
    "COLUMNS",
    "VelocityLoopGains",
    "CurrentLoopGains",
    "RigController",
    "RigRun",
    "read_run",
    "write_run",
    "to_columns",
]

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
    """

    velocity_loop: VelocityLoopGains
    current_loop: CurrentLoopGains
    control_period: float
    extra: dict[str, Any] = field(default_factory=dict)


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


# --------------------------------------------------------------------- helpers
def _number(value: Any) -> float | None:
    """A finite JSON number as float, else None (booleans are not numbers)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
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


def _parse_cells(cells: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Strings -> (values, stripped strings, empty mask, not-a-number mask)."""
    text = np.char.strip(np.asarray(cells, dtype=str))
    empty = text == ""
    invalid = np.zeros(text.shape, dtype=bool)
    values = np.full(text.shape, np.nan)
    filled = ~empty
    try:
        values[filled] = text[filled].astype(np.float64)
    except ValueError:
        for i in np.flatnonzero(filled):
            try:
                values[i] = float(text[i])
            except ValueError:
                invalid[i] = True
    invalid |= filled & (np.char.find(text, "_") >= 0)  # float() accepts 1_000; we do not
    values[invalid] = np.nan
    return values, text, empty, invalid


def _fit_scale(measured: np.ndarray, expected: np.ndarray) -> tuple[float, float]:
    """Least-squares ``measured ~ k expected`` through 0: (k, explained fraction)."""
    sxx = float(expected @ expected)
    syy = float(measured @ measured)
    if sxx <= 0.0 or syy <= 0.0:
        return math.nan, 0.0
    k = float(measured @ expected) / sxx
    resid = measured - k * expected
    return k, 1.0 - float(resid @ resid) / syy


def _verdict(k: float, r2: float, tol: float) -> str:
    """Classify a kinematic ratio: ok, rad_s, metre, x1000, sign, other, undecided."""
    if not math.isfinite(k) or r2 < _MIN_R2:
        return "undecided"
    for name, target in (("ok", 1.0), ("x1000", 1000.0), ("sign", -1.0),
                         ("rad_s", _RAD_S_PER_RPM), ("metre", 1e-3)):
        if abs(k / target - 1.0) <= tol:
            return name
    return "other"


# ------------------------------------------------------------------------ JSON
def _load_json(path: Path, problems: list) -> dict | None:
    where = path.name
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        problems.append((where, None, f"JSON file not found: {path}"))
        return None
    except (OSError, UnicodeDecodeError) as exc:
        problems.append((where, None, f"cannot read JSON file: {exc}"))
        return None
    try:
        meta = json.loads(text, parse_constant=_reject_constant)
    except (json.JSONDecodeError, ValueError) as exc:
        problems.append((where, None, f"malformed JSON: {exc}"))
        return None
    if not isinstance(meta, dict):
        problems.append((where, None, f"top level must be an object, got {type(meta).__name__}"))
        return None
    return meta


def _reject_constant(name: str):
    raise ValueError(f"{name} is not valid JSON")


def _check_metadata(meta: dict, where: str, has_temperature_column: bool, problems: list):
    """Validate the JSON object; return (controller, motor_disabled, lead_mm, ratio)."""
    def bad(key: str, message: str) -> None:
        problems.append((f"{where}:{key}", None, message))

    fmt = meta.get("format")
    if "format" not in meta:
        bad("format", f"missing; must be '{FORMAT_TAG}'")
    elif fmt != FORMAT_TAG:
        bad("format", f"is {fmt!r}, expected '{FORMAT_TAG}'")
    if "name" in meta and not isinstance(meta["name"], str):
        bad("name", "must be a string")
    if "temperature_C" in meta:
        temp = _number(meta["temperature_C"])
        if temp is None:
            bad("temperature_C", f"must be a finite number [degC], got {meta['temperature_C']!r}")
        elif temp > _MAX_TEMPERATURE_C:
            bad("temperature_C", f"{temp:g} degC is above {_MAX_TEMPERATURE_C:g} degC: "
                                 "looks like kelvin")
        elif temp < -273.15:
            bad("temperature_C", f"{temp:g} degC is below absolute zero")
    elif not has_temperature_column:
        bad("temperature_C", "missing; required when the CSV has no temperature_C column")
    if "sample_rate_hz" in meta:
        rate = _number(meta["sample_rate_hz"])
        if rate is None or rate <= 0:
            bad("sample_rate_hz", f"must be a positive number [Hz], got {meta['sample_rate_hz']!r}")
    disabled = meta.get("motor_disabled_when_cmd_zero", False)
    if not isinstance(disabled, bool):
        bad("motor_disabled_when_cmd_zero", f"must be true or false, got {disabled!r}")
        disabled = False
    lead_mm, ratio = DEFAULT_SCREW_LEAD_MM, DEFAULT_GEAR_RATIO
    rig = meta.get("rig")
    if rig is not None and not isinstance(rig, dict):
        bad("rig", "must be an object")
    elif isinstance(rig, dict):
        for key in ("screw_lead_mm", "gear_ratio"):
            if key in rig:
                value = _number(rig[key])
                if value is None or value <= 0:
                    bad(f"rig.{key}", f"must be a positive number, got {rig[key]!r}")
                elif key == "screw_lead_mm":
                    lead_mm = value
                else:
                    ratio = value
    controller = _parse_controller(meta["controller"], bad) if "controller" in meta else None
    return controller, disabled, lead_mm, ratio


_LOOPS = {
    "velocity_loop": (VelocityLoopGains, (("kp_A_per_rad_s", "kp", False),
                                          ("ki_A_per_rad", "ki", False),
                                          ("current_limit_A", "current_limit", True))),
    "current_loop": (CurrentLoopGains, (("kp_V_per_A", "kp", False),
                                        ("ki_V_per_A_s", "ki", False),
                                        ("voltage_limit_V", "voltage_limit", True))),
}


def _parse_controller(block: Any, bad: Callable[[str, str], None]) -> RigController | None:
    if not isinstance(block, dict):
        bad("controller", "must be an object")
        return None
    loops, ok = {}, True
    for loop, (cls, keys) in _LOOPS.items():
        sub = block.get(loop)
        if not isinstance(sub, dict):
            bad(f"controller.{loop}", "missing or not an object")
            ok = False
            continue
        values = {}
        for key, attr, strictly_positive in keys:
            value = _number(sub.get(key))
            if key not in sub:
                bad(f"controller.{loop}.{key}", "missing")
            elif value is None:
                bad(f"controller.{loop}.{key}", f"must be a finite number, got {sub[key]!r}")
            elif value < 0 or (strictly_positive and value == 0):
                bad(f"controller.{loop}.{key}",
                    f"must be {'> 0' if strictly_positive else '>= 0'}, got {value:g}")
            else:
                values[attr] = value
                continue
            ok = False
        known = {k for k, _, _ in keys}
        loops[loop] = cls(**values, extra={k: v for k, v in sub.items() if k not in known}) \
            if len(values) == 3 else None
    period = _number(block.get("control_period_s"))
    if period is None or period <= 0:
        bad("controller.control_period_s",
            f"must be a positive number [s], got {block.get('control_period_s', 'nothing')!r}")
        ok = False
    if not ok:
        return None
    extra = {k: v for k, v in block.items()
             if k not in ("velocity_loop", "current_loop", "control_period_s")}
    return RigController(loops["velocity_loop"], loops["current_loop"], period, extra)


# ------------------------------------------------------------------------- CSV
def _load_csv(path: Path, problems: list) -> tuple[list[str], list[list[str]]] | None:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        problems.append((None, None, f"CSV file not found: {path}"))
        return None
    except (OSError, UnicodeDecodeError) as exc:
        problems.append((None, None, f"cannot read CSV file: {exc}"))
        return None
    try:
        rows = list(csv.reader(io.StringIO(text, newline="")))
    except csv.Error as exc:
        problems.append((None, None, f"not a readable CSV file: {exc}"))
        return None
    while rows and rows[-1] == []:  # trailing blank lines only
        rows.pop()
    if not rows:
        problems.append((None, 0, "empty file: no header line"))
        return None
    return [c.strip() for c in rows[0]], rows[1:]


def _map_header(header: list[str], column_map: Mapping[str, str], problems: list):
    """Canonical names and error labels of the CSV columns."""
    for original, target in column_map.items():
        if original not in header:
            problems.append((original, 0, f"column_map names a column the CSV does not have "
                                          f"(header: {', '.join(header)})"))
        if target not in COLUMNS:
            problems.append((original, 0, f"column_map maps to {target!r}, which is not a "
                                          f"{FORMAT_TAG} column"))
    names, labels = [], []
    for j, original in enumerate(header):
        canonical = column_map.get(original, original)
        names.append(canonical)
        labels.append(original if canonical == original else f"{original} (as {canonical})")
        if not original:
            problems.append((f"#{j + 1}", 0, "empty column name"))
    seen: dict[str, list[int]] = {}
    for j, name in enumerate(names):
        seen.setdefault(name, []).append(j)
    for name, where in seen.items():
        if len(where) > 1 and name:
            problems.append((name, 0, "duplicate column: " + ", ".join(
                f"'{labels[j]}' (position {j + 1})" for j in where)))
    return names, labels


def read_run(csv_path: str | os.PathLike, *, column_map: Mapping[str, str] | None = None,
             json_path: str | os.PathLike | None = None) -> RigRun:
    """Read and validate one ``thsa-rig-run/1`` run.

    Parameters
    ----------
    csv_path : str or path-like
        ``NAME.csv`` with FORMAT.md columns and units (mm, mm/s, rpm, N, A,
        degC; positive = extending, load positive = compressive).
    column_map : mapping of str to str, optional
        Original CSV column name -> FORMAT.md column name, for rigs that name
        their columns otherwise (``{"t": "time_s"}``).  Errors then name both.
    json_path : str or path-like, optional
        The metadata file; default ``NAME.json`` next to the CSV.

    Returns
    -------
    RigRun
        The run in SI (temperature in degC).

    Raises
    ------
    RigDataError
        With every violation found (file, column, row, message); nothing is
        returned partially.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> d = pathlib.Path(tmp.name)
    >>> _ = (d / "r.json").write_text('{"format": "thsa-rig-run/1", "temperature_C": 20}')
    >>> _ = (d / "r.csv").write_text("t,speed_cmd_mm_s,load_force_N,motor_speed_rpm\\n"
    ...                              "0,0,10,0\\n0.001,0,10,\\n0.002,0,12,1\\n")
    >>> run = read_run(d / "r.csv", column_map={"t": "time_s"})
    >>> run.warnings[0]
    "column 'motor_speed_rpm', row 2: single missing sample, kept as NaN (not interpolated)"
    >>> _ = (d / "r.csv").write_text("t,speed_cmd_mm_s,load_force_N\\n0,0,1\\n0,0,1\\n")
    >>> read_run(d / "r.csv", column_map={"t": "time_s"})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    thsa_control.errors.RigDataError: ...r.csv: 2 problem(s)
      column 'motor_speed_rpm', row 0: missing: one of motor_speed_rpm, screw_speed_rpm is required
      column 't (as time_s)', row 2: time_s does not strictly increase: 0 s after 0 s (row 1)
    >>> tmp.cleanup()
    """
    csv_path = Path(csv_path)
    json_path = Path(json_path) if json_path is not None else csv_path.with_suffix(".json")
    column_map = dict(column_map or {})
    csv_problems: list = []
    json_problems: list = []
    warnings: list[str] = []

    table = _load_csv(csv_path, csv_problems)
    meta = _load_json(json_path, json_problems)
    names: list[str] = []
    if table is not None:
        names, labels = _map_header(table[0], column_map, csv_problems)
    parsed = None
    if meta is not None:
        parsed = _check_metadata(meta, json_path.name, "temperature_C" in names, json_problems)
    lead_mm, ratio = (parsed[2], parsed[3]) if parsed else (DEFAULT_SCREW_LEAD_MM,
                                                            DEFAULT_GEAR_RATIO)
    columns: dict[str, np.ndarray] = {}
    extra: dict[str, np.ndarray] = {}
    source: dict[str, str] = {}
    if table is not None:
        columns, extra, source = _check_table(table, names, labels, meta, lead_mm, ratio,
                                              csv_problems, warnings)
    if csv_problems or json_problems:
        raise RigDataError(str(csv_path if csv_problems else json_path),
                           csv_problems + json_problems)

    controller, disabled = parsed[0], parsed[1]
    time = columns.pop("time_s")
    signals: dict[str, np.ndarray] = {}
    for spec in _SPECS[1:]:
        if spec.column in columns:
            signals[spec.signal] = np.asarray(spec.to_si(columns[spec.column]), dtype=float)
        elif spec.role == "enable":
            signals[spec.signal] = np.full(time.shape, spec.default)
        elif spec.column == "temperature_C":
            signals[spec.signal] = np.full(time.shape, float(meta["temperature_C"]))
    for array in (time, *signals.values(), *extra.values()):
        array.flags.writeable = False
    name = meta.get("name") if isinstance(meta.get("name"), str) else csv_path.stem
    return RigRun(name=name, csv_path=csv_path, json_path=json_path, metadata=meta, time=time,
                  signals=signals, extra=extra, controller=controller,
                  motor_disabled_when_cmd_zero=disabled, warnings=tuple(warnings),
                  screw_lead=float(mm_to_m(lead_mm)), gear_ratio=ratio, source_columns=source)


def _check_table(table, names, labels, meta, lead_mm, ratio, problems, warnings):
    """Parse and check every column; return (standard columns, extras, sources)."""
    header, rows = table
    width = len(header)
    if len(rows) < _MIN_ROWS:
        problems.append((None, None, f"{len(rows)} data row(s); at least {_MIN_ROWS} needed"))
    ragged = np.zeros(len(rows), dtype=bool)
    for i, row in enumerate(rows):
        if len(row) != width:
            ragged[i] = True
    _add_rows(problems, None, np.flatnonzero(ragged),
              lambda i: f"has {len(rows[i])} field(s), the header has {width}")
    if not ragged.any():
        cells = [list(c) for c in zip(*rows)] if rows else [[] for _ in header]
    else:
        cells = [[r[j] if j < len(r) else "" for r in rows] for j in range(width)]

    label_of = dict(zip(names, labels))
    for column in ("time_s", "speed_cmd_mm_s", "load_force_N"):
        if column not in names:
            problems.append((column, 0, "missing required column"))
    if not any(c in names for c in _SPEED_COLUMNS):
        problems.append((_SPEED_COLUMNS[0], 0,
                         f"missing: one of {', '.join(_SPEED_COLUMNS)} is required"))

    columns, extra, source, clean = {}, {}, {}, set()
    for j, name in enumerate(names):
        if names.count(name) > 1 or not name:
            continue
        values, text, empty, invalid = _parse_cells(cells[j])
        empty &= ~ragged
        invalid &= ~ragged  # a ragged row is reported once, not per cell
        if name not in COLUMNS:  # unknown column: kept, not validated
            if invalid.any():
                extra[header[j]] = text
            else:
                extra[header[j]] = values
            continue
        spec, label, before = COLUMNS[name], labels[j], len(problems)
        _add_rows(problems, label, np.flatnonzero(invalid),
                  lambda i: f"not a number: {str(text[i])!r}")
        nonfinite = ~empty & ~invalid & ~ragged & ~np.isfinite(values)
        _add_rows(problems, label, np.flatnonzero(nonfinite),
                  lambda i: f"{str(text[i])!r} is not allowed (a missing value is an empty cell)")
        _check_gaps(spec, label, empty, problems, warnings)
        finite = np.isfinite(values)
        if spec.role == "time":
            idx = np.flatnonzero(finite)
            back = np.flatnonzero(np.diff(values[idx]) <= 0)
            _add_rows(problems, label, idx[back + 1],
                      lambda i: f"time_s does not strictly increase: {values[i]:.9g} s after "
                                f"{values[idx[np.searchsorted(idx, i) - 1]]:.9g} s "
                                f"(row {idx[np.searchsorted(idx, i) - 1] + 1})")
        elif spec.role == "enable":
            _add_rows(problems, label, np.flatnonzero(finite & (values != 0) & (values != 1)),
                      lambda i: f"enable flag must be 0 or 1, got {text[i]}")
        elif name == "temperature_C":
            hot = np.flatnonzero(finite & (values > _MAX_TEMPERATURE_C))
            if hot.size and hot.size == finite.sum():
                problems.append((label, int(hot[0]) + 1,
                                 f"every value is above {_MAX_TEMPERATURE_C:g} degC (range "
                                 f"{values[hot].min():g} to {values[hot].max():g}): "
                                 "looks like kelvin"))
            else:
                _add_rows(problems, label, hot,
                          lambda i: f"{values[i]:g} degC is above {_MAX_TEMPERATURE_C:g} degC: "
                                    "kelvin?")
            _add_rows(problems, label, np.flatnonzero(finite & (values < -273.15)),
                      lambda i: f"{values[i]:g} degC is below absolute zero")
        columns[name] = values
        source[spec.signal] = header[j]
        if len(problems) == before:
            clean.add(name)
    if not ragged.any() and len(rows) >= _MIN_ROWS:
        _check_units(columns, clean, label_of, meta, lead_mm, ratio, problems, warnings)
    return columns, extra, source


def _check_gaps(spec: ColumnSpec, label: str, empty: np.ndarray, problems: list,
                warnings: list) -> None:
    singles, listed = [], []
    for start, stop in _runs(empty):
        if stop - start == 1 and spec.role == "measured":
            singles.append(start)
        elif stop - start == 1:
            listed.append((start, "missing value (empty cell)"))
        else:
            listed.append((start, f"gap of {stop - start} samples (rows {start + 1} to {stop}); "
                                  "at most one isolated missing sample is tolerated, and only "
                                  "in a measured column"))
    messages = dict(listed)
    _add_rows(problems, label, np.array([s for s, _ in listed], dtype=int), messages.__getitem__)
    for start in singles[:MAX_ROWS_LISTED]:
        warnings.append(f"column '{label}', row {start + 1}: single missing sample, "
                        "kept as NaN (not interpolated)")
    if len(singles) > MAX_ROWS_LISTED:
        warnings.append(f"column '{label}': {len(singles) - MAX_ROWS_LISTED} more single "
                        "missing samples, kept as NaN")


def _check_units(columns, clean, label_of, meta, lead_mm, ratio, problems, warnings):
    """Kinematic and range heuristics of the module docstring.

    Speed checks need a clean speed command and column only; the time-base and
    position checks also need a clean ``time_s``.
    """
    time_ok = "time_s" in clean
    t = columns.get("time_s")
    dt = np.diff(t) if time_ok else None
    nominal = _number(meta.get("sample_rate_hz")) if meta else None
    if nominal and time_ok:
        r = float(np.median(dt)) * nominal
        if abs(r / 1000.0 - 1.0) <= 0.2:
            problems.append((label_of["time_s"], 2,
                             f"median time step {np.median(dt):.6g} is ~1000x 1/sample_rate_hz "
                             f"({1.0 / nominal:.6g} s): time_s looks like milliseconds"))
            return  # the kinematic checks below integrate over time
        elif not 0.5 <= r <= 2.0:
            warnings.append(f"column '{label_of['time_s']}': median time step "
                            f"{np.median(dt):.6g} s disagrees with sample_rate_hz {nominal:g}")
    if "speed_cmd_mm_s" not in clean:
        return
    cmd = columns["speed_cmd_mm_s"]
    enabled = np.ones(cmd.shape, dtype=bool)
    if "primary_enable" in columns or "standby_enable" in columns:
        enabled = (columns.get("primary_enable", np.ones(cmd.shape)) == 1) | \
                  (columns.get("standby_enable", np.zeros(cmd.shape)) == 1)
    peak = float(np.max(np.abs(cmd)))
    verdicts: dict[str, tuple[str, float, np.ndarray]] = {}
    screw_rpm_per_mm_s = 60.0 / lead_mm
    for column, gain in (("motor_speed_rpm", screw_rpm_per_mm_s * ratio),
                         ("screw_speed_rpm", screw_rpm_per_mm_s)):
        if column not in clean or peak <= 0:
            continue
        meas = columns[column]
        moving = (np.abs(cmd) >= 0.25 * peak) & enabled & np.isfinite(meas)
        if moving.sum() >= _MIN_FIT_SAMPLES:
            k, r2 = _fit_scale(meas[moving], gain * cmd[moving])
            verdicts[column] = (_verdict(k, r2, 0.25), k, np.flatnonzero(moving))
    if "nut_position_mm" in clean and time_ok and t.size >= _MIN_FIT_SAMPLES:
        pos = columns["nut_position_mm"]
        ok = np.isfinite(pos)
        travel = np.concatenate(([0.0], np.cumsum(0.5 * (cmd[1:] + cmd[:-1]) * dt)))
        x, y = travel[ok] - travel[ok].mean(), pos[ok] - pos[ok].mean()
        k, r2 = _fit_scale(y, x)
        verdicts["nut_position_mm"] = (_verdict(k, r2, 0.3), k, np.flatnonzero(ok))
    kinds = {v[0] for v in verdicts.values()}
    if "x1000" in kinds and "ok" not in kinds:
        first = min(int(v[2][0]) for v in verdicts.values() if v[0] == "x1000")
        problems.append((label_of["speed_cmd_mm_s"], first + 1,
                         "measured speeds/position are ~1000x the kinematic prediction: "
                         "speed_cmd_mm_s looks like m/s"))
        return
    expected = {"motor_speed_rpm": f"{screw_rpm_per_mm_s * ratio:g} rpm per mm/s",
                "screw_speed_rpm": f"{screw_rpm_per_mm_s:g} rpm per mm/s",
                "nut_position_mm": "1 mm per mm of integrated speed command"}
    for column, (verdict, k, rows) in verdicts.items():
        label = label_of[column]
        what = (f"{k:.4g} x the kinematic prediction ({expected[column]}, least-squares fit "
                f"over {rows.size} samples, rows {rows[0] + 1} to {rows[-1] + 1})")
        if verdict == "rad_s" and column != "nut_position_mm":
            problems.append((label, int(rows[0]) + 1, f"{what}: looks like rad/s, not rpm"))
        elif verdict == "metre" and column == "nut_position_mm":
            problems.append((label, int(rows[0]) + 1, f"{what}: looks like metres, not mm"))
        elif verdict == "sign":
            warnings.append(f"column '{label}': {what}: sign convention reversed?")
        elif verdict not in ("ok", "undecided"):
            warnings.append(f"column '{label}': {what}: check its unit and the rig kinematics")


# ---------------------------------------------------------------------- writer
def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _check_columns(columns: Mapping[str, Any], problems: list) -> dict[str, np.ndarray]:
    """Validate writer input; return the arrays in file order."""
    arrays: dict[str, np.ndarray] = {}
    for name, value in columns.items():
        if not isinstance(name, str) or not name or name != name.strip() \
                or any(c in name for c in ',"\r\n'):
            problems.append((str(name), 0, "column name must be a non-empty string without "
                                           "commas, quotes, line breaks or edge spaces"))
            continue
        array = np.asarray(value)
        if array.ndim != 1:
            problems.append((name, None, f"must be 1-D, got shape {array.shape}"))
            continue
        if name not in COLUMNS and array.dtype.kind in "US":
            bad = [i for i, s in enumerate(array.astype(str)) if any(c in s for c in ',"\r\n')]
            _add_rows(problems, name, np.array(bad, dtype=int),
                      lambda i: "text cell holds a comma, quote or line break")
            arrays[name] = array.astype(str)
            continue
        try:
            array = array.astype(np.float64)
        except (TypeError, ValueError):
            problems.append((name, None, f"not numeric (dtype {array.dtype})"))
            continue
        nonfinite = ~np.isfinite(array) & ~(np.isnan(array) & (name not in COLUMNS))
        _add_rows(problems, name, np.flatnonzero(nonfinite), lambda i: f"{array[i]} is not finite")
        arrays[name] = array
    for column in ("time_s", "speed_cmd_mm_s", "load_force_N"):
        if column not in columns:
            problems.append((column, 0, "missing required column"))
    if not any(c in columns for c in _SPEED_COLUMNS):
        problems.append((_SPEED_COLUMNS[0], 0,
                         f"missing: one of {', '.join(_SPEED_COLUMNS)} is required"))
    lengths = {name: a.size for name, a in arrays.items()}
    n = lengths.get("time_s", max(lengths.values(), default=0))
    for name, size in lengths.items():
        if size != n:
            problems.append((name, None, f"has {size} samples, time_s has {n}"))
    if n < _MIN_ROWS:
        problems.append(("time_s", None, f"{n} sample(s); at least {_MIN_ROWS} needed"))
    if "time_s" in arrays:
        t = arrays["time_s"]
        _add_rows(problems, "time_s", np.flatnonzero(np.diff(t) <= 0) + 1,
                  lambda i: f"time_s does not strictly increase: {t[i]!r} s after {t[i - 1]!r} s")
    for column in ("primary_enable", "standby_enable"):
        if column in arrays:
            e = arrays[column]
            _add_rows(problems, column, np.flatnonzero((e != 0) & (e != 1)),
                      lambda i: f"enable flag must be 0 or 1, got {e[i]!r}")
    ordered = {c: arrays[c] for c in COLUMNS if c in arrays}
    ordered.update({c: a for c, a in arrays.items() if c not in COLUMNS})
    return ordered


def _format(array: np.ndarray, fmt: str) -> list[str]:
    if array.dtype.kind in "US":
        return array.tolist()
    text = np.char.mod(fmt, array)
    text[np.isnan(array)] = ""
    return text.tolist()


def write_run(stem: str | os.PathLike, columns: Mapping[str, Any], metadata: Mapping[str, Any],
              *, significant_digits: int = 9, overwrite: bool = True) -> tuple[Path, Path]:
    """Write ``stem.csv`` and ``stem.json`` in ``thsa-rig-run/1``, atomically.

    Parameters
    ----------
    stem : str or path-like
        Target path without suffix; its directory must exist.
    columns : mapping of str to array_like
        FORMAT.md column names -> 1-D arrays in FORMAT units (``time_s`` [s],
        ``speed_cmd_mm_s`` [mm/s], ``motor_speed_rpm`` [rpm], ...; positive =
        extending, load positive = compressive).  Standard columns are written
        in FORMAT.md order, then unknown columns in the order given.  Every
        numeric cell must be finite, except NaN in an unknown column, written
        as an empty cell; unknown columns may also be text.
    metadata : mapping
        JSON content; ``format`` is set (a different tag is an error) and
        ``name`` defaults to the stem.  Must satisfy :func:`read_run`.
    significant_digits : int, optional
        Digits of every number (``%.{n}g``).  ``time_s`` uses 17 when fewer
        would make it non-increasing.
    overwrite : bool, optional
        Replace existing files (default) or raise ``FileExistsError``.

    Returns
    -------
    tuple of Path
        ``(csv_path, json_path)``.

    Raises
    ------
    RigDataError
        On invalid input, naming the column and row, before anything is
        written; or when the written files would not read back.
    FileExistsError, FileNotFoundError
        Existing target without ``overwrite``; missing target directory.

    Notes
    -----
    Both files are written and read back with :func:`read_run` in a
    temporary directory next to the target, then renamed into place; a failure
    leaves neither file behind (or the previous pair, if the second rename
    fails after the first succeeded the first new file is removed).

    Examples
    --------
    >>> import tempfile
    >>> tmp = tempfile.TemporaryDirectory()
    >>> cols = {"time_s": [0.0, 0.001], "speed_cmd_mm_s": [0, 0], "load_force_N": [1, float("nan")],
    ...         "motor_speed_rpm": [0, 0]}
    >>> write_run(f"{tmp.name}/bad", cols, {"temperature_C": 20.0})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    thsa_control.errors.RigDataError: ...bad.csv: 1 problem(s)
      column 'load_force_N', row 2: nan is not finite
    >>> tmp.cleanup()
    """
    stem = Path(stem)
    csv_path = stem.parent / f"{stem.name}.csv"
    json_path = stem.parent / f"{stem.name}.json"
    if not stem.parent.is_dir():
        raise FileNotFoundError(f"target directory does not exist: {stem.parent}")
    if not overwrite:
        for path in (csv_path, json_path):
            if path.exists():
                raise FileExistsError(f"{path} exists (overwrite=False)")
    if not isinstance(significant_digits, int) or not 1 <= significant_digits <= 17:
        raise ValueError(f"significant_digits must be an int in 1..17, got {significant_digits!r}")
    if not isinstance(columns, Mapping) or not isinstance(metadata, Mapping):
        raise TypeError("columns and metadata must be mappings (column name -> array, JSON keys)")
    problems: list = []
    arrays = _check_columns(columns, problems)
    if problems:
        raise RigDataError(str(csv_path), problems)
    meta = dict(metadata)
    if meta.get("format", FORMAT_TAG) != FORMAT_TAG:
        raise RigDataError(str(json_path), [(f"{json_path.name}:format", None,
                                             f"is {meta['format']!r}, expected '{FORMAT_TAG}'")])
    meta = {"format": FORMAT_TAG, "name": stem.name, **{k: v for k, v in meta.items()
                                                       if k != "format"}}
    try:
        json_text = json.dumps(meta, indent=2, allow_nan=False, default=_json_default) + "\n"
    except (TypeError, ValueError) as exc:
        raise RigDataError(str(json_path), [(json_path.name, None, f"metadata: {exc}")]) from None

    fmt = f"%.{significant_digits}g"
    text_columns = [_format(a, fmt) for a in arrays.values()]
    if "time_s" in arrays:
        t_text = text_columns[0]
        if np.any(np.diff(np.array(t_text, dtype=float)) <= 0):
            text_columns[0] = _format(arrays["time_s"], "%.17g")
    lines = [",".join(arrays)] + [",".join(cells) for cells in zip(*text_columns)]

    tmp = Path(tempfile.mkdtemp(prefix=f".{stem.name}.", suffix=".tmp", dir=stem.parent))
    try:
        tmp_csv, tmp_json = tmp / csv_path.name, tmp / json_path.name
        tmp_csv.write_text("\n".join(lines) + "\n", encoding="utf-8", newline="")
        tmp_json.write_text(json_text, encoding="utf-8", newline="")
        try:
            read_run(tmp_csv, json_path=tmp_json)
        except RigDataError as exc:
            raise RigDataError(str(csv_path if exc.file == str(tmp_csv) else json_path),
                               exc.problems) from None
        os.replace(tmp_json, json_path)
        try:
            os.replace(tmp_csv, csv_path)
        except OSError:
            json_path.unlink(missing_ok=True)
            raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return csv_path, json_path


def to_columns(run: RigRun) -> dict[str, np.ndarray]:
    """FORMAT.md columns of a run, in FORMAT units: the inverse of :func:`read_run`.

    Parameters
    ----------
    run : RigRun

    Returns
    -------
    dict of str to ndarray
        ``time_s`` [s] and every signal that came from the CSV, converted back
        (mm, mm/s, rpm, ...), then the extra columns; ready for
        :func:`write_run`.  Signals filled from the JSON or from defaults are
        left out, as in the file they came from.
    """
    out = {"time_s": np.array(run.time, dtype=float)}
    for spec in _SPECS[1:]:
        if spec.signal in run.source_columns:
            out[spec.column] = np.asarray(spec.from_si(run.signals[spec.signal]), dtype=float)
    out.update({name: np.array(a) for name, a in run.extra.items()})
    return out
