"""Parameters: immutable, typed, with unit, bounds and source.

A :class:`Parameter` is a frozen record (lmfit style: value, bounds, vary) that
also carries its unit and where its value comes from: a table of the papers or
``"assumed: <reason>"``.  A :class:`ParameterSet` is an immutable mapping from
dotted names (``motor.resistance``) to parameters that loads from and saves to
TOML.  Values are SI (temperatures in degC); units are metadata for checks and
display.  This module does no physics; from the model it reads only the
effect registry (for the parameters an effect declares beyond the file).

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
from ..memo import KeyedLRU

__all__ = ["Parameter", "ParameterSet", "default_parameters", "load_parameters", "convert_unit", "UNIT_CONVERSIONS",
           "search_bounds_for", "SEARCH_DECADES"]

_FIELDS = {"value", "unit", "min", "max", "source", "vary", "description", "integer", "valid"}

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
        Search bounds of the identification; ``value`` lies inside.
    vary : bool
        Default for identification: free (True) or held (False).
    description : str
        One line, with the sign convention where one applies.
    integer : bool
        The value must be a whole number (``motor.pole_pairs``).
    hard_min, hard_max : float
        Physical validity bounds: what a parameter file may hold at all
        (efficiency in (0, 1], inertia > 0, ...); default ``min`` / ``max``.
        In a file they are the ``valid`` interval, ``"(0, 1]"``.  No
        override may widen them.
    hard_min_open, hard_max_open : bool
        The physical bound itself is excluded (``(`` / ``)`` in ``valid``).

    Notes
    -----
    ``min`` / ``max`` are the identification's search bounds (overridable
    per fit, ``Identifier(bounds=...)``), inside the physical ones; they
    always contain the value.  A physically valid value outside them is
    accepted: the search bounds then move with it (:func:`search_bounds_for`),
    since they described another rig.
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
    hard_min_open: bool = False
    hard_max_open: bool = False

    def __post_init__(self):
        for key in ("value", "min", "max", "hard_min", "hard_max"):
            v = getattr(self, key)
            if not _is_number(v):
                raise ParameterError(self.name, f"{key} {v!r} is not a number ({type(v).__name__})")
            object.__setattr__(self, key, float(v))
        for key in ("unit", "source", "description"):
            if not isinstance(getattr(self, key), str):
                raise ParameterError(self.name, f"{key} {getattr(self, key)!r} must be a string")
        for key in ("vary", "integer", "hard_min_open", "hard_max_open"):
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
        if self.hard_min > self.hard_max:
            raise ParameterError(self.name, f"physical bounds {self.valid} are empty")
        if not (self.physically_valid(value)):
            raise ParameterError(self.name, f"value {value:g} {self.unit} outside its bounds: physically valid "
                                            f"values are {self.valid} {self.unit}")
        if self.min < self.hard_min or self.max > self.hard_max:
            raise ParameterError(self.name, f"search bounds [{self.min:g}, {self.max:g}] would widen the physical "
                                            f"bounds {self.valid} {self.unit} (an override may only narrow them)")
        if not (self.min <= value <= self.max):
            raise ParameterError(
                self.name, f"value {value:g} {self.unit} outside its search bounds [{self.min:g}, {self.max:g}]"
            )
        if self.integer and value != round(value):
            raise ParameterError(self.name, f"value {value:g} must be a whole number")
        src = str(self.source).strip()
        if not src:
            raise ParameterError(self.name, "has no source (give a paper table or 'assumed: <reason>')")
        if src.lower().startswith("assumed") and len(src.split(":", 1)) < 2:
            raise ParameterError(self.name, "an assumed value needs a reason: 'assumed: <reason>'")

    @property
    def valid(self) -> str:
        """The physical validity interval as written in a file, ``"(0, 1]"``."""
        return _interval(self.hard_min, self.hard_max, self.hard_min_open, self.hard_max_open)

    def physically_valid(self, value: float) -> bool:
        """True when ``value`` lies in the physical interval (open ends excluded)."""
        lo_ok = value > self.hard_min if self.hard_min_open else value >= self.hard_min
        hi_ok = value < self.hard_max if self.hard_max_open else value <= self.hard_max
        return bool(lo_ok and hi_ok)

    def search_interval(self) -> tuple[float, float]:
        """The search bounds as a closed interval an optimiser may reach (an open physical end kept just inside)."""
        lo, hi = self.min, self.max
        if self.hard_min_open and lo <= self.hard_min:
            lo = self.hard_min + 1e-6 * (self.value - self.hard_min)
        if self.hard_max_open and hi >= self.hard_max:
            hi = self.hard_max - 1e-6 * (self.hard_max - self.value)
        return lo, hi

    def with_value(self, value: float) -> "Parameter":
        """Return a copy with another value.

        The value must be physically valid (else :class:`ParameterError`
        naming the parameter); outside the search bounds, they move with it
        (:func:`search_bounds_for`).
        """
        if _is_number(value) and math.isfinite(float(value)) and not (self.min <= value <= self.max) \
                and self.physically_valid(float(value)):
            lo, hi = search_bounds_for(self, float(value))
            return _dc_replace(self, value=value, min=lo, max=hi)
        return _dc_replace(self, value=value)


#: Decades either side of a value that the search bounds span when they are re-derived from it.
SEARCH_DECADES = 3.0


def _fmt(x: float) -> str:
    return "inf" if x == math.inf else "-inf" if x == -math.inf else f"{x:g}"


def search_bounds_for(par: Parameter, value: float) -> tuple[float, float]:
    """Search bounds around a physically valid ``value`` that lies outside ``par``'s search bounds.

    The old search bounds described another rig (the papers' actuator).  A
    positive quantity (physical lower bound >= 0, value > 0) gets
    ``value / 10**3 .. value * 10**3``; anything else the physical interval.
    Both are clipped to the physical interval (an open end is kept just
    inside, so that an identification never reaches it).
    """
    if par.hard_min >= 0.0 and value > 0.0:
        lo, hi = value * 10.0 ** -SEARCH_DECADES, value * 10.0 ** SEARCH_DECADES
    else:
        lo, hi = par.hard_min, par.hard_max
    lo, hi = max(lo, par.hard_min), min(hi, par.hard_max)
    if par.hard_min_open and lo <= par.hard_min:
        lo = min(value, par.hard_min + 1e-9 * max(abs(value), 1e-300)) if par.hard_min != 0 else value * 1e-9
    if par.hard_max_open and hi >= par.hard_max:
        hi = max(value, par.hard_max - 1e-9 * abs(par.hard_max))
    return min(lo, value), max(hi, value)


def _interval(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    return ("(" if lo_open else "[") + f"{_fmt(lo)}, {_fmt(hi)}" + (")" if hi_open else "]")


def parse_valid(name: str, text, source_name: str) -> tuple[float, float, bool, bool]:
    """``"(0, 1]"`` -> (0.0, 1.0, True, False); ParameterError naming the parameter otherwise."""
    import re

    m = re.fullmatch(r"\s*([\[(])\s*([^,\s]+)\s*,\s*([^,\s]+)\s*([\])])\s*", text) if isinstance(text, str) else None
    if m is None:
        raise ParameterError(name, f"valid {text!r} in {source_name} is not an interval like \"(0, 1]\" or "
                                   "\"[0, inf)\"")
    try:
        lo, hi = float(m.group(2)), float(m.group(3))
    except ValueError:
        raise ParameterError(name, f"valid {text!r} in {source_name}: bounds must be numbers or inf") from None
    if math.isnan(lo) or math.isnan(hi) or lo > hi:
        raise ParameterError(name, f"valid {text!r} in {source_name} is an empty interval")
    return lo, hi, m.group(1) == "(", m.group(4) == ")"


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
            entry["valid"] = p.valid
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
                    "hard_min_open": old.hard_min_open, "hard_max_open": old.hard_max_open,
                }
                if "valid" in entry:
                    lo, hi, lo_open, hi_open = parse_valid(name, entry.pop("valid"), source_name)
                    if not ((lo > old.hard_min or (lo == old.hard_min and (lo_open or not old.hard_min_open)))
                            and (hi < old.hard_max or (hi == old.hard_max and (hi_open or not old.hard_max_open)))):
                        raise ParameterError(name, f"valid {_interval(lo, hi, lo_open, hi_open)} in {source_name} "
                                                   f"would widen the physical bounds {old.valid} {old.unit} "
                                                   "(an override may only narrow them)")
                    merged.update(hard_min=lo, hard_max=hi, hard_min_open=lo_open, hard_max_open=hi_open)
                    merged["min"], merged["max"] = max(old.min, lo), min(old.max, hi)
                merged.update(entry)
                if "value" in entry and "min" not in entry and "max" not in entry and _is_number(entry["value"]) \
                        and merged["min"] <= old.value <= merged["max"]:
                    # a new value moves the search bounds as Parameter.with_value does (physically valid, outside them)
                    moved = Parameter(name=name, **{**merged, "value": old.value}).with_value(float(entry["value"]))
                    merged["min"], merged["max"] = moved.min, moved.max
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
            entry = dict(entry)
            if "valid" in entry:
                lo, hi, lo_open, hi_open = parse_valid(name, entry.pop("valid"), source_name)
                entry.update(hard_min=lo, hard_max=hi, hard_min_open=lo_open, hard_max_open=hi_open)
                entry.setdefault("min", lo)
                entry.setdefault("max", hi)
            params.append(Parameter(name=name, **entry))
        if base is None:
            return cls(tuple(params))
        return base.replace_parameters({p.name: p for p in params})


def load_parameters(path, *, base: ParameterSet | None = None) -> ParameterSet:
    """Load a parameter TOML file, or several merged in order.

    Parameters
    ----------
    path : path or sequence of paths
        TOML file.  A full set, or (with ``base``) overrides of some entries.
        Several files: each overrides the result of the ones before (the
        first one over ``base``), so a rig description followed by an
        identified ``parameters.toml`` replays the identified model.
    base : ParameterSet, optional
        Set that the file overrides; ``default_parameters()`` is typical.

    Raises
    ------
    ParameterError
        Unreadable file, unknown parameter, value outside bounds; the message
        names the file and the parameter.
    """
    if isinstance(path, (list, tuple)):
        if not path:
            raise ParameterError("<params>", "no parameter file given")
        out = base
        for one in path:
            out = load_parameters(one, base=out)
        return out
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ParameterError(str(path), f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise ParameterError(str(path), f"not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    return ParameterSet.from_toml(text, source_name=str(path), base=base)


def default_parameters() -> ParameterSet:
    """The embedded default actuator (the papers' values, assumed ones marked).

    Parameters that registered effects bring beyond the file
    (``Effect.parameter_defaults``) are appended, so an effect registered
    outside the package is simulated, identified and overridden like the
    library's own.
    """
    from .effect import EFFECTS  # the registry imports nothing of the model

    # Parsed once per state of the registry (the set is immutable; the TOML parse is most of the cost): the key
    # holds the identity of each registered Effect (kept alive by the entry), so registering or removing one,
    # or registering one again under its name, gives a new set.
    effects = tuple(EFFECTS.values())
    return _DEFAULTS.get(tuple(map(id, effects)), lambda: _default_parameters(effects), keep=effects)


def _default_parameters(effects) -> ParameterSet:
    text = resources.files("thsa_control.model").joinpath("default_actuator.toml").read_text(encoding="utf-8")
    base = ParameterSet.from_toml(text, source_name="default_actuator.toml")
    extra = {p.name: p for e in effects for p in e.parameter_defaults if p.name not in base}
    return ParameterSet(base.parameters + tuple(extra.values())) if extra else base


#: default_parameters' memo: the registry's Effect objects (their identities) -> ParameterSet.
_DEFAULTS = KeyedLRU(8)
