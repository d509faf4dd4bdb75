"""Named test scenarios of the papers, as reusable input definitions.

A scenario gives the target nut speed (piecewise constant; the controller's
shaper turns it into trapezoids with the scenario's acceleration limit), or a
position command, the load force (piecewise linear, FORMAT.md sign:
compressive positive, i.e. it opposes extension), the temperature and the
channel enables.  Timings the papers do not state exactly are chosen here and
written in each description.

Scenario files
--------------
A new (fault) case without code: a scenario file holds the fields of :class:`Scenario`
in SI units (times [s], speeds [m/s], forces [N], compressive positive), an
optional ``base`` (a named scenario whose fields the file overrides), an
optional ``[monitors]`` table (its presence runs the monitors in the loop;
keys override :class:`~thsa_control.sim.monitor_settings.MonitorSettings`) and
``[[faults]]`` tables (fields of :class:`~thsa_control.sim.events.FaultEvent`)::

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

``thsa simulate --scenario FILE.toml``, ``thsa tune --scenario FILE.toml`` and
``get_scenario("FILE.toml")`` read it.  Every error names the file and the field.

Examples
--------
>>> sorted(SCENARIOS)[:2]
['backdrive_bipolar_ramp', 'cold_ramp']
>>> s = get_scenario("backdrive_bipolar_ramp")
>>> u = s.inputs([0.5, 2.0, 7.0])
>>> u["load_force"].tolist()
[0.0, 29000.0, 29000.0]
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from ..errors import ScenarioError
from .events import FaultEvent
from .monitor_settings import MonitorSettings

__all__ = ["Scenario", "SCENARIOS", "get_scenario", "TEMPERATURE_RANGE", "load_scenario_file", "scenario_from_dict",
           "scenario_to_dict"]

#: Temperature range of the friction law and of the papers' tests [degC].
TEMPERATURE_RANGE = (-55.0, 70.0)

Breakpoints = tuple[tuple[float, float], ...]


def _steps(points: Breakpoints, t: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Piecewise-constant signal: value of the last breakpoint at or before t (written into ``out`` if given)."""
    t = np.asarray(t, dtype=float)
    if out is None:
        out = np.zeros(t.shape)
    else:
        out[...] = 0.0
    if t.ndim == 1 and (t.size < 2 or bool(np.all(t[1:] >= t[:-1]))):  # sampled in order: one slice per breakpoint
        for ti, vi in points:  # ordered in time: a later breakpoint holds from its time on
            out[np.searchsorted(t, ti, side="left"):] = vi
        return out
    for ti, vi in points:
        out[t >= ti] = vi
    return out


def _linear(points: Breakpoints, t: np.ndarray) -> np.ndarray:
    """Piecewise-linear signal, held before the first and after the last breakpoint."""
    return np.interp(t, [p[0] for p in points], [p[1] for p in points])


@dataclass(frozen=True)
class Scenario:
    """One scenario: inputs as functions of time (SI, FORMAT.md signs).

    Parameters
    ----------
    name, description : str
    duration : float
        [s].
    speed_target : tuple of (t [s], v [m/s])
        Piecewise-constant target nut speed; shaped by the controller.
    accel_limit : float
        Shaper rate limit [m/s^2].
    load : tuple of (t [s], F [N])
        Piecewise-linear load force.
    temperature : float
        [degC], -55..70.
    jerk_limit : float
        Shaper acceleration limit [m/s^3] (inf: none).
    primary_enable, standby_enable : tuple of (t [s], 0/1)
        Channel enables (piecewise constant).
    position_cmd : tuple of (t [s], x [m]) or None
        If given, the position loop is closed and ``speed_target`` ignored.
    required_effects : tuple of str
        Effects the scenario needs (e.g. ``standby_motor``).
    motor_off_at_zero : bool
        De-energise the motors while the shaped command is exactly zero.
    faults : tuple of FaultEvent
        Scheduled faults (``thsa_control.sim.events``).
    monitors : MonitorSettings or None
        Run the monitors and reconfiguration logic in the loop (None: no
        monitors; faults then act unmonitored).
    """

    name: str
    description: str
    duration: float
    speed_target: Breakpoints
    accel_limit: float
    load: Breakpoints
    temperature: float = 25.0
    jerk_limit: float = math.inf
    primary_enable: Breakpoints = ((0.0, 1.0),)
    standby_enable: Breakpoints = ((0.0, 0.0),)
    position_cmd: Breakpoints | None = None
    required_effects: tuple[str, ...] = ()
    motor_off_at_zero: bool = True
    faults: tuple[FaultEvent, ...] = ()
    monitors: MonitorSettings | None = None

    def __post_init__(self):
        if not all(isinstance(f, FaultEvent) for f in self.faults):
            raise ScenarioError(f"scenario {self.name!r}: faults must be FaultEvent records")
        if self.monitors is not None:
            if not isinstance(self.monitors, MonitorSettings):
                raise ScenarioError(f"scenario {self.name!r}: monitors must be MonitorSettings or None")
            try:
                self.monitors.validate()
            except ValueError as exc:
                raise ScenarioError(f"scenario {self.name!r}: {exc}") from None
        if not (self.duration > 0 and math.isfinite(self.duration)):
            raise ScenarioError(f"scenario {self.name!r}: duration {self.duration!r} must be positive")
        if not self.accel_limit > 0:
            raise ScenarioError(f"scenario {self.name!r}: accel_limit {self.accel_limit!r} must be positive")
        lo, hi = TEMPERATURE_RANGE
        if not (lo <= self.temperature <= hi):
            raise ScenarioError(
                f"scenario {self.name!r}: temperature {self.temperature!r} degC outside the model's range {lo:g}..{hi:g} degC")
        for field_name in ("speed_target", "load", "primary_enable", "standby_enable", "position_cmd"):
            pts = getattr(self, field_name)
            if pts is None:
                continue
            times = [p[0] for p in pts]
            if not pts or any(b < a for a, b in zip(times, times[1:])):
                raise ScenarioError(f"scenario {self.name!r}: {field_name} breakpoints must be non-empty and ordered in time")
            if not all(math.isfinite(v) for p in pts for v in p):
                raise ScenarioError(f"scenario {self.name!r}: {field_name} has a non-finite value")

    def with_temperature(self, temperature: float) -> "Scenario":
        """Same scenario at another temperature [degC]."""
        return replace(self, temperature=float(temperature))

    def inputs(self, t, out: dict | None = None) -> dict[str, np.ndarray]:
        """Input signals at times ``t`` [s] (SI): speed_target, position_cmd,
        position_mode, primary_enable, standby_enable, load_force, temperature.

        ``out``: arrays of ``t``'s shape, by name, to write the signals into (returned
        as the dict); a name it lacks gets a new array.
        """
        t = np.asarray(t, dtype=float)
        out = dict(out or {})
        pos_mode = self.position_cmd is not None

        def put(name, value):
            if name in out:
                out[name][...] = value
            else:
                out[name] = np.full(t.shape, value) if np.ndim(value) == 0 else value

        put("speed_target", _steps(self.speed_target, t, out.get("speed_target")))
        put("position_cmd", _linear(self.position_cmd, t) if pos_mode else 0.0)
        put("position_mode", 1.0 if pos_mode else 0.0)
        put("primary_enable", _steps(self.primary_enable, t, out.get("primary_enable")))
        put("standby_enable", _steps(self.standby_enable, t, out.get("standby_enable")))
        put("load_force", _linear(self.load, t))
        put("temperature", float(self.temperature))
        return out

    def sampled_inputs(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """:meth:`inputs` at the ordered sample times ``t`` (from 0), with every signal that is
        constant over ``t`` as a read-only zero-stride view of its value (``np.broadcast_to``):
        the same values, bit for bit, without n copies of a constant."""
        t = np.asarray(t, dtype=float)
        n = t.shape[0]

        def const(value):
            return np.broadcast_to(float(value), (n,))

        def steps(points):
            v = _constant_steps(points, float(t[0]) if n else 0.0)
            return const(v) if v is not None else _steps(points, t)

        def linear(points):
            v = _constant_linear(points)
            return const(v) if v is not None else _linear(points, t)

        pos_mode = self.position_cmd is not None
        return {"speed_target": steps(self.speed_target),
                "position_cmd": linear(self.position_cmd) if pos_mode else const(0.0),
                "position_mode": const(1.0 if pos_mode else 0.0),
                "primary_enable": steps(self.primary_enable),
                "standby_enable": steps(self.standby_enable),
                "load_force": linear(self.load),
                "temperature": const(self.temperature)}


def _same_bits(a: float, b: float) -> bool:
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


def _constant_steps(points: Breakpoints, t0: float) -> float | None:
    """The value of :func:`_steps` at every time from ``t0`` on when it is one value, else None."""
    v = points[0][1]
    if not all(_same_bits(p[1], v) for p in points):
        return None
    if points[0][0] <= t0 or _same_bits(v, 0.0):  # before the first breakpoint _steps gives +0.0
        return v
    return None


def _constant_linear(points: Breakpoints) -> float | None:
    """The value of :func:`_linear` (``np.interp``) everywhere when it is one value, else None:
    one breakpoint, or all of one value other than -0.0 (interp gives 0 * dt + v there)."""
    v = points[0][1]
    if len(points) == 1:
        return v
    if all(_same_bits(p[1], v) for p in points) and not _same_bits(v, -0.0):
        return v
    return None


_MM = 1e-3

SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            "backdrive_bipolar_ramp",
            "Papers' back-drive test: +15 mm/s trapezoid (30 mm/s^2) from 1 s to a trim stop at 4 s, "
            "-15 mm/s trapezoid from 6 s to a trim stop at 9 s; compressive load ramp to 29 kN at 58 kN/s "
            "from 1 s, then held: the load opposes the first motion and aids the second. Motors off in the stops.",
            10.0, ((0.0, 0.0), (1.0, 15 * _MM), (3.5, 0.0), (6.0, -15 * _MM), (8.5, 0.0)), 30 * _MM,
            ((0.0, 0.0), (1.0, 0.0), (1.5, 29e3)),
        ),
        Scenario(
            "unipolar_speed_bipolar_load",
            "+15 mm/s trapezoids (30 mm/s^2) from 1 s and from 6 s with a trim stop between; the load ramps to "
            "29 kN compressive from 1 s, then turns to 29 kN tensile at 58 kN/s during the stop (zero at 5.5 s): "
            "opposing, then aiding.",
            10.0, ((0.0, 0.0), (1.0, 15 * _MM), (3.5, 0.0), (6.0, 15 * _MM), (8.5, 0.0)), 30 * _MM,
            ((0.0, 0.0), (1.0, 0.0), (1.5, 29e3), (5.0, 29e3), (6.0, -29e3)),
        ),
        Scenario(
            "triangular_load",
            "-15 mm/s trapezoid (30 mm/s^2) from 1 s to a stop at 15 s under a triangular load of 29 kN "
            "amplitude and 15 s period, starting at 1 s towards tension (opposing the retraction), crossing zero "
            "towards compression (aiding) at 8.5 s, where the load-path backlash is crossed.",
            16.0, ((0.0, 0.0), (1.0, -15 * _MM), (14.5, 0.0)), 30 * _MM,
            ((0.0, 0.0), (1.0, 0.0), (4.75, -29e3), (12.25, 29e3), (16.0, 0.0)),
        ),
        Scenario(
            "cold_ramp",
            "Cold operation at -30 degC, loaded start from standstill: the 55 kN opposing (compressive) load is "
            "ramped on from 0 to 0.4 s with the motors off (the no-back holds it), then the actuator ramps to "
            "+9 mm/s at 30 mm/s^2 from 0.5 s; stop from 2.5 s.",
            3.0, ((0.0, 0.0), (0.5, 9 * _MM), (2.5, 0.0)), 30 * _MM,
            ((0.0, 0.0), (0.4, 55e3)), temperature=-30.0,
        ),
        Scenario(
            "motor_fault_switch",
            "Paper 000's active/standby switch-over: -5 mm/s at 20 mm/s^2 from 0.5 s under a constant aiding "
            "load of 20 kN (compressive here, the papers' tensile; ramped on from 0 to 0.4 s); primary channel "
            "disabled at 1.8 s, standby enabled 15 ms later.",
            3.0, ((0.0, 0.0), (0.5, -5 * _MM)), 20 * _MM,
            ((0.0, 0.0), (0.4, 20e3)),
            primary_enable=((0.0, 1.0), (1.8, 0.0)), standby_enable=((0.0, 0.0), (1.815, 1.0)),
            required_effects=("standby_motor",),
        ),
        Scenario(
            "motor_fault_switch_rising_load",
            "Paper 000's second switch-over test: -5 mm/s at 20 mm/s^2 from 0.5 s, aiding load 20 kN (ramped on "
            "from 0 to 0.4 s), primary disabled at 1.35 s and standby enabled 15 ms later; from the fault the "
            "load rises 40 kN/s (20 kN + 40 kN/s), held at 55 kN from 2.225 s.",
            3.0, ((0.0, 0.0), (0.5, -5 * _MM)), 20 * _MM,
            ((0.0, 0.0), (0.4, 20e3), (1.35, 20e3), (2.225, 55e3)),
            primary_enable=((0.0, 1.0), (1.35, 0.0)), standby_enable=((0.0, 0.0), (1.365, 1.0)),
            required_effects=("standby_motor",),
        ),
        # ---- fault cases (papers' model F, issue #10): monitors in the loop
        Scenario(
            "jam",
            "Papers' jam: +15 mm/s trapezoid (30 mm/s^2) from 1 s against a compressive load ramped to 20 kN "
            "from 1 s; the surface locks at 3.5 s. The motor torque rises until the torque limiter slips, the "
            "motor sensor and the RVDT disagree and the position monitor safes the actuator (motors off, brakes on).",
            5.0, ((0.0, 0.0), (1.0, 15 * _MM)), 30 * _MM, ((0.0, 0.0), (1.0, 0.0), (1.5, 20e3)),
            required_effects=("loadpath_compliance", "drivetrain_compliance", "torque_limiter", "surface_jam", "motor_brakes"),
            faults=(FaultEvent("surface_jam", 3.5),), monitors=MonitorSettings(),
        ),
        Scenario(
            "loadpath_failure",
            "Papers' primary load-path failure: the back-drive profile (+15 mm/s from 1 s, -15 mm/s from 6 s, "
            "29 kN compressive from 1.5 s); the upper gimbal of the primary path breaks at 7.5 s, the actuator "
            "body moves until the secondary path's clearance is taken up, the LVDT monitor trips and both motors "
            "are shut down with the brakes on.",
            10.0, ((0.0, 0.0), (1.0, 15 * _MM), (3.5, 0.0), (6.0, -15 * _MM), (8.5, 0.0)), 30 * _MM,
            ((0.0, 0.0), (1.0, 0.0), (1.5, 29e3)),
            required_effects=("loadpath_compliance", "secondary_load_path", "motor_brakes"),
            faults=(FaultEvent("loadpath_failure", 7.5),), monitors=MonitorSettings(),
        ),
        Scenario(
            "motor_fault_monitored",
            "motor_fault_switch with the monitors in the loop: -5 mm/s under a constant 20 kN aiding load; the "
            "primary channel fails at 1.8 s (its inverter stops); the speed-tracking monitor detects it and the "
            "reconfiguration logic enables the standby channel after its take-over delay (papers: 15 ms).",
            3.0, ((0.0, 0.0), (0.5, -5 * _MM)), 20 * _MM, ((0.0, 0.0), (0.4, 20e3)),
            required_effects=("standby_motor",),
            faults=(FaultEvent("channel_failure", 1.8, channel="primary"),), monitors=MonitorSettings(),
        ),
        Scenario(
            "motor_fault_monitored_rising_load",
            "motor_fault_switch_rising_load with the monitors in the loop: the primary channel fails at 1.35 s, "
            "the load rises 40 kN/s from the fault (held at 55 kN from 2.225 s); the monitors switch to standby.",
            3.0, ((0.0, 0.0), (0.5, -5 * _MM)), 20 * _MM, ((0.0, 0.0), (0.4, 20e3), (1.35, 20e3), (2.225, 55e3)),
            required_effects=("standby_motor",),
            faults=(FaultEvent("channel_failure", 1.35, channel="primary"),), monitors=MonitorSettings(),
        ),
    )
}


def get_scenario(name: str) -> Scenario:
    """The scenario called ``name``, or read from ``name`` if it ends in ``.toml``
    (:func:`load_scenario_file`); :class:`ScenarioError` lists the known ones otherwise."""
    if str(name).lower().endswith(".toml"):
        return load_scenario_file(name)
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ScenarioError(f"unknown scenario {name!r}; scenarios are {', '.join(SCENARIOS)}") from None


# ---- scenario files (TOML; see the module docstring)
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


def scenario_to_dict(scenario: Scenario) -> dict:
    """The TOML-ready table of a :class:`Scenario` that :func:`scenario_from_dict` reads back to an equal one
    (an infinite fault ``end`` as the string ``"inf"``; the default infinite ``jerk_limit`` left out)."""
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
            continue
        else:
            out[f.name] = value
    return out


def load_scenario_file(path) -> Scenario:
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
