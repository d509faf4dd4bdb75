"""Parameters: immutable, typed, with unit, bounds and source.

A :class:`Parameter` is a frozen record (lmfit style: value, bounds, vary) that
also carries its unit and where its value comes from: a table of the papers or
``"assumed: <reason>"``.  A :class:`ParameterSet` is an immutable mapping from
dotted names (``motor.resistance``) to parameters that loads from and saves to
TOML.  Values are SI (temperatures in degC); units are metadata for checks and
display.  This module does no physics and imports nothing from the model.

Examples
--------
>>> from thsa_control.model.params import default_parameters
>>> p = default_parameters()
>>> p["gear.ratio"].value
65.61
>>> p2 = p.replace({"motor.resistance": 1.3})
>>> (p["motor.resistance"].value, p2["motor.resistance"].value)
(1.23, 1.3)
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace as _dc_replace
from importlib import resources
from pathlib import Path

import numpy as np
import tomli_w

from ..errors import ParameterError

__all__ = ["Parameter", "ParameterSet", "default_parameters", "load_parameters", "convert_unit", "UNIT_CONVERSIONS"]

_FIELDS = {"value", "unit", "min", "max", "source", "vary", "description", "integer"}

#: Units a parameter file may use instead of the parameter's own unit: unit -> (unit, factor),
#: value_in_unit * factor = value in the parameter's unit.  Anything else is refused.
UNIT_CONVERSIONS: dict[str, tuple[str, float]] = {
    "mOhm": ("Ohm", 1e-3), "kOhm": ("Ohm", 1e3),
    "mH": ("H", 1e-3), "uH": ("H", 1e-6),
    "mWb": ("Wb", 1e-3),
    "mA": ("A", 1e-3), "kV": ("V", 1e3), "mV": ("V", 1e-3),
    "mN m": ("N m", 1e-3), "N mm": ("N m", 1e-3),
    "kN": ("N", 1e3),
    "mm": ("m", 1e-3), "um": ("m", 1e-6),
    "g": ("kg", 1e-3), "t": ("kg", 1e3),
    "g cm^2": ("kg m^2", 1e-7), "kg cm^2": ("kg m^2", 1e-4), "kg mm^2": ("kg m^2", 1e-6),
    "N/mm": ("N/m", 1e3), "kN/mm": ("N/m", 1e6), "kN/m": ("N/m", 1e3), "N s/mm": ("N s/m", 1e3),
    "deg": ("rad", math.pi / 180.0),
    "rpm": ("rad/s", math.pi / 30.0),
    "ms": ("s", 1e-3), "us": ("s", 1e-6),
    "%": ("-", 1e-2),
}


def _is_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def convert_unit(name: str, value, unit: str, target: str, source_name: str = "<string>") -> float:
    """``value`` given in ``unit`` -> the parameter's ``target`` unit, or ParameterError.

    Examples
    --------
    >>> convert_unit("motor.resistance", 1230.0, "mOhm", "Ohm")
    1.23
    """
    if unit == target:
        return value
    conv = UNIT_CONVERSIONS.get(unit)
    if conv is None or conv[0] != target:
        known = sorted(u for u, (t, _) in UNIT_CONVERSIONS.items() if t == target)
        raise ParameterError(name, f"unit {unit!r} in {source_name} is not {target!r} and cannot be converted to it"
                                   + (f" (convertible: {', '.join(known)})" if known else ""))
    return float(value) * conv[1]


@dataclass(frozen=True)
class Parameter:
    """One physical parameter.

    Parameters
    ----------
    name : str
        Dotted name, ``group.quantity``.
    value : float
        Value in SI units (temperatures in degC).
    unit : str
        Unit of ``value`` (display and checks only).
    source : str
        A table of the papers, or ``"assumed: <reason>"``.
    min, max : float
        Physical bounds; ``value`` must lie inside.
    vary : bool
        Default for identification: free (True) or held (False).
    description : str
        One line, with the sign convention where one applies.
    integer : bool
        The value must be a whole number (``motor.pole_pairs``).
    hard_min, hard_max : float
        Physical bounds that no override may move (efficiency <= 1, masses
        >= 0, ...); default ``min`` / ``max``.  ``min`` / ``max`` are the
        adjustable (search) bounds and must lie inside them.
    """

    name: str
    value: float
    unit: str
    source: str
    min: float = -math.inf
    max: float = math.inf
    vary: bool = False
    description: str = ""
    integer: bool = False
    hard_min: float = math.nan
    hard_max: float = math.nan

    def __post_init__(self):
        for key in ("value", "min", "max", "hard_min", "hard_max"):
            v = getattr(self, key)
            if not _is_number(v):
                raise ParameterError(self.name, f"{key} {v!r} is not a number ({type(v).__name__})")
            object.__setattr__(self, key, float(v))
        for key in ("unit", "source", "description"):
            if not isinstance(getattr(self, key), str):
                raise ParameterError(self.name, f"{key} {getattr(self, key)!r} must be a string")
        for key in ("vary", "integer"):
            if not isinstance(getattr(self, key), (bool, np.bool_)):
                raise ParameterError(self.name, f"{key} {getattr(self, key)!r} must be true or false")
            object.__setattr__(self, key, bool(getattr(self, key)))
        value = self.value
        if math.isnan(self.hard_min):
            object.__setattr__(self, "hard_min", self.min)
        if math.isnan(self.hard_max):
            object.__setattr__(self, "hard_max", self.max)
        if not math.isfinite(value):
            raise ParameterError(self.name, f"value {value!r} is not finite")
        if math.isnan(self.min) or math.isnan(self.max):
            raise ParameterError(self.name, "min/max must not be NaN")
        if self.min > self.max:
            raise ParameterError(self.name, f"min {self.min} > max {self.max}")
        if self.min < self.hard_min or self.max > self.hard_max:
            raise ParameterError(self.name, f"bounds [{self.min:g}, {self.max:g}] would widen the physical bounds "
                                            f"[{self.hard_min:g}, {self.hard_max:g}] {self.unit} (an override may "
                                            "only narrow them)")
        if not (self.min <= value <= self.max):
            raise ParameterError(
                self.name, f"value {value:g} {self.unit} outside its bounds [{self.min:g}, {self.max:g}]"
            )
        if self.integer and value != round(value):
            raise ParameterError(self.name, f"value {value:g} must be a whole number")
        src = str(self.source).strip()
        if not src:
            raise ParameterError(self.name, "has no source (give a paper table or 'assumed: <reason>')")
        if src.lower().startswith("assumed") and len(src.split(":", 1)) < 2:
            raise ParameterError(self.name, "an assumed value needs a reason: 'assumed: <reason>'")

    def with_value(self, value: float) -> "Parameter":
        """Return a copy with another value (bounds are checked)."""
        return _dc_replace(self, value=value)


@dataclass(frozen=True)
class ParameterSet(Mapping[str, Parameter]):
    """Immutable, ordered mapping ``name -> Parameter``.

    Parameters
    ----------
    parameters : tuple of Parameter
        In a fixed order; this order defines :meth:`vector`.
    """

    parameters: tuple[Parameter, ...]
    _index: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        index = {}
        for i, par in enumerate(self.parameters):
            if par.name in index:
                raise ParameterError(par.name, "defined twice")
            index[par.name] = i
        object.__setattr__(self, "_index", index)

    # Mapping protocol
    def __getitem__(self, name: str) -> Parameter:
        try:
            return self.parameters[self._index[name]]
        except KeyError:
            raise ParameterError(name, f"unknown; known parameters: {', '.join(self._index)}") from None

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __iter__(self) -> Iterator[str]:
        return iter(self._index)

    def __len__(self) -> int:
        return len(self.parameters)

    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names in vector order."""
        return tuple(p.name for p in self.parameters)

    def value(self, name: str) -> float:
        """Value of ``name`` [SI]."""
        return self[name].value

    def vector(self) -> np.ndarray:
        """All values in :attr:`names` order (the model's ``p`` vector)."""
        return np.array([p.value for p in self.parameters], dtype=float)

    def replace(self, values: Mapping[str, float] | None = None, **kw) -> "ParameterSet":
        """Return a new set with some values replaced (bounds checked).

        ``values`` uses dotted names; keyword arguments use ``__`` for the dot
        (``motor__resistance=1.3``).
        """
        updates = dict(values or {})
        updates.update({k.replace("__", "."): v for k, v in kw.items()})
        for name in updates:
            self[name]  # raises for unknown names
        return ParameterSet(
            tuple(p.with_value(updates[p.name]) if p.name in updates else p for p in self.parameters)
        )

    def replace_parameters(self, new: Mapping[str, Parameter]) -> "ParameterSet":
        """Return a new set with whole parameters (value, bounds, source) replaced."""
        for name in new:
            self[name]
        return ParameterSet(tuple(new.get(p.name, p) for p in self.parameters))

    # TOML
    def to_toml(self) -> str:
        """Serialise to TOML: one inline table per parameter, grouped by prefix."""
        doc: dict = {}
        for p in self.parameters:
            group, _, key = p.name.rpartition(".")
            entry = {"value": p.value, "unit": p.unit, "source": p.source}
            if math.isfinite(p.min):
                entry["min"] = p.min
            if math.isfinite(p.max):
                entry["max"] = p.max
            if p.vary:
                entry["vary"] = True
            if p.integer:
                entry["integer"] = True
            if p.description:
                entry["description"] = p.description
            target = doc
            for part in group.split(".") if group else []:
                target = target.setdefault(part, {})
            target[key] = entry
        return tomli_w.dumps(doc)

    def save(self, path: str | Path) -> Path:
        """Write the set to ``path`` as TOML (atomically)."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(self.to_toml(), encoding="utf-8")
        tmp.replace(path)
        return path

    @classmethod
    def from_toml(cls, text: str, *, source_name: str = "<string>", base: "ParameterSet | None" = None) -> "ParameterSet":
        """Parse a TOML document.

        With ``base``, the document may give only some parameters, either as
        full tables or as bare numbers (``resistance = 1.3``), which replace
        the value of the base's parameter and keep its unit, bounds and source
        unless given.  Unknown names raise :class:`ParameterError`.
        """
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ParameterError(source_name, f"not valid TOML: {exc}") from None
        except RecursionError:
            raise ParameterError(source_name, "not valid TOML: nested too deeply") from None
        flat: dict[str, object] = {}

        def walk(prefix: str, table: dict):
            for key, val in table.items():
                name = f"{prefix}.{key}" if prefix else key
                if isinstance(val, dict) and not ("value" in val and set(val) <= _FIELDS):
                    walk(name, val)
                else:
                    flat[name] = val

        walk("", doc)
        params = []
        for name, entry in flat.items():
            if base is not None and name in base:
                old = base[name]
                if not isinstance(entry, dict):
                    entry = {"value": entry}
                unknown = set(entry) - _FIELDS
                if unknown:
                    raise ParameterError(name, f"unknown field(s) {sorted(unknown)} in {source_name}")
                entry = dict(entry)
                if "integer" in entry and entry["integer"] != old.integer:
                    raise ParameterError(name, f"'integer' cannot be changed by an override in {source_name}")
                if "unit" in entry:
                    unit = entry.pop("unit")
                    if not isinstance(unit, str):
                        raise ParameterError(name, f"unit {unit!r} in {source_name} must be a string")
                    for key in ("value", "min", "max"):
                        if key in entry:
                            if not _is_number(entry[key]):
                                raise ParameterError(name, f"{key} {entry[key]!r} in {source_name} is not a number")
                            entry[key] = convert_unit(name, entry[key], unit.strip(), old.unit, source_name)
                merged = {
                    "value": old.value, "unit": old.unit, "source": old.source, "min": old.min,
                    "max": old.max, "vary": old.vary, "description": old.description, "integer": old.integer,
                    "hard_min": old.hard_min, "hard_max": old.hard_max,
                }
                merged.update(entry)
                params.append(Parameter(name=name, **merged))
                continue
            if base is not None:
                raise ParameterError(name, f"unknown parameter in {source_name}")
            if not isinstance(entry, dict) or "value" not in entry:
                raise ParameterError(name, f"needs a table with value, unit and source in {source_name}")
            unknown = set(entry) - _FIELDS
            if unknown:
                raise ParameterError(name, f"unknown field(s) {sorted(unknown)} in {source_name}")
            for req in ("unit", "source"):
                if req not in entry:
                    raise ParameterError(name, f"missing '{req}' in {source_name}")
            params.append(Parameter(name=name, **entry))
        if base is None:
            return cls(tuple(params))
        return base.replace_parameters({p.name: p for p in params})


def load_parameters(path: str | Path, *, base: ParameterSet | None = None) -> ParameterSet:
    """Load a parameter TOML file.

    Parameters
    ----------
    path : path
        TOML file.  A full set, or (with ``base``) overrides of some entries.
    base : ParameterSet, optional
        Set that the file overrides; ``default_parameters()`` is typical.

    Raises
    ------
    ParameterError
        Unreadable file, unknown parameter, value outside bounds; the message
        names the file and the parameter.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ParameterError(str(path), f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise ParameterError(str(path), f"not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    return ParameterSet.from_toml(text, source_name=str(path), base=base)


def default_parameters() -> ParameterSet:
    """The embedded default actuator (the papers' values, assumed ones marked)."""
    text = resources.files("thsa_control.model").joinpath("default_actuator.toml").read_text(encoding="utf-8")
    return ParameterSet.from_toml(text, source_name="default_actuator.toml")
