"""Component identification from component-rig tables (issue 4, item 5).

This module owns the *component table*: a small CSV written by a component
rig (or by :func:`generate_component_table`), one header line of column names
preceded by ``#`` comment lines that carry its provenance, as in the NIST StRD
files.  It reads, validates, writes and generates such tables and fits the
effect library's component laws to them.  It never re-writes the physics: every
model value and every Jacobian comes from the casadi Functions of
:data:`thsa_control.model.laws.LAWS`, evaluated vectorised with
``law.function.map(n)`` and differentiated by casadi.  It imports numpy, scipy,
casadi and the package's ``errors``, ``params``, ``units`` and ``model.laws``;
never matplotlib.

Table kinds (:data:`KINDS`)
---------------------------
``noback_disk``
    ``screw_speed_rpm, normal_force_N, torque_Nm``: a friction-disk rig.  The
    sign of the screw speed selects the rotation direction and so the law
    (``noback_disk_pos`` / ``noback_disk_neg``, the papers' Table 2 Stribeck law
    per direction); the torque carries the sign of the speed.
``loadpath_stiffness``
    ``deflection_mm, force_N``: a static load-path test (deflection positive
    when the nut pushes the surface, force compressive positive) -> backlash
    ``bpb``, disk-spring stiffness ``kds`` (the law applies ``2 kds``), contact
    stiffnesses ``kp,u`` (beyond ``+b``) and ``kp,l`` (beyond ``-b``): the
    papers' Table 1.
``temperature_friction``
    ``temperature_C, motor_speed_rpm, torque_Nm``: no-load drag torque at the
    motor shaft on a temperature x speed grid (the papers' 8 x 8 cold tests)
    -> the ``temperature_friction`` law's ``friction.*`` parameters and
    ``gear.viscous_friction``.  ``friction.reference_temperature`` (a
    definition: gear.viscous_friction and it are not separable) and
    ``motor.bearing_viscous_friction`` are held by default.

How the fit works
-----------------
Least squares of ``law(inputs, p) - measured`` over the free parameters with
``scipy.optimize.least_squares`` (trust-region reflective), the exact casadi
Jacobian, each parameter scaled by its initial magnitude, and the
:class:`~thsa_control.model.params.ParameterSet` bounds.  Standard errors come from
the Jacobian at the optimum, ``cov = s^2 (J^T J)^-1`` with
``s^2 = RSS / (n - k)``; confidence intervals use Student's t.

The load-path law is piecewise linear with a kink at ``|deflection| = b``: the
residual is not differentiable in the backlash wherever a data point sits on
the edge, and the cost has a local minimum between every two data points.  The
fit therefore *profiles* the backlash: for fixed ``b`` the law is linear in the
three stiffnesses, so they are solved exactly by bounded linear least squares
(design matrix = the casadi Jacobian); the profile cost ``S(b)`` is smooth
between consecutive data deflections, so it is evaluated once inside every such
interval (at most ``profile_points`` intervals) and refined with a bounded
scalar search in the three best intervals.  A final joint least-squares polish
from the profile optimum gives the covariance.  ``global_stage=True`` instead
runs scipy's differential evolution over all free parameters (log-scaled for
wide positive ranges), as the papers do, before the same polish; it works for
every kind.

Examples
--------
>>> import numpy as np
>>> from thsa_control.model.params import default_parameters
>>> p = default_parameters()
>>> table = generate_component_table("loadpath_stiffness", p, noise=50.0, rng=1)
>>> fit = fit_component(table, params=p)
>>> round(fit.values["loadpath.backlash"] * 1e3, 2), fit.n_data
(0.67, 61)
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from scipy import optimize, stats

from thsa_control.errors import ModelError, ParameterError, RigDataError
from thsa_control.model.laws import LAWS
from thsa_control.model.params import ParameterSet, default_parameters
from thsa_control.data.units import mm_to_m, rpm_to_rad_s

__all__ = [
    "ComponentKind",
    "KINDS",
    "DEFAULT_GRIDS",
    "ComponentTable",
    "ComponentFit",
    "read_component_table",
    "write_component_table",
    "generate_component_table",
    "fit_component",
    "format_component_fit",
]

Float1D = NDArray[np.float64]

#: How many rows of one repeated problem are listed before they are counted.
MAX_ROWS_LISTED = 10
#: Correlation above which two parameters are flagged as not identifiable together.
CORRELATION_LIMIT = 0.95


def _identity(x):
    return np.asarray(x, dtype=float)


@dataclass(frozen=True)
class ComponentKind:
    """What a component table holds and which laws it identifies.

    Parameters
    ----------
    name : str
        Kind name (``noback_disk``, ``loadpath_stiffness``, ``temperature_friction``).
    columns : tuple of str
        Required CSV columns, operating variables first, the measured output last.
    units : tuple of str
        Unit of each column in the file.
    laws : tuple of str
        Names in :data:`~thsa_control.model.laws.LAWS`.
    law_inputs : dict of str to (str, callable)
        Law input name -> (column, conversion from the file unit to SI).
    default_free : tuple of str
        Parameters fitted when ``free`` is not given.
    description : str
        One line.
    """

    name: str
    columns: tuple[str, ...]
    units: tuple[str, ...]
    laws: tuple[str, ...]
    law_inputs: dict[str, tuple[str, Callable]]
    default_free: tuple[str, ...]
    description: str

    @property
    def output(self) -> str:
        """The measured column (last)."""
        return self.columns[-1]


KINDS: dict[str, ComponentKind] = {
    k.name: k
    for k in (
        ComponentKind(
            "noback_disk", ("screw_speed_rpm", "normal_force_N", "torque_Nm"), ("rpm", "N", "N m"),
            ("noback_disk_pos", "noback_disk_neg"),
            {"screw_speed": ("screw_speed_rpm", rpm_to_rad_s), "normal_force": ("normal_force_N", _identity)},
            LAWS["noback_disk_pos"].parameters + LAWS["noback_disk_neg"].parameters,
            "no-back friction disk: screw speed (sign = direction) and normal force -> friction torque",
        ),
        ComponentKind(
            "loadpath_stiffness", ("deflection_mm", "force_N"), ("mm", "N"), ("loadpath_force",),
            {"deflection": ("deflection_mm", mm_to_m)},
            ("loadpath.backlash", "loadpath.disk_spring_stiffness", "loadpath.contact_stiffness_upper",
             "loadpath.contact_stiffness_lower"),
            "static load path: deflection (nut minus surface) -> force, compressive positive",
        ),
        ComponentKind(
            "temperature_friction", ("temperature_C", "motor_speed_rpm", "torque_Nm"), ("degC", "rpm", "N m"),
            ("transmission_drag",),
            {"motor_speed": ("motor_speed_rpm", rpm_to_rad_s), "temperature": ("temperature_C", _identity)},
            ("gear.viscous_friction", "friction.viscous_temperature_coefficient", "friction.cold_coulomb_torque",
             "friction.coulomb_temperature_coefficient", "friction.cold_stribeck_ratio",
             "friction.cold_stribeck_speed"),
            "no-load transmission drag at the motor shaft versus temperature and motor speed",
        ),
    )
}

#: Default generator grids (full factorial over the operating columns), file units.
#: ``noback_disk``: 10 speeds each way, 1..75 rpm screw (0.2..15 mm/s at the nut)
#: around the papers' Stribeck speeds (15-18 rpm), times 6 normal forces from
#: the preload (3 kN) to 30 kN.  ``loadpath_stiffness``: +-1.5 mm in 0.05 mm
#: steps (about +-45 kN).  ``temperature_friction``: the papers' 8 temperatures
#: 5..-55 degC times 8 motor speeds, 50..5000 rpm (0.15..15 mm/s at the nut).
DEFAULT_GRIDS: dict[str, dict[str, tuple[float, ...]]] = {
    "noback_disk": {
        "screw_speed_rpm": tuple(np.concatenate([-np.geomspace(75.0, 1.0, 10), np.geomspace(1.0, 75.0, 10)]).round(4)),
        "normal_force_N": (3000.0, 6000.0, 10000.0, 15000.0, 22000.0, 30000.0),
    },
    "loadpath_stiffness": {"deflection_mm": tuple(np.linspace(-1.5, 1.5, 61).round(6))},
    "temperature_friction": {
        "temperature_C": tuple(np.linspace(5.0, -55.0, 8).round(4)),
        "motor_speed_rpm": tuple(np.geomspace(50.0, 5000.0, 8).round(3)),
    },
}

_COMMENT_KEY = re.compile(r"^\s*([A-Za-z_][\w .-]*?)\s*:\s*(.*)$")
_TRUTH = re.compile(r"^\s*([\w.]+)\s*=\s*([-+0-9.eE]+)\s*(.*)$")


def _kind(name: str) -> ComponentKind:
    try:
        return KINDS[name]
    except KeyError:
        raise ModelError(f"unknown component-table kind {name!r}; known: {', '.join(KINDS)}") from None


# ----------------------------------------------------------------- the table
def _check_columns(kind: ComponentKind, columns: Mapping[str, np.ndarray], label_rows: bool = True) -> list:
    """Semantic problems (missing column, non-finite, physics) as (column, row, message)."""
    problems: list = []
    missing = [c for c in kind.columns if c not in columns]
    for c in missing:
        problems.append((c, None, f"missing required column for a '{kind.name}' table "
                                  f"(needs {', '.join(kind.columns)})"))
    lengths = {c: np.asarray(v).shape for c, v in columns.items() if c in kind.columns}
    if len({s for s in lengths.values()}) > 1:
        problems.append((None, None, f"columns differ in length: {lengths}"))
        return problems
    present = [c for c in kind.columns if c in columns]
    n = next(iter(lengths.values()))[0] if lengths else 0
    if not missing and n < 2:
        problems.append((None, None, f"needs at least 2 data rows, has {n}"))

    def rows(c, mask, message):
        idx = np.flatnonzero(mask)
        for i in idx[:MAX_ROWS_LISTED]:
            problems.append((c, int(i) + 1, message(float(np.asarray(columns[c])[i]))))
        if idx.size > MAX_ROWS_LISTED:
            problems.append((c, int(idx[MAX_ROWS_LISTED]) + 1,
                             f"... and {idx.size - MAX_ROWS_LISTED} more row(s) with the same problem"))

    for c in present:
        v = np.asarray(columns[c], dtype=float)
        rows(c, ~np.isfinite(v), lambda x: f"value {x} is not a finite number")
    if missing:
        return problems
    if kind.name == "noback_disk":
        rows("screw_speed_rpm", np.asarray(columns["screw_speed_rpm"]) == 0.0,
             lambda x: "zero screw speed: the rotation direction (and so the law) is undefined")
        rows("normal_force_N", np.asarray(columns["normal_force_N"]) < 0.0,
             lambda x: f"negative normal force {x:g} N (the disks are compressed: >= 0)")
    elif kind.name == "temperature_friction":
        rows("motor_speed_rpm", np.asarray(columns["motor_speed_rpm"]) == 0.0,
             lambda x: "zero motor speed: the drag direction is undefined (standstill is not a drag point)")
        t = np.asarray(columns["temperature_C"])
        rows("temperature_C", (t > 150.0) | (t < -273.15),
             lambda x: f"temperature {x:g} degC is impossible or in kelvin (expects degC)")
    return problems


@dataclass(frozen=True, eq=False)
class ComponentTable:
    """A validated component-rig table, in its file units.

    Parameters
    ----------
    kind : str
        A key of :data:`KINDS`.
    columns : dict of str to ndarray
        Columns by name, in the file units (rpm, N, N m, mm, degC); the kind's
        required columns plus any extra ones (kept, unused; text columns stay
        strings).
    path : str or None
        File the table was read from; None when built in memory.
    comments : tuple of str
        The ``#`` provenance lines, without the ``#``.

    Raises
    ------
    RigDataError
        A required column is missing or has a non-finite value, or a value is
        physically meaningless (zero speed, negative normal force, kelvin);
        the message names the file (or ``<table>``), the column and the row.
    """

    kind: str
    columns: dict[str, np.ndarray]
    path: str | None = None
    comments: tuple[str, ...] = ()

    def __post_init__(self):
        kind = KINDS.get(self.kind)
        where = self.path or "<table>"
        if kind is None:
            raise RigDataError(where, [(None, None, f"unknown component-table kind {self.kind!r}; "
                                                    f"known: {', '.join(KINDS)}")])
        cols = {}
        for c, v in self.columns.items():
            try:
                a = np.array(v, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                if c in kind.columns:
                    raise RigDataError(where, [(c, None, "values are not numbers")]) from None
                a = np.array(v, dtype=str).reshape(-1)  # an extra text column, kept as is
            a.setflags(write=False)
            cols[c] = a
        problems = _check_columns(kind, cols)
        if problems:
            raise RigDataError(where, problems)
        object.__setattr__(self, "columns", cols)
        object.__setattr__(self, "comments", tuple(self.comments))

    @property
    def spec(self) -> ComponentKind:
        """The :class:`ComponentKind` of this table."""
        return KINDS[self.kind]

    @property
    def n_rows(self) -> int:
        """Number of data rows."""
        return int(self.columns[self.spec.output].size)

    @property
    def metadata(self) -> dict[str, str]:
        """``key: value`` comment lines (first occurrence of each key)."""
        out: dict[str, str] = {}
        for line in self.comments:
            m = _COMMENT_KEY.match(line)
            if m and m.group(1) not in out:
                out[m.group(1)] = m.group(2).strip()
        return out

    @property
    def truth(self) -> dict[str, float]:
        """Certified values from ``truth: name = value unit`` comment lines (empty if none)."""
        out: dict[str, float] = {}
        for line in self.comments:
            m = _COMMENT_KEY.match(line)
            if m and m.group(1) == "truth":
                t = _TRUTH.match(m.group(2))
                if t:
                    out[t.group(1)] = float(t.group(2))
        return out

    def law_inputs(self) -> dict[str, Float1D]:
        """Operating variables in SI by law input name (``screw_speed`` [rad/s], ...)."""
        return {name: np.asarray(conv(self.columns[col]), dtype=float)
                for name, (col, conv) in self.spec.law_inputs.items()}

    @property
    def measured(self) -> Float1D:
        """The measured output (torque [N m] or force [N])."""
        return self.columns[self.spec.output]


def read_component_table(path: str | os.PathLike, kind: str | None = None) -> ComponentTable:
    """Read and validate a component-rig table.

    Parameters
    ----------
    path : path
        CSV file: optional ``#`` comment lines (provenance; ``kind: NAME``
        gives the kind), one header line of column names, then one row per
        point, ``.`` as decimal point, no units in cells.
    kind : str, optional
        A key of :data:`KINDS`; when omitted the file's ``# kind:`` line is used.
        When both are given they must agree.

    Returns
    -------
    ComponentTable

    Raises
    ------
    RigDataError
        Every problem found, each with the column and the data row (rows count
        from 1, the header is row 0): unreadable file, no header, unknown or
        contradictory kind, duplicated or missing column, a row with the wrong
        number of cells, an empty, non-numeric, NaN or infinite cell, zero
        speed (direction undefined), negative normal force, a temperature in
        kelvin.  Nothing is returned partially.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     f = Path(d) / "lp.csv"
    ...     _ = f.write_text("# kind: loadpath_stiffness\\ndeflection_mm,force_N\\n-1,-40000\\n0,0\\n1,30000\\n")
    ...     t = read_component_table(f)
    >>> t.kind, t.n_rows, float(t.columns["force_N"][-1])
    ('loadpath_stiffness', 3, 30000.0)
    """
    path = Path(path)
    where = str(path)
    try:
        text = path.read_text(encoding="utf-8-sig")  # tolerate the byte-order mark spreadsheets write
    except (OSError, UnicodeDecodeError) as exc:
        raise RigDataError(where, [(None, None, f"cannot read component table: {exc}")]) from None
    lines = text.splitlines()
    comments: list[str] = []
    i = 0
    while i < len(lines) and (lines[i].lstrip().startswith("#") or not lines[i].strip()):
        if lines[i].lstrip().startswith("#"):
            comments.append(lines[i].lstrip()[1:].strip())
        i += 1
    problems: list = []
    file_kind = None
    for c in comments:
        m = _COMMENT_KEY.match(c)
        if m and m.group(1) == "kind":
            file_kind = m.group(2).strip()
            break
    if kind is None and file_kind is None:
        raise RigDataError(where, [(None, None, "no kind given and no '# kind: NAME' comment line; "
                                                f"known kinds: {', '.join(KINDS)}")])
    if kind is not None and file_kind is not None and kind != file_kind:
        problems.append((None, None, f"kind {kind!r} requested but the file says '# kind: {file_kind}'"))
    kind_name = kind if kind is not None else file_kind
    if kind_name not in KINDS:
        raise RigDataError(where, problems + [(None, None, f"unknown component-table kind {kind_name!r}; "
                                                           f"known: {', '.join(KINDS)}")])
    if i >= len(lines):
        raise RigDataError(where, problems + [(None, 0, "no header line of column names")])
    header = [h.strip() for h in next(csv.reader([lines[i]]))]
    seen = set()
    for h in header:
        if h in seen:
            problems.append((h, 0, "column name appears twice in the header"))
        seen.add(h)
    if any(not h for h in header):
        problems.append((None, 0, "empty column name in the header"))
    data_lines = [(k + 1 + i, ln) for k, ln in enumerate(lines[i + 1:])
                  if ln.strip() and not ln.lstrip().startswith("#")]
    cells: dict[str, list[str]] = {h: [] for h in header}
    bad: dict[tuple[str, str], list[int]] = {}
    for row, (lineno, ln) in enumerate(data_lines, start=1):
        rec = next(csv.reader([ln]))
        if len(rec) != len(header):
            problems.append((None, row, f"has {len(rec)} cell(s), the header has {len(header)} (line {lineno})"))
            rec = (rec + [""] * len(header))[:len(header)]
        for h, cell in zip(header, rec):
            cells[h].append(cell.strip())
    columns: dict[str, np.ndarray] = {}
    for h in header:
        values = np.full(len(cells[h]), np.nan)
        for r, cell in enumerate(cells[h]):
            if cell == "":
                bad.setdefault((h, "empty cell (missing value)"), []).append(r + 1)
                continue
            try:
                if "_" in cell:
                    raise ValueError(cell)
                values[r] = float(cell)
            except ValueError:
                bad.setdefault((h, "not a number"), []).append(r + 1)
                continue
            if not math.isfinite(values[r]) and h in KINDS[kind_name].columns:
                bad.setdefault((h, f"{cell!r} is not a finite number (missing values are not allowed)"),
                               []).append(r + 1)
        if h not in KINDS[kind_name].columns and any(m == "not a number" for (c, m) in bad if c == h):
            columns[h] = np.array(cells[h], dtype=str)
        else:
            columns[h] = values
    for (h, message), rows in bad.items():
        if h not in KINDS[kind_name].columns:
            continue  # extra columns are kept, unvalidated
        for r in rows[:MAX_ROWS_LISTED]:
            problems.append((h, r, f"{message}: {cells[h][r - 1]!r}" if message == "not a number" else message))
        if len(rows) > MAX_ROWS_LISTED:
            problems.append((h, rows[MAX_ROWS_LISTED], f"... and {len(rows) - MAX_ROWS_LISTED} more row(s): {message}"))
    if problems:
        # semantic problems of the columns that parsed, so that one error lists everything
        semantic = [p for p in _check_columns(KINDS[kind_name], columns)
                    if not (p[0] is not None and p[1] is not None and (p[0], p[1]) in
                            {(q[0], q[1]) for q in problems})]
        semantic = [p for p in semantic if "not a finite number" not in p[2]]
        raise RigDataError(where, problems + semantic)
    return ComponentTable(kind_name, columns, path=where, comments=tuple(comments))


def write_component_table(path: str | os.PathLike, table: ComponentTable, *,
                          comments: Sequence[str] | None = None) -> Path:
    """Write a component table as CSV with its ``#`` provenance lines (atomically).

    Parameters
    ----------
    path : path
        Target file; its folder must exist.
    table : ComponentTable
        The table; its required columns are written first, extra ones after.
    comments : sequence of str, optional
        Provenance lines replacing ``table.comments``.  A ``kind:`` line is
        added when absent.

    Returns
    -------
    Path
        The written file.
    """
    path = Path(path)
    lines = list(table.comments if comments is None else comments)
    if not any((m := _COMMENT_KEY.match(c)) and m.group(1) == "kind" for c in lines):
        lines.insert(0, f"kind: {table.kind}")
    names = list(table.spec.columns) + [c for c in table.columns if c not in table.spec.columns]
    buf = io.StringIO()
    for c in lines:
        buf.write(f"# {c}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    cols = [table.columns[c] for c in names]
    for i in range(table.n_rows):
        w.writerow([f"{c[i]:.10g}" if c.dtype.kind == "f" else str(c[i]) for c in cols])
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(buf.getvalue())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def generate_component_table(kind: str, params: ParameterSet | None = None, *, noise: float,
                             rng: np.random.Generator | int | None,
                             grid: Mapping[str, Sequence[float]] | None = None,
                             repeats: int = 1) -> ComponentTable:
    """A synthetic component table with known truth (the laws of the effect library plus noise).

    Parameters
    ----------
    kind : str
        A key of :data:`KINDS`.
    params : ParameterSet, optional
        True parameter values; default :func:`~thsa_control.model.params.default_parameters`
        (the papers' Tables 1 and 2 and the assumed temperature law).
    noise : float
        Standard deviation of the Gaussian noise added to the measured column,
        in its unit ([N m] for torques, [N] for the load-path force); >= 0.
    rng : numpy.random.Generator or int or None
        Random generator or seed.
    grid : mapping of column name to sequence of float, optional
        Values of each operating column (file units); the table is their full
        factorial.  Default :data:`DEFAULT_GRIDS` ``[kind]``.
    repeats : int
        Each grid point is measured ``repeats`` times (independent noise).

    Returns
    -------
    ComponentTable
        With comment lines ``kind``, ``source``, ``noise`` and one
        ``truth: name = value unit`` line per law parameter (read back by
        :attr:`ComponentTable.truth`).

    Raises
    ------
    ModelError
        Unknown kind.
    ValueError
        Negative noise, ``repeats < 1``, or a grid missing an operating column.

    Examples
    --------
    >>> t = generate_component_table("noback_disk", noise=0.0, rng=0,
    ...                              grid={"screw_speed_rpm": [-10.0, 10.0], "normal_force_N": [10000.0]})
    >>> np.round(t.columns["torque_Nm"], 2)
    array([-57.88,  65.39])
    """
    spec = _kind(kind)
    params = default_parameters() if params is None else params
    if not (noise >= 0.0):
        raise ValueError(f"noise must be >= 0, got {noise!r}")
    if int(repeats) < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats!r}")
    grid = dict(DEFAULT_GRIDS[kind] if grid is None else grid)
    operating = spec.columns[:-1]
    missing = [c for c in operating if c not in grid]
    unknown = [c for c in grid if c not in operating]
    if missing or unknown:
        raise ValueError(f"grid for a '{kind}' table needs exactly the columns {operating}; "
                         f"missing {missing}, unknown {unknown}")
    mesh = np.meshgrid(*[np.asarray(grid[c], dtype=float) for c in operating], indexing="ij")
    columns = {c: np.tile(m.reshape(-1), int(repeats)) for c, m in zip(operating, mesh)}
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    probe = ComponentTable(kind, {**columns, spec.output: np.zeros(columns[operating[0]].size)})
    model = _Model(probe, params.names)
    clean = model.evaluate(params.vector())
    columns[spec.output] = clean + (gen.normal(0.0, noise, clean.size) if noise > 0 else 0.0)
    names = tuple(dict.fromkeys(n for law in spec.laws for n in LAWS[law].parameters))
    comments = [
        f"kind: {kind}",
        f"description: {spec.description}",
        "source: synthetic, thsa_control.fit.component_id.generate_component_table "
        "(laws of the effect library, thsa_control.model.laws)",
        "units: " + ", ".join(f"{c} [{u}]" for c, u in zip(spec.columns, spec.units)),
        f"noise: {noise:g} {spec.units[-1]} rms, Gaussian, added to {spec.output}",
        f"repeats: {int(repeats)}",
    ]
    comments += [f"truth: {n} = {params[n].value:.10g} {params[n].unit} ({params[n].source})" for n in names]
    return ComponentTable(kind, columns, comments=tuple(comments))


# ---------------------------------------------------------------- the model
class _Model:
    """The table's laws as one casadi Function of the full parameter vector.

    ``F(p) -> (prediction[n], d prediction / d p [n x np])``: each law mapped
    over its rows (``law.function.map(n)``), rows in table order.
    """

    def __init__(self, table: ComponentTable, names: Sequence[str]):
        spec = table.spec
        self.names = tuple(names)
        index = {n: i for i, n in enumerate(self.names)}
        inputs = table.law_inputs()
        if spec.name == "noback_disk":
            ws = inputs["screw_speed"]
            groups = {"noback_disk_pos": np.flatnonzero(ws > 0), "noback_disk_neg": np.flatnonzero(ws < 0)}
        else:
            groups = {spec.laws[0]: np.arange(table.n_rows)}
        self.groups = {k: v for k, v in groups.items() if v.size}
        P = ca.MX.sym("p", len(self.names))
        parts, order = [], []
        for law_name, rows in self.groups.items():
            law = LAWS[law_name]
            try:
                p_law = ca.vertcat(*[P[index[n]] for n in law.parameters])
            except KeyError as exc:
                raise ParameterError(exc.args[0], f"needed by law '{law_name}' but not in the parameter set") from None
            args = [ca.DM(inputs[i][rows]).T for i in law.inputs]
            parts.append(law.function.map(rows.size)(*args, p_law).T)
            order.append(rows)
        out = ca.vertcat(*parts)
        perm = np.argsort(np.concatenate(order))
        out = out[perm.tolist()]
        self.value = ca.Function("component_model", [P], [out])
        self.with_jacobian = ca.Function("component_model_jac", [P], [out, ca.jacobian(out, P)])
        self.n = table.n_rows

    def evaluate(self, p: np.ndarray) -> Float1D:
        return np.asarray(self.value(p)).reshape(-1)

    def jacobian(self, p: np.ndarray) -> tuple[Float1D, np.ndarray]:
        out, jac = self.with_jacobian(p)
        return np.asarray(out).reshape(-1), np.asarray(ca.densify(jac))

    def parameters_used(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(n for law in self.groups for n in LAWS[law].parameters))


# ---------------------------------------------------------------- the result
@dataclass(frozen=True, eq=False)
class ComponentFit:
    """Result of :func:`fit_component` (lmfit style; the inputs are untouched).

    Parameters
    ----------
    kind : str
        Table kind.
    laws : tuple of str
        Laws fitted (names in :data:`~thsa_control.model.laws.LAWS`).
    source : str
        Table file, or ``<table>``.
    method : str
        What was run (local, profile, global stage).
    names : tuple of str
        Free parameters, in the order of :attr:`correlation`.
    values, stderr, init : dict of str to float
        Fitted value, standard error (1 sigma; NaN when not identifiable) and
        initial value of each free parameter [SI units of the parameter].
    units : dict of str to str
        Unit of each free parameter.
    held : dict of str to float
        Law parameters held at their value.
    correlation : ndarray
        Correlation matrix of the free parameters.
    n_data, n_free : int
    cost : float
        Residual sum of squares [output unit^2].
    rms_residual : float
        ``sqrt(cost / n_data)`` [N m or N].
    residual_std : float
        ``sqrt(cost / (n_data - n_free))``, the noise estimate [N m or N].
    aic, bic : float
        ``n ln(RSS/n) + 2k`` and ``n ln(RSS/n) + k ln n``.
    residuals : ndarray
        ``measured - model`` per row [N m or N].
    at_bound : tuple of str
        Free parameters at (within 1e-6 relative of) a bound.
    not_identifiable : tuple of str
        Parameters the data cannot determine (singular Jacobian direction).
    correlated_pairs : tuple of (str, str, float)
        Pairs with ``|correlation| > 0.95``: not identifiable together.
    nfev : int
        Model evaluations (all stages).
    success : bool
    message : str
    """

    kind: str
    laws: tuple[str, ...]
    source: str
    method: str
    names: tuple[str, ...]
    values: dict[str, float]
    stderr: dict[str, float]
    init: dict[str, float]
    units: dict[str, str]
    held: dict[str, float]
    correlation: np.ndarray
    n_data: int
    n_free: int
    cost: float
    rms_residual: float
    residual_std: float
    aic: float
    bic: float
    residuals: np.ndarray
    at_bound: tuple[str, ...]
    not_identifiable: tuple[str, ...]
    correlated_pairs: tuple[tuple[str, str, float], ...]
    nfev: int
    success: bool
    message: str

    @property
    def law(self) -> str:
        """The fitted law name(s), joined by ``+``."""
        return "+".join(self.laws)

    @property
    def dof(self) -> int:
        """Degrees of freedom ``n_data - n_free``."""
        return self.n_data - self.n_free

    def confidence_interval(self, name: str, level: float = 0.95) -> tuple[float, float]:
        """Two-sided ``level`` interval of ``name`` (Student t, ``dof`` degrees of freedom) [SI]."""
        if name not in self.values:
            raise ParameterError(name, f"not a free parameter of this fit (free: {', '.join(self.names)})")
        if not 0.0 < level < 1.0:
            raise ValueError(f"level must be in (0, 1), got {level!r}")
        half = float(stats.t.ppf(0.5 + level / 2.0, max(self.dof, 1))) * self.stderr[name]
        return self.values[name] - half, self.values[name] + half

    def to_parameters(self, params: ParameterSet) -> ParameterSet:
        """``params`` with the fitted values, each source naming this fit (value ± stderr).

        Parameters flagged :attr:`not_identifiable` keep their value and source
        in ``params``: the data said nothing about them.

        Raises
        ------
        ParameterError
            A fitted name is not in ``params``.
        """
        new = {}
        for n in self.names:
            if n in self.not_identifiable:
                continue
            old = params[n]
            src = (f"identified: {self.kind} component table {self.source} "
                   f"({self.values[n]:.6g} +- {self.stderr[n]:.2g} {old.unit}, 1 sigma; was {old.value:.6g})")
            new[n] = type(old)(name=n, value=self.values[n], unit=old.unit, source=src, min=old.min,
                               max=old.max, vary=old.vary, description=old.description)
        return params.replace_parameters(new)

    def report(self) -> str:
        """lmfit-style text (see :func:`format_component_fit`)."""
        return format_component_fit(self)


def format_component_fit(fit: ComponentFit, *, min_correl: float = 0.3) -> str:
    """lmfit-style report of a :class:`ComponentFit`.

    Parameters
    ----------
    fit : ComponentFit
    min_correl : float
        Correlations with a smaller magnitude are not listed [-].

    Returns
    -------
    str
    """
    out = ["[[Fit Statistics]]",
           f"    # kind             = {fit.kind} ({', '.join(fit.laws)})",
           f"    # table            = {fit.source}",
           f"    # fitting method   = {fit.method}",
           f"    # function evals   = {fit.nfev}",
           f"    # data points      = {fit.n_data}",
           f"    # variables        = {fit.n_free}",
           f"    chi-square (RSS)   = {fit.cost:.6g}",
           f"    RMS residual       = {fit.rms_residual:.6g}",
           f"    residual std       = {fit.residual_std:.6g}",
           f"    Akaike info crit   = {fit.aic:.4f}",
           f"    Bayesian info crit = {fit.bic:.4f}",
           f"    success            = {fit.success} ({fit.message})",
           "[[Variables]]"]
    width = max(len(n) for n in fit.names) if fit.names else 0
    for n in fit.names:
        v, s = fit.values[n], fit.stderr[n]
        pct = f" ({100 * abs(s / v):.2f}%)" if v != 0 and math.isfinite(s) else ""
        flags = []
        if n in fit.at_bound:
            flags.append("at bound")
        if n in fit.not_identifiable:
            flags.append("NOT IDENTIFIABLE")
        if v == fit.init[n]:
            flags.append("at initial value")
        flag = f"  [{', '.join(flags)}]" if flags else ""
        out.append(f"    {n:<{width}}: {v:.6g} +/- {s:.3g}{pct} {fit.units[n]} (init = {fit.init[n]:.6g}){flag}")
    for n, v in fit.held.items():
        out.append(f"    {n:<{width}}: {v:.6g} (fixed)")
    pairs = []
    for i, a in enumerate(fit.names):
        for j in range(i + 1, len(fit.names)):
            r = fit.correlation[i, j]
            if math.isfinite(r) and abs(r) >= min_correl:
                pairs.append((abs(r), a, fit.names[j], r))
    if pairs:
        out.append(f"[[Correlations]] (unreported correlations are < {min_correl:.3f})")
        for _, a, b, r in sorted(pairs, reverse=True):
            tag = "  NOT IDENTIFIABLE TOGETHER" if abs(r) > CORRELATION_LIMIT else ""
            out.append(f"    C({a}, {b}) = {r:+.4f}{tag}")
    return "\n".join(out)


# ---------------------------------------------------------------- the fit
def _scales(x0: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """Typical magnitude of each parameter: |x0|, else a thousandth of its finite range, else 1."""
    s = np.abs(x0).astype(float)
    for i in np.flatnonzero(s == 0):
        rng = ub[i] - lb[i]
        s[i] = 1e-3 * rng if math.isfinite(rng) and rng > 0 else 1.0
    return s


class _Problem:
    """Residuals of one table over the free parameters, in scaled coordinates ``z = x / s``."""

    def __init__(self, model: _Model, table: ComponentTable, params: ParameterSet, free: tuple[str, ...]):
        self.model = model
        self.y = np.asarray(table.measured, dtype=float)
        self.base = params.vector()
        self.idx = np.array([params.names.index(n) for n in free], dtype=int)
        self.lb = np.array([params[n].min for n in free])
        self.ub = np.array([params[n].max for n in free])
        self.x0 = self.base[self.idx].copy()
        self.s = _scales(self.x0, self.lb, self.ub)
        self.nfev = 0
        self._maps: dict[int, ca.Function] = {}

    def full(self, x: np.ndarray) -> np.ndarray:
        p = self.base.copy()
        p[self.idx] = x
        return p

    def residual_x(self, x: np.ndarray) -> np.ndarray:
        self.nfev += 1
        return self.model.evaluate(self.full(x)) - self.y

    def cost_x(self, x: np.ndarray) -> float:
        r = self.residual_x(x)
        return float(r @ r)

    def population_cost(self, xs: np.ndarray) -> np.ndarray:
        """Cost of each column of ``xs`` (free parameters x candidates), one mapped casadi call."""
        m = xs.shape[1]
        if m not in self._maps:
            self._maps[m] = self.model.value.map(m)
        P = np.repeat(self.base[:, None], m, axis=1)
        P[self.idx, :] = xs
        self.nfev += m
        out = np.asarray(self._maps[m](P))
        return np.sum((out - self.y[:, None]) ** 2, axis=0)

    def fun(self, z):
        return self.residual_x(z * self.s)

    def jac(self, z):
        _, j = self.model.jacobian(self.full(z * self.s))
        return j[:, self.idx] * self.s

    def local(self, x_start: np.ndarray) -> optimize.OptimizeResult:
        z0 = np.clip(x_start, self.lb, self.ub) / self.s
        res = optimize.least_squares(self.fun, z0, jac=self.jac, bounds=(self.lb / self.s, self.ub / self.s),
                                     method="trf", ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=2000)
        res.x_phys = res.x * self.s
        return res


def _profile_backlash(prob: _Problem, free: tuple[str, ...], deflection: np.ndarray,
                      profile_points: int) -> tuple[np.ndarray, int]:
    """Backlash profile with the stiffnesses solved linearly; returns the starting point and evaluations."""
    ib = free.index("loadpath.backlash")
    linear = [i for i, n in enumerate(free) if n in ("loadpath.disk_spring_stiffness",
                                                       "loadpath.contact_stiffness_upper",
                                                       "loadpath.contact_stiffness_lower")]
    x = prob.x0.copy()
    evals = 0

    def solve(b: float) -> tuple[float, np.ndarray]:
        nonlocal evals
        evals += 1
        xb = x.copy()
        xb[ib] = b
        if linear:
            xb[linear] = 0.0
        out, jac = prob.model.jacobian(prob.full(xb))
        if not linear:
            r = out - prob.y
            return float(r @ r), xb
        A = jac[:, prob.idx[linear]]
        rhs = prob.y - out  # the law is linear in the stiffnesses: out(k) = out(0) + A k
        scale = prob.s[linear]
        sol = optimize.lsq_linear(A * scale, rhs, bounds=(prob.lb[linear] / scale, prob.ub[linear] / scale),
                                  method="bvls")
        xb[linear] = sol.x * scale
        r = A @ xb[linear] - rhs
        return float(r @ r), xb

    lo = max(prob.lb[ib], 0.0)
    hi = min(prob.ub[ib], float(np.max(np.abs(deflection))))
    kinks = np.unique(np.abs(deflection))
    kinks = kinks[(kinks > lo) & (kinks < hi)]
    if kinks.size > profile_points:
        kinks = np.unique(np.quantile(kinks, np.linspace(0.0, 1.0, profile_points)))
    edges = np.concatenate([[lo], kinks, [hi]])
    mids = 0.5 * (edges[:-1] + edges[1:])
    costs = np.array([solve(b)[0] for b in mids])
    best_cost, best_x = math.inf, x
    for k in np.argsort(costs)[:3]:
        a, c = edges[k], edges[k + 1]
        if c - a > 0:
            r = optimize.minimize_scalar(lambda b: solve(b)[0], bounds=(a, c), method="bounded",
                                         options={"xatol": 1e-9 * max(hi, 1e-12)})
            cost, xb = solve(float(r.x))
        else:
            cost, xb = solve(float(a))
        if cost < best_cost:
            best_cost, best_x = cost, xb
    return best_x, evals


def _global_stage(prob: _Problem, search_factor: float, seed: int | None) -> tuple[np.ndarray, int]:
    """Differential evolution over the free parameters (log scale for wide positive ranges)."""
    lo, hi, logs = [], [], []
    for x0, lb, ub in zip(prob.x0, prob.lb, prob.ub):
        if x0 > 0:
            a, b = max(lb, x0 / search_factor), min(ub, x0 * search_factor)
        else:
            a, b = lb, (ub if math.isfinite(ub) else lb + 1.0)
        use_log = a > 0 and b / a > 20.0
        logs.append(use_log)
        lo.append(math.log(a) if use_log else a)
        hi.append(math.log(b) if use_log else b)
    logs = np.array(logs)

    def to_x(u):
        return np.where(logs, np.exp(u), u)

    def costs(u):  # the whole population in one call of the mapped law
        u = np.asarray(u, dtype=float).reshape(len(logs), -1)
        return prob.population_cost(to_x(u.T).T)

    res = optimize.differential_evolution(costs, list(zip(lo, hi)), seed=seed, tol=1e-10, maxiter=400,
                                          popsize=20, polish=False, init="sobol", vectorized=True,
                                          updating="deferred")
    return to_x(res.x), int(res.nfev)


def fit_component(table: ComponentTable, *, params: ParameterSet | None = None,
                  free: Sequence[str] | None = None, global_stage: bool = False,
                  seed: int | None = 0, search_factor: float = 10.0,
                  profile_points: int = 400, profile_backlash: bool = True) -> ComponentFit:
    """Fit the table's component law(s) through the effect library's casadi Functions.

    Parameters
    ----------
    table : ComponentTable
        From :func:`read_component_table` or :func:`generate_component_table`.
    params : ParameterSet, optional
        Initial values, bounds and held values; default
        :func:`~thsa_control.model.params.default_parameters`.  Not modified.
    free : sequence of str, optional
        Parameters to fit, all read by the table's law(s); default the kind's
        ``default_free`` (for a disk table only the directions present).
    global_stage : bool
        Run differential evolution first (search box ``[x0/search_factor,
        x0*search_factor]`` within the bounds, log-scaled when wide), then the
        local polish.  Without it a load-path fit with a free backlash profiles
        the backlash (module docstring).
    seed : int or None
        Seed of the global stage.
    search_factor : float
        Width of the global search box around the initial values (> 1).
    profile_points : int
        Most backlash intervals evaluated by the profile.
    profile_backlash : bool
        Profile a free load-path backlash (default).  False runs the local
        least squares alone from the initial values, which the backlash edge
        can trap in a local minimum (kept for comparison and tests).

    Returns
    -------
    ComponentFit

    Raises
    ------
    ParameterError
        A free name is unknown, not read by the law(s), or (disk tables) belongs
        to a direction with no data.
    ValueError
        Fewer data rows than free parameters, or a bad option.
    """
    params = default_parameters() if params is None else params
    if not search_factor > 1.0:
        raise ValueError(f"search_factor must be > 1, got {search_factor!r}")
    if int(profile_points) < 2:
        raise ValueError(f"profile_points must be >= 2, got {profile_points!r}")
    spec = table.spec
    model_probe = _Model(table, params.names)
    used = model_probe.parameters_used()
    all_law = tuple(dict.fromkeys(n for law in spec.laws for n in LAWS[law].parameters))
    if free is None:
        free = tuple(n for n in spec.default_free if n in used)
    else:
        free = tuple(free)
        for n in free:
            params[n]  # unknown names raise ParameterError
            if n not in all_law:
                raise ParameterError(n, f"not a parameter of the '{spec.name}' law(s); "
                                        f"they read: {', '.join(all_law)}")
            if n not in used:
                raise ParameterError(n, f"its rotation direction has no rows in {table.path or '<table>'}")
        twice = sorted({n for n in free if free.count(n) > 1})
        if twice:
            raise ParameterError(twice[0], "listed twice in free")
    if not free:
        raise ParameterError("free", "no free parameter to fit")
    if table.n_rows <= len(free):
        raise ValueError(f"{table.n_rows} data rows cannot determine {len(free)} free parameters")

    prob = _Problem(model_probe, table, params, free)
    stages = []
    extra_nfev = 0
    start = prob.x0
    if global_stage:
        start, n_de = _global_stage(prob, search_factor, seed)
        extra_nfev += n_de
        stages.append(f"differential evolution (scipy, {n_de} evaluations)")
    elif profile_backlash and "loadpath.backlash" in free:
        deflection = table.law_inputs()["deflection"]
        start, n_prof = _profile_backlash(prob, free, deflection, int(profile_points))
        extra_nfev += n_prof
        stages.append(f"backlash profile with linear stiffnesses ({n_prof} profile points)")
    res = prob.local(start)
    stages.append("least_squares (trf, exact casadi Jacobian, scaled, bounded)")
    x = res.x_phys
    cost_start = prob.cost_x(start)
    if cost_start < prob.cost_x(x):  # the polish never makes a global-stage optimum worse
        x = np.asarray(start, dtype=float)

    r = prob.residual_x(x)
    n, k = r.size, len(free)
    rss = float(r @ r)
    _, jac = prob.model.jacobian(prob.full(x))
    js = jac[:, prob.idx] * prob.s
    s2 = rss / max(n - k, 1)
    u, sv, vt = np.linalg.svd(js, full_matrices=False)
    tol = sv.max() * max(js.shape) * np.finfo(float).eps * 1e3 if sv.size else 0.0
    good = sv > tol
    cov_z = (vt[good].T / sv[good] ** 2) @ vt[good] * s2
    null = vt[~good]
    weak = np.zeros(k, dtype=bool)
    if null.size:
        weak = np.any(np.abs(null) > 1e-3, axis=0)
    cov = cov_z * np.outer(prob.s, prob.s)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    std[weak] = np.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    corr[weak, :] = np.nan
    corr[:, weak] = np.nan
    np.fill_diagonal(corr, 1.0)
    at_bound = tuple(n_ for i, n_ in enumerate(free)
                     if abs(x[i] - prob.lb[i]) <= 1e-6 * prob.s[i] or abs(prob.ub[i] - x[i]) <= 1e-6 * prob.s[i])
    pairs = tuple((free[i], free[j], float(corr[i, j])) for i in range(k) for j in range(i + 1, k)
                  if math.isfinite(corr[i, j]) and abs(corr[i, j]) > CORRELATION_LIMIT)
    held = {n_: params[n_].value for n_ in all_law if n_ not in free and n_ in used}
    with np.errstate(divide="ignore"):
        loglik = n * math.log(rss / n) if rss > 0 else -math.inf
    return ComponentFit(
        kind=spec.name, laws=tuple(model_probe.groups), source=table.path or "<table>",
        method=" -> ".join(stages), names=free,
        values={n_: float(v) for n_, v in zip(free, x)},
        stderr={n_: float(v) for n_, v in zip(free, std)},
        init={n_: float(v) for n_, v in zip(free, prob.x0)},
        units={n_: params[n_].unit for n_ in free}, held=held, correlation=corr,
        n_data=n, n_free=k, cost=rss, rms_residual=math.sqrt(rss / n), residual_std=math.sqrt(s2),
        aic=loglik + 2 * k, bic=loglik + k * math.log(n), residuals=-r,
        at_bound=at_bound, not_identifiable=tuple(n_ for n_, w in zip(free, weak) if w),
        correlated_pairs=pairs, nfev=prob.nfev + extra_nfev, success=bool(res.success),
        message=str(res.message),
    )
