"""Scheduled fault inputs of a scenario, and their per-sample signals.

A :class:`FaultEvent` is data (it lives in a :class:`~thsa_control.sim.scenarios.Scenario`
and in scenario TOML files).  Kinds:

``surface_jam``
    The surface is locked where it is from ``time`` on (plant input
    ``surface_jam``; needs the ``surface_jam`` effect).
``loadpath_failure``
    The primary load path breaks at the upper gimbal at ``time`` (plant input
    ``loadpath_failure``; needs ``secondary_load_path``).
``channel_failure``
    Motor channel ``channel`` (``primary``/``standby``) fails at ``time``: its
    inverter stops, whatever the controller commands (the enable reaching the
    plant is forced to 0).
``sensor``
    Sensor ``sensor`` (``motor_speed``: the primary motor's speed sensor [rad/s];
    ``rvdt``: screw angle [rad]; ``lvdt``: upper-gimbal displacement [m]) fails
    from ``time`` to ``end`` in mode ``stuck`` (holds its last value),
    ``offset`` (adds ``value``), ``noise`` (adds white noise of standard
    deviation ``value``, seeded by ``seed``) or ``loss`` (reads 0).

Fault events are scenario data (``sim/scenarios.py`` holds them, scenario
files write them); the monitor loop extension (``sim/monitors.py``) turns
them into its per-sample inputs.  Only numpy and the errors module are
imported here.

Examples
--------
>>> ev = (FaultEvent("surface_jam", 3.5), FaultEvent("sensor", 1.0, sensor="lvdt", mode="offset", value=1e-4, end=2.0))
>>> s = fault_signals(ev, np.array([0.5, 1.5, 2.5, 3.6]))
>>> s["surface_jam"].tolist(), s["lvdt_error"].tolist()
([0.0, 0.0, 0.0, 1.0], [0.0, 0.0001, 0.0, 0.0])
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ScenarioError

__all__ = ["FaultEvent", "FAULT_KINDS", "SENSORS", "SENSOR_MODES", "FAULT_INPUTS", "fault_signals", "effects_for_faults"]

FAULT_KINDS = ("surface_jam", "loadpath_failure", "channel_failure", "sensor")
#: sensor -> (unit of its reading and of ``value``, what it measures)
SENSORS = {
    "motor_speed": ("rad/s", "speed sensor of the primary motor (velocity loop; integrated: motor position)"),
    "rvdt": ("rad", "screw angle (position loop; nut position = angle x lead / 2 pi)"),
    "lvdt": ("m", "upper-gimbal displacement (primary/secondary attachment)"),
}
SENSOR_MODES = ("stuck", "offset", "noise", "loss")
#: Per-sample fault inputs of the fault loop, after ``RUN_INPUTS``.
FAULT_INPUTS = ("surface_jam", "loadpath_failure", "primary_channel_failure", "standby_channel_failure") + tuple(
    f"{s}_{m}" for s in SENSORS for m in ("stuck", "lost", "error"))
#: plant effect a fault kind needs
_NEEDS = {"surface_jam": "surface_jam", "loadpath_failure": "secondary_load_path"}


@dataclass(frozen=True)
class FaultEvent:
    """One scheduled fault (see the module docstring for the kinds).

    Parameters
    ----------
    kind : str
        ``surface_jam``, ``loadpath_failure``, ``channel_failure`` or ``sensor``.
    time : float
        Onset [s].
    end : float
        End [s] (sensor faults only; inf: to the end of the run).  Jams,
        load-path and channel failures are permanent.
    channel : str
        ``primary`` or ``standby`` (channel failures).
    sensor, mode : str
        Sensor and failure mode (sensor faults).
    value : float
        Offset or noise standard deviation, in the sensor's unit (SI).
    seed : int
        Noise seed.
    """

    kind: str
    time: float
    end: float = math.inf
    channel: str = ""
    sensor: str = ""
    mode: str = ""
    value: float = 0.0
    seed: int = 0

    def __post_init__(self):
        where = f"fault {self.kind!r} at {self.time!r} s"
        if self.kind not in FAULT_KINDS:
            raise ScenarioError(f"fault kind {self.kind!r} unknown; kinds are {', '.join(FAULT_KINDS)}")
        if not (isinstance(self.time, (int, float)) and math.isfinite(self.time) and self.time >= 0):
            raise ScenarioError(f"{where}: time must be a finite number >= 0")
        if not (self.end > self.time):
            raise ScenarioError(f"{where}: end {self.end!r} must be after the onset")
        if self.kind != "sensor" and math.isfinite(self.end):
            raise ScenarioError(f"{where}: only sensor faults have an end (the others are permanent)")
        if self.kind == "channel_failure" and self.channel not in ("primary", "standby"):
            raise ScenarioError(f"{where}: channel {self.channel!r} must be 'primary' or 'standby'")
        if self.kind == "sensor":
            if self.sensor not in SENSORS:
                raise ScenarioError(f"{where}: sensor {self.sensor!r} unknown; sensors are {', '.join(SENSORS)}")
            if self.mode not in SENSOR_MODES:
                raise ScenarioError(f"{where}: mode {self.mode!r} unknown; modes are {', '.join(SENSOR_MODES)}")
            if not math.isfinite(self.value) or (self.mode == "noise" and self.value < 0):
                raise ScenarioError(f"{where}: value {self.value!r} must be finite (>= 0 for noise)")

    @property
    def label(self) -> str:
        """Short description, e.g. ``sensor rvdt offset`` or ``surface_jam``."""
        if self.kind == "sensor":
            return f"sensor {self.sensor} {self.mode}"
        if self.kind == "channel_failure":
            return f"{self.channel} channel failure"
        return self.kind


def fault_signals(faults, t) -> dict[str, np.ndarray]:
    """Per-sample fault inputs (``FAULT_INPUTS``) of ``faults`` at times ``t`` [s]; an input no fault
    touches is a read-only zero-stride view of 0.0 (no array of zeros)."""
    t = np.asarray(t, dtype=float)
    zero = np.broadcast_to(0.0, t.shape)
    out = {name: zero for name in FAULT_INPUTS}
    for ev in faults:
        on = (t >= ev.time) & (t < ev.end)
        if ev.kind in ("surface_jam", "loadpath_failure"):
            out[ev.kind] = np.maximum(out[ev.kind], on)
        elif ev.kind == "channel_failure":
            key = f"{ev.channel}_channel_failure"
            out[key] = np.maximum(out[key], on)
        elif ev.mode == "stuck":
            out[f"{ev.sensor}_stuck"] = np.maximum(out[f"{ev.sensor}_stuck"], on)
        elif ev.mode == "loss":
            out[f"{ev.sensor}_lost"] = np.maximum(out[f"{ev.sensor}_lost"], on)
        elif ev.mode == "offset":
            out[f"{ev.sensor}_error"] = out[f"{ev.sensor}_error"] + ev.value * on
        else:  # noise
            noise = np.random.default_rng(ev.seed).standard_normal(t.shape) * ev.value
            out[f"{ev.sensor}_error"] = out[f"{ev.sensor}_error"] + noise * on
    return out


def effects_for_faults(faults) -> tuple[str, ...]:
    """Plant effects the faults need (a jam needs ``surface_jam``, ...)."""
    need = []
    for ev in faults:
        e = _NEEDS.get(ev.kind)
        if e and e not in need:
            need.append(e)
    return tuple(need)
