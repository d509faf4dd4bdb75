"""The only unit conversions of thsa-control.

SI inside the package; the rig-data format and the reports use mm, rpm, kN and
degC.  Every conversion lives here so that no module multiplies by a bare
``60 / (2 * pi)``.

Examples
--------
>>> round(rpm_to_rad_s(60.0), 6)
6.283185
>>> mm_to_m(12.0)
0.012
"""

from __future__ import annotations

import math

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
