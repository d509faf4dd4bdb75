"""MATLAB ``.mat`` exports (``scipy.io.savemat``, MAT 5): simulation results and linear models.

What MATLAB users get with ``load FILE.mat`` (SI units, as the API and JSON;
every unit is written next to its value):

* a **linear model** (``thsa linearize ... --save model.mat``, or
  :func:`linear_model_to_mat`): ``A``, ``B``, ``C``, ``D`` (double), the signal
  names ``states``, ``inputs``, ``outputs`` (cell arrays of char) with their
  units ``state_units``, ``input_units``, ``output_units``, ``Ts`` (0 for a
  continuous model, the sample period of a discrete one), and the operating
  point as a struct ``op`` (``x``, ``u``, ``y`` and their names; for a
  workbench condition also ``nut_speed_m_s``, ``load_force_N``,
  ``temperature_C``, ``active``).  In MATLAB:
  ``sys = ss(A, B, C, D, Ts, 'StateName', states, 'InputName', inputs, 'OutputName', outputs)``.
* a **simulation result** (``thsa simulate ... --format mat``, or
  :func:`simulation_to_mat`): ``time`` [s] (column), a struct ``signals`` with
  one column per signal and a struct ``units`` with its unit, plus
  ``scenario``, ``level``, ``effects``, ``temperature_C``.

:func:`read_mat` reads either back (tests round-trip through it).  Writing is
atomic (a temporary file renamed), so a failure leaves no half-written file.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .atomic import atomic_write_file

__all__ = ["MAT_FORMAT", "plant_units", "linear_model_to_mat", "statespace_to_mat", "simulation_to_mat", "write_mat", "read_mat"]

#: Tag written in every file (variable ``format``).
MAT_FORMAT = "thsa-mat/1"


def _cell(names) -> np.ndarray:
    """A MATLAB cell array of char (1 x n)."""
    out = np.empty((1, len(names)), dtype=object)
    for k, n in enumerate(names):
        out[0, k] = str(n)
    return out


def _field(name: str) -> str:
    """A valid MATLAB struct field name (letters, digits, underscores; starts with a letter; <= 63 chars)."""
    f = re.sub(r"\W", "_", name)
    if not f or not f[0].isalpha():
        f = "s_" + f
    return f[:63]


def _units(names, units: Mapping[str, str] | None) -> np.ndarray:
    return _cell([(units or {}).get(n, "") for n in names])


def statespace_to_mat(sys, *, units: Mapping[str, str] | None = None, condition=None) -> dict:
    """A python-control ``StateSpace`` (e.g. :func:`thsa_control.open_loop`) as MAT variables.

    ``units`` maps signal names to units; ``condition`` (an ``OperatingCondition``) is stored as ``op``.
    """
    states = list(sys.state_labels)
    inputs, outputs = list(sys.input_labels), list(sys.output_labels)
    data = {"format": MAT_FORMAT, "A": np.asarray(sys.A, float), "B": np.asarray(sys.B, float),
            "C": np.asarray(sys.C, float), "D": np.asarray(sys.D, float),
            "Ts": float(sys.dt) if sys.dt not in (None, True) else 0.0,
            "states": _cell(states), "inputs": _cell(inputs), "outputs": _cell(outputs),
            "state_units": _units(states, units), "input_units": _units(inputs, units),
            "output_units": _units(outputs, units), "name": str(sys.name or "")}
    if condition is not None:
        data["op"] = _condition_struct(condition)
    return data


def _condition_struct(c) -> dict:
    return {"nut_speed_m_s": float(c.nut_speed), "load_force_N": float(c.load_force),
            "temperature_C": float(c.temperature), "active": str(getattr(c, "active", "primary")),
            "label": c.label()}


def linear_model_to_mat(model, *, units: Mapping[str, str] | None = None, condition=None) -> dict:
    """A :class:`linearization.LinearModel` (continuous, ``Ts = 0``) as MAT variables, operating point included."""
    data = {"format": MAT_FORMAT, "A": np.asarray(model.A, float), "B": np.asarray(model.B, float),
            "C": np.asarray(model.C, float), "D": np.asarray(model.D, float), "Ts": 0.0,
            "states": _cell(model.states), "inputs": _cell(model.inputs), "outputs": _cell(model.outputs),
            "state_units": _units(model.states, units), "input_units": _units(model.inputs, units),
            "output_units": _units(model.outputs, units), "valid": bool(model.valid),
            "invalid_reasons": _cell(model.invalid_reasons),
            "excluded_states": _cell(model.excluded_states)}
    op = model.operating_point
    opd: dict = {}
    if op is not None:
        opd = {"x": np.asarray(op.x, float).reshape(-1, 1), "u": np.asarray(op.u, float).reshape(-1, 1),
               "y": np.asarray(op.y, float).reshape(-1, 1), "x_names": _cell(op.states),
               "u_names": _cell(op.inputs), "y_names": _cell(op.outputs),
               "parameters": np.asarray(op.p, float).reshape(-1, 1), "parameter_names": _cell(op.parameters)}
    if condition is not None:
        opd.update(_condition_struct(condition))
    if opd:
        data["op"] = opd
    return data


def plant_units(plant) -> dict[str, str]:
    """Units of a plant's states and outputs by name (for :func:`linear_model_to_mat`)."""
    units = {s.name: s.unit for s in plant.states}
    units.update(plant.output_units)
    return units


def simulation_to_mat(result, *, level: str = "", temperature_C: float | None = None) -> dict:
    """A :class:`thsa_control.sim.simulate.SimulationResult` as MAT variables (SI)."""
    signals, units, names = {}, {}, {}
    for n in result.names:
        f = _field(n)
        signals[f] = np.asarray(result[n], float).reshape(-1, 1)
        units[f] = str(result.units.get(n, ""))
        names[f] = n
    return {"format": MAT_FORMAT, "time": np.asarray(result.time, float).reshape(-1, 1), "signals": signals,
            "units": units, "signal_names": names, "scenario": str(result.name),
            "level": str(level), "effects": _cell(result.effects),
            "temperature_C": float("nan") if temperature_C is None else float(temperature_C)}


def write_mat(path: str | os.PathLike, data: Mapping) -> Path:
    """Write ``data`` (variable name -> value) to ``path`` (``.mat`` appended when missing), atomically."""
    from scipy.io import savemat

    target = Path(path)
    if target.suffix != ".mat":
        target = target.with_name(target.name + ".mat")
    target.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_file(target, lambda fh: savemat(fh, dict(data), format="5", long_field_names=True,
                                                         do_compression=True, oned_as="column"))


def read_mat(path: str | os.PathLike) -> dict:
    """Read a file of :func:`write_mat` back: arrays, ``list`` of str for cells, ``dict`` for structs."""
    from scipy.io import loadmat

    raw = loadmat(os.fspath(path), squeeze_me=True, simplify_cells=True)
    return {k: _plain(v, k) for k, v in raw.items() if not k.startswith("__")}


#: Variables and fields written as cell arrays of names (read back as lists, also with one element).
_CELLS = {"states", "inputs", "outputs", "state_units", "input_units", "output_units", "effects", "invalid_reasons",
          "excluded_states", "x_names", "u_names", "y_names", "parameter_names"}


def _plain(v, key: str = ""):
    if key in _CELLS and isinstance(v, str):
        return [v]
    if isinstance(v, dict):
        return {k: _plain(x, k) for k, x in v.items()}
    if isinstance(v, np.ndarray) and v.dtype == object:
        return [str(x) for x in v.ravel()]
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v
