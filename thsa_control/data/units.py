"""The only unit conversions of thsa-control, and the one display-unit table.

SI inside the package, in the API and in every JSON file (each key carries its
unit: ``delay_margin_s``, ``load_force_N``); the rig-data format, the reports,
their tables and plot axes, and the command-line options use the display
units of :data:`DISPLAY_UNITS`:

============================ ========= ========== =====================================
quantity                     SI        display    used for
============================ ========= ========== =====================================
``position``                 m         mm         nut position, position errors
``nut_speed``                m/s       mm/s       nut speed, trim speed, speed errors
``force``                    N         kN         load, load-path force
``torque``                   N m       N m        motor, no-back, friction torques
``rotational_speed``         rad/s     rpm        motor and screw speed
``current``                  A         A          motor current
``voltage``                  V         V          motor voltage
``temperature``              degC      degC       housing temperature (degC inside too)
``time``                     s         ms         delays, detection and recovery times,
                                                  rise/settling times, delay margins
``duration``                 s         s          run length, time axes of runs
``frequency``                Hz        Hz         crossover, bandwidth
``angle``                    rad       deg        phase, rotor and pawl angles
``velocity_load_step``       m/s/N     mm/s/kN    nut-speed peak per unit load step
``position_load_step``       m/N       um/kN      nut-position peak per unit load step
============================ ========= ========== =====================================

:func:`to_display` / :func:`from_display` convert, :func:`label` writes a
column or axis heading (``"load [kN]"``).  Every conversion lives here so
that no module multiplies by a bare ``60 / (2 * pi)``.

Examples
--------
>>> round(rpm_to_rad_s(60.0), 6)
6.283185
>>> mm_to_m(12.0)
0.012
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "rpm_to_rad_s",
    "rad_s_to_rpm",
    "mm_to_m",
    "m_to_mm",
    "deg_to_rad",
    "rad_to_deg",
    "celsius_to_kelvin",
    "kelvin_to_celsius",
    "to_db",
    "hz_to_rad_s",
    "rad_s_to_hz",
    "DisplayUnit",
    "DISPLAY_UNITS",
    "display_unit",
    "to_display",
    "from_display",
    "label",
    "SIGNAL_QUANTITY",
    "signal_display",
    "signal_label",
]

_RPM = 2.0 * math.pi / 60.0


def rpm_to_rad_s(x):
    """Rotational speed [rpm] -> [rad/s]."""
    return np.asarray(x) * _RPM if not np.isscalar(x) else x * _RPM


def rad_s_to_rpm(x):
    """Rotational speed [rad/s] -> [rpm]."""
    return np.asarray(x) / _RPM if not np.isscalar(x) else x / _RPM


def mm_to_m(x):
    """Length [mm] -> [m]."""
    return np.asarray(x) * 1e-3 if not np.isscalar(x) else x * 1e-3


def m_to_mm(x):
    """Length [m] -> [mm]."""
    return np.asarray(x) * 1e3 if not np.isscalar(x) else x * 1e3


def deg_to_rad(x):
    """Angle [deg] -> [rad]."""
    return np.deg2rad(x) if not np.isscalar(x) else math.radians(x)


def rad_to_deg(x):
    """Angle [rad] -> [deg]."""
    return np.rad2deg(x) if not np.isscalar(x) else math.degrees(x)


def celsius_to_kelvin(x):
    """Temperature [degC] -> [K]."""
    return np.asarray(x) + 273.15 if not np.isscalar(x) else x + 273.15


def kelvin_to_celsius(x):
    """Temperature [K] -> [degC]."""
    return np.asarray(x) - 273.15 if not np.isscalar(x) else x - 273.15


def to_db(x):
    """Magnitude ratio -> [dB] (20 log10)."""
    return 20.0 * np.log10(x)


def hz_to_rad_s(x):
    """Frequency [Hz] -> [rad/s]."""
    return np.asarray(x) * 2 * math.pi if not np.isscalar(x) else x * 2 * math.pi


def rad_s_to_hz(x):
    """Frequency [rad/s] -> [Hz]."""
    return np.asarray(x) / (2 * math.pi) if not np.isscalar(x) else x / (2 * math.pi)


# ----------------------------------------------------------------------------------------------------------------
# the display-unit table
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DisplayUnit:
    """How one quantity is shown: ``display = si * factor``.

    Parameters
    ----------
    quantity : str
        Name of the quantity (a key of :data:`DISPLAY_UNITS`).
    si : str
        Unit inside the package, in the API and in JSON.
    unit : str
        Unit of reports, tables, plot axes and command-line options.
    factor : float
        Display value per SI value.
    """

    quantity: str
    si: str
    unit: str
    factor: float

    def to_display(self, x):
        """SI -> display unit (scalars stay scalars)."""
        return x * self.factor if np.isscalar(x) else np.asarray(x, float) * self.factor

    def from_display(self, x):
        """Display unit -> SI."""
        return x / self.factor if np.isscalar(x) else np.asarray(x, float) / self.factor

    def label(self, name: str) -> str:
        """A column or axis heading: ``"name [unit]"`` (``"name"`` for a dimensionless quantity)."""
        return f"{name} [{self.unit}]" if self.unit not in ("", "-") else name


_TABLE = (
    DisplayUnit("position", "m", "mm", 1e3),
    DisplayUnit("nut_speed", "m/s", "mm/s", 1e3),
    DisplayUnit("force", "N", "kN", 1e-3),
    DisplayUnit("torque", "N m", "N m", 1.0),
    DisplayUnit("rotational_speed", "rad/s", "rpm", 60.0 / (2.0 * math.pi)),
    DisplayUnit("current", "A", "A", 1.0),
    DisplayUnit("voltage", "V", "V", 1.0),
    DisplayUnit("temperature", "degC", "degC", 1.0),
    DisplayUnit("time", "s", "ms", 1e3),
    DisplayUnit("duration", "s", "s", 1.0),
    DisplayUnit("frequency", "Hz", "Hz", 1.0),
    DisplayUnit("angle", "rad", "deg", 180.0 / math.pi),
    DisplayUnit("velocity_load_step", "m/s per N", "mm/s per kN", 1e6),
    DisplayUnit("position_load_step", "m per N", "um per kN", 1e9),
    DisplayUnit("dimensionless", "-", "-", 1.0),
)
#: Quantity -> its display unit (the one table; see the module docstring).
DISPLAY_UNITS: dict[str, DisplayUnit] = {u.quantity: u for u in _TABLE}


def display_unit(quantity: str) -> DisplayUnit:
    """The :class:`DisplayUnit` of ``quantity`` (``KeyError`` naming the known ones)."""
    try:
        return DISPLAY_UNITS[quantity]
    except KeyError:
        raise KeyError(f"no display unit for {quantity!r}; known: {', '.join(DISPLAY_UNITS)}") from None


def to_display(quantity: str, x):
    """``x`` [SI] in the display unit of ``quantity``.

    >>> to_display("force", -55e3), to_display("time", 0.015)
    (-55.0, 15.0)
    """
    return display_unit(quantity).to_display(x)


def from_display(quantity: str, x):
    """``x`` [display unit of ``quantity``] in SI.

    >>> from_display("nut_speed", 5.0)
    0.005
    """
    return display_unit(quantity).from_display(x)


def label(name: str, quantity: str) -> str:
    """Column or axis heading of a ``quantity`` shown in its display unit.

    >>> label("load", "force")
    'load [kN]'
    """
    return display_unit(quantity).label(name)


#: Signal names of the workbench (rig-run signals, simulation outputs, replay channels) -> quantity.
SIGNAL_QUANTITY: dict[str, str] = {
    "motor_speed": "rotational_speed", "screw_speed": "rotational_speed", "standby_speed": "rotational_speed",
    "nut_position": "position", "position_cmd": "position", "surface_position": "position",
    "model_nut_position": "position",
    "nut_speed": "nut_speed", "speed_cmd": "nut_speed", "surface_speed": "nut_speed",
    "load_force": "force", "loadpath_force": "force",
    "motor_current": "current", "standby_current": "current", "current_ref": "current",
    "motor_voltage": "voltage",
    "noback_torque": "torque", "missing_torque": "torque", "motor_torque": "torque",
    "temperature": "temperature",
    "motor_angle": "angle",
    "reversal_proximity": "duration",
}


def signal_display(name: str) -> DisplayUnit:
    """Display unit of a named signal (``dimensionless`` when the signal has no entry).

    >>> signal_display("motor_speed").unit, signal_display("load_force").unit
    ('rpm', 'kN')
    """
    return DISPLAY_UNITS[SIGNAL_QUANTITY.get(name, "dimensionless")]


def signal_label(name: str, text: str | None = None) -> str:
    """Axis or column heading of a signal: ``"motor_speed [rpm]"``."""
    return signal_display(name).label(text or name)
