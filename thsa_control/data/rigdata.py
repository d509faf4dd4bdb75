"""Reader and writer of ``thsa-rig-run/1`` test-rig runs (the summary is in ``rigsummary``).

This is the only module of thsa-control that parses rig-run files (component-rig
tables are read by ``component_id``).  It owns the
format described in full in ``docs/rig_format.md`` (the shared contract is
``rig-data/FORMAT.md``): a run is ``NAME.csv`` (samples, in
FORMAT units: mm, mm/s, rpm, N, A, degC) plus ``NAME.json`` (metadata).
Everything downstream receives a :class:`RigRun` whose signals are SI (the one
exception is ``temperature``, kept in degC as everywhere in the project).  It
imports numpy, the standard library, :mod:`thsa_control.errors` and its own
parts only; never matplotlib.  The parts: ``rigformat`` (columns, units, the
records), ``_csvtable`` (the one-pass chunked CSV reader: time and memory
linear in rows x columns), ``rigchecks`` (JSON validation, unit heuristics,
JSON/CSV cross-checks); ``rigsummary`` summarises a run for ``thsa check-data``.

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
  Extensions the workbench reads beyond FORMAT.md (``docs/rig_format.md``):
  ``controller.position_loop`` (a position P loop; needs the
  ``position_cmd_mm`` column), ``controller.current_feedforward`` (a
  current added at the velocity loop's output: ``offset_A`` and/or an extra
  CSV ``column`` in A, every cell a number), ``controller.computation_delay_samples``.
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
  than 10 % contradicts the JSON and is an error too (the median is robust to
  a few irregular samples).
* JSON ``temperature_C`` more than 10 K outside the range of a CSV
  ``temperature_C`` column contradicts it (error).
* ``load_force_N`` in kN: when the largest |load| is below 200 and the motor
  current during motion rises with |load| 100-10000x faster than the rig
  kinematics and a ~0.324 N m/A motor predict (fit explaining half of the
  current's variance), an error.  An unloaded run read in newtons shows no
  such slope; no current column or no motion gives no verdict.
* The JSON controller's period is checked against the plant (its electrical
  time constant) where a plant is known: ``thsa residual``/``identify`` and
  every replay (:func:`thsa_control.loops.design.check_control_period`).

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

import json
import os
import shutil
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from thsa_control.errors import RigDataError
from thsa_control.data import _csvtable
from thsa_control.data.rigchecks import (
    _check_controller_columns, _check_gaps, _check_metadata, _check_units, _load_json,
)
from thsa_control.data.rigformat import (  # noqa: F401  (re-exported: the public names live here)
    _BY_SIGNAL,
    _MAX_TEMPERATURE_C,
    _MIN_ROWS,
    _SPECS,
    _SPEED_COLUMNS,
    COLUMNS,
    DEFAULT_GEAR_RATIO,
    DEFAULT_SCREW_LEAD_MM,
    FORMAT_TAG,
    MAX_ROWS_LISTED,
    ColumnSpec,
    CurrentLoopGains,
    RigController,
    RigRun,
    VelocityLoopGains,
    _add_rows,
    _number,
    true_runs,
    drive_on,
    measured_motor_speed,
    motion_sign,
    stop_band,
    speed_integral,
    motor_speed_from,
)
from thsa_control.data.units import mm_to_m

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

# ------------------------------------------------------------------------- CSV
def _load_csv(path: Path, problems: list) -> "_csvtable.Table | None":
    try:
        table = _csvtable.read_table(path)
    except FileNotFoundError:
        problems.append((None, None, f"CSV file not found: {path}"))
        return None
    except (OSError, UnicodeDecodeError) as exc:
        problems.append((None, None, f"cannot read CSV file: {exc}"))
        return None
    except _csvtable.TableError as exc:
        problems.append((None, exc.row, str(exc)))
        return None
    if table is None:
        problems.append((None, 0, "empty file: no header line"))
        return None
    return table


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
             json_path: str | os.PathLike | None = None,
             default_kinematics: tuple[float, float] | None = None) -> RigRun:
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
    default_kinematics : (screw_lead_mm, gear_ratio), optional
        Kinematics where the JSON's ``rig`` block states none (the parameter
        set's, so that the unit checks use the rig's); default FORMAT.md's
        seed values.  Whether stated ones agree with the parameter set is
        decided by :func:`thsa_control.fit.kinematics.run_kinematics`.

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
        names, labels = _map_header(table.header, column_map, csv_problems)
    parsed = None
    if meta is not None:
        parsed = _check_metadata(meta, json_path.name, "temperature_C" in names, json_problems,
                                 default_kinematics)
    lead_mm, ratio = (parsed[2], parsed[3]) if parsed else (DEFAULT_SCREW_LEAD_MM,
                                                            DEFAULT_GEAR_RATIO)
    columns: dict[str, np.ndarray] = {}
    extra: dict[str, np.ndarray] = {}
    source: dict[str, str] = {}
    if table is not None:
        columns, extra, source = _check_table(table, names, labels, meta, lead_mm, ratio,
                                              csv_problems, warnings)
        if parsed is not None:
            _check_controller_columns(parsed[0], columns, extra, json_path.name, json_problems)
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
                  screw_lead=float(mm_to_m(lead_mm)), gear_ratio=ratio, source_columns=source,
                  kinematics_stated=tuple(k for k in ("screw_lead_mm", "gear_ratio")
                                          if isinstance(meta.get("rig"), dict) and k in meta["rig"]))


def _check_table(table, names, labels, meta, lead_mm, ratio, problems, warnings):
    """Check every column of the table; return (standard columns, extras, sources)."""
    header, n_rows = table.header, table.n_rows
    width = len(header)
    if n_rows < _MIN_ROWS:
        problems.append((None, None, f"{n_rows} data row(s); at least {_MIN_ROWS} needed"))
    ragged = np.zeros(n_rows, dtype=bool)
    ragged[table.ragged_rows] = True
    _add_rows(problems, None, table.ragged_rows,
              lambda i: f"has {table.ragged.get(i, '?')} field(s), the header has {width}")

    label_of = dict(zip(names, labels))
    for column in ("time_s", "speed_cmd_mm_s", "load_force_N"):
        if column not in names:
            problems.append((column, 0, "missing required column"))
    if not any(c in names for c in _SPEED_COLUMNS):
        problems.append((_SPEED_COLUMNS[0], 0,
                         f"missing: one of {', '.join(_SPEED_COLUMNS)} is required"))

    counts: dict[str, int] = {}
    for name in names:
        counts[name] = counts.get(name, 0) + 1
    columns, extra, source, clean = {}, {}, {}, set()
    text_extras = []
    for j, name in enumerate(names):
        if counts[name] > 1 or not name:
            continue
        values = table.values[:, j]
        texts = table.texts[j]
        empty = np.zeros(n_rows, dtype=bool)
        empty[table.empty[j]] = True
        invalid_rows = table.invalid[j]
        if name not in COLUMNS:  # unknown column: kept, not validated
            if invalid_rows.size:
                text_extras.append(j)
            else:
                extra[header[j]] = values
            continue
        spec, label, before = COLUMNS[name], labels[j], len(problems)
        _add_rows(problems, label, invalid_rows, lambda i: f"not a number: {texts.get(i, '?')!r}")
        nonfinite = np.flatnonzero(~np.isfinite(values) & ~empty & ~ragged)
        nonfinite = np.setdiff1d(nonfinite, invalid_rows, assume_unique=True)
        _add_rows(problems, label, nonfinite,
                  lambda i: f"{texts.get(i, '?')!r} is not allowed (a missing value is an empty cell)")
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
                      lambda i: f"enable flag must be 0 or 1, got {values[i]:.9g}")
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
    if text_extras:
        full = _csvtable.column_texts(table.path, text_extras)
        for j in text_extras:
            extra[header[j]] = full[j]
    if not ragged.any() and n_rows >= _MIN_ROWS:
        _check_units(columns, clean, label_of, meta, lead_mm, ratio, problems, warnings)
    return columns, extra, source


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
    """The cells of one column: ``fmt % value`` (Python's formatting of the float), NaN as an empty cell.

    The same text as ``np.char.mod(fmt, array)`` (which applies ``%`` to each numpy scalar), in well under half
    the time: the CSV formatting was most of writing a run.
    """
    if array.dtype.kind in "US":
        return array.tolist()
    text = [fmt % v for v in array.tolist()]
    for i in np.flatnonzero(np.isnan(array)).tolist():
        text[i] = ""
    return text


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
