"""Scenarios written in TOML: a new (fault) case without code.

A scenario file holds the fields of :class:`~thsa_control.sim.scenarios.Scenario`
in SI units (times [s], speeds [m/s], forces [N], compressive positive), an
optional ``base`` (a named scenario whose fields the file overrides), an
optional ``[monitors]`` table (its presence runs the monitors in the loop;
keys override :class:`~thsa_control.faults.settings.MonitorSettings`) and
``[[faults]]`` tables (fields of :class:`~thsa_control.faults.events.FaultEvent`)::

    name = "jam_at_2s_cold"
    base = "jam"                      # start from the named scenario
    temperature = -30.0
    speed_target = [[0.0, 0.0], [1.0, 0.012]]
    required_effects = ["loadpath_compliance", "drivetrain_compliance", "torque_limiter", "surface_jam", "motor_brakes"]

    [monitors]
    discrepancy_threshold = 0.4       # rad at the screw

    [[faults]]
    kind = "surface_jam"
    time = 2.0

    [[faults]]
    kind = "sensor"
    sensor = "rvdt"
    mode = "noise"
    value = 0.002                     # rad
    time = 1.0
    end = 1.5

``thsa simulate --scenario FILE.toml`` and ``get_scenario("FILE.toml")`` read it.
Every error names the file and the field.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import fields, replace
from pathlib import Path

from ..errors import ScenarioError
from .events import FaultEvent
from .settings import MonitorSettings

__all__ = ["load_scenario_file", "scenario_from_dict", "scenario_to_dict"]

_BREAKPOINTS = ("speed_target", "load", "primary_enable", "standby_enable", "position_cmd")


def _breakpoints(where: str, key: str, value):
    if not isinstance(value, list) or not all(isinstance(p, list) and len(p) == 2 for p in value):
        raise ScenarioError(f"{where}: {key} must be a list of [time, value] pairs")
    try:
        return tuple((float(a), float(b)) for a, b in value)
    except (TypeError, ValueError):
        raise ScenarioError(f"{where}: {key} has a non-numeric breakpoint") from None


def scenario_from_dict(data: dict, *, where: str = "scenario"):
    """A :class:`Scenario` from a parsed TOML table (see the module docstring)."""
    from ..sim.scenarios import SCENARIOS, Scenario  # here: sim.scenarios imports this package's events

    data = dict(data)
    known = {f.name for f in fields(Scenario)} | {"base"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ScenarioError(f"{where}: unknown field(s) {unknown}; fields are {', '.join(sorted(known))}")
    base_name = data.pop("base", None)
    if base_name is not None and base_name not in SCENARIOS:
        raise ScenarioError(f"{where}: base {base_name!r} is not a named scenario; scenarios are {', '.join(SCENARIOS)}")
    kw = {}
    for key, value in data.items():
        if key in _BREAKPOINTS:
            kw[key] = _breakpoints(where, key, value)
        elif key == "faults":
            if not isinstance(value, list):
                raise ScenarioError(f"{where}: faults must be an array of tables ([[faults]])")
            evs = []
            for i, ev in enumerate(value):
                extra = sorted(set(ev) - {f.name for f in fields(FaultEvent)})
                if extra:
                    raise ScenarioError(f"{where}: faults[{i}] has unknown field(s) {extra}")
                try:
                    evs.append(FaultEvent(**{k: (math.inf if k == "end" and v == "inf" else v) for k, v in ev.items()}))
                except TypeError as exc:
                    raise ScenarioError(f"{where}: faults[{i}]: {exc}") from None
                except ScenarioError as exc:
                    raise ScenarioError(f"{where}: faults[{i}]: {exc}") from None
            kw["faults"] = tuple(evs)
        elif key == "monitors":
            if not isinstance(value, dict):
                raise ScenarioError(f"{where}: monitors must be a table ([monitors])")
            names = {f.name for f in fields(MonitorSettings)}
            extra = sorted(set(value) - names)
            if extra:
                raise ScenarioError(f"{where}: monitors has unknown field(s) {extra}; fields are {', '.join(sorted(names))}")
            m = MonitorSettings(**value)
            try:
                m.validate()
            except ValueError as exc:
                raise ScenarioError(f"{where}: {exc}") from None
            kw["monitors"] = m
        elif key == "required_effects":
            kw[key] = tuple(str(e) for e in value)
        else:
            kw[key] = value
    try:
        if base_name is not None:
            return replace(SCENARIOS[base_name], **kw)
        missing = [k for k in ("name", "description", "duration", "speed_target", "accel_limit", "load") if k not in kw]
        if missing:
            raise ScenarioError(f"{where}: missing field(s) {missing} (or give a base scenario)")
        return Scenario(**kw)
    except ScenarioError as exc:
        raise ScenarioError(f"{where}: {exc}") from None
    except TypeError as exc:
        raise ScenarioError(f"{where}: {exc}") from None


def load_scenario_file(path) -> "Scenario":  # noqa: F821 - Scenario imported lazily
    """Read a scenario TOML file (see the module docstring).

    Raises
    ------
    ScenarioError
        Unreadable file, bad TOML, unknown or malformed field (named).
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ScenarioError(f"scenario file {str(path)!r} not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"scenario file {str(path)!r}: {exc}") from None
    if "base" not in data:
        data.setdefault("name", path.stem)
    return scenario_from_dict(data, where=f"scenario file {str(path)!r}")


def scenario_to_dict(scenario) -> dict:
    """The TOML-ready table of a :class:`Scenario` that :func:`scenario_from_dict` reads back to an equal one
    (``inf`` as the string ``"inf"`` where TOML writers would refuse it)."""
    out = {}
    for f in fields(scenario):
        value = getattr(scenario, f.name)
        if f.name in _BREAKPOINTS:
            if value is not None:
                out[f.name] = [[float(a), float(b)] for a, b in value]
        elif f.name == "faults":
            if value:
                out["faults"] = [{g.name: ("inf" if g.name == "end" and math.isinf(getattr(ev, g.name))
                                           else getattr(ev, g.name)) for g in fields(ev)} for ev in value]
        elif f.name == "monitors":
            if value is not None:
                out["monitors"] = {g.name: getattr(value, g.name) for g in fields(value)}
        elif f.name == "required_effects":
            out[f.name] = list(value)
        elif f.name == "jerk_limit" and math.isinf(value):
            continue  # the default
        else:
            out[f.name] = value
    return out
