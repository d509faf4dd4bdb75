"""Component-rig tables: read, validate, write and generate (re-exported by :mod:`.component_id`).

A *component table* is a small CSV written by a component rig (or by
:func:`generate_component_table`), one header line of column names preceded by
``#`` comment lines that carry its provenance, as in the NIST StRD files.
:mod:`thsa_control.fit.component_id` fits the effect library's component laws
to them.  Never imports matplotlib.

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
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from linearization.buffered import call_dense
from thsa_control.errors import ModelError, ParameterError, RigDataError
from thsa_control.model.laws import LAWS
from thsa_control.model.params import ParameterSet, default_parameters
from thsa_control.data.atomic import atomic_write_file
from thsa_control.data.units import mm_to_m, rpm_to_rad_s

__all__ = [
    "ComponentKind",
    "KINDS",
    "DEFAULT_GRIDS",
    "ComponentTable",
    "read_component_table",
    "write_component_table",
    "generate_component_table",
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
    return atomic_write_file(path, lambda fh: fh.write(buf.getvalue()), text=True)


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
        self.value = ca.Function("component_model", [P], [ca.densify(out)])
        self.with_jacobian = ca.Function("component_model_jac", [P], [ca.densify(out), ca.densify(ca.jacobian(out, P))])
        self.n = table.n_rows

    def evaluate(self, p: np.ndarray) -> Float1D:
        return call_dense(self.value, p)[0].reshape(-1)

    def jacobian(self, p: np.ndarray) -> tuple[Float1D, np.ndarray]:
        out, jac = call_dense(self.with_jacobian, p)
        return out.reshape(-1), jac

    def parameters_used(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(n for law in self.groups for n in LAWS[law].parameters))
