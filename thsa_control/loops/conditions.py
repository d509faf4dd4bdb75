"""Operating conditions of the linear workflow: where a THSA plant is linearised, and how points are judged.

:class:`OperatingCondition` (trim nut speed [m/s], load [N], temperature
[degC], active motor), :class:`ConditionGrid` (their product), and
:class:`LinearizationSettings` (validity bands, solver tolerance, pawl
placement).  The adapter that uses them is :mod:`thsa_control.loops.linear`
(which re-exports these names).  Numbers only: no model, no plotting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = ["INPUTS", "CONDITION_PARAMETERS", "Active", "ACTIVE_CHANNELS", "LinearizationSettings",
           "OperatingCondition", "ConditionGrid", "conditions_tuple"]

#: Inputs of the adapted model, in order.
INPUTS: tuple[str, ...] = ("voltage_primary", "voltage_standby", "load_force", "disturbance_torque")
#: Held operating conditions appended to the plant's parameters, in order.
CONDITION_PARAMETERS: tuple[str, ...] = ("enable_primary", "enable_standby", "temperature")

Active = Literal["primary", "standby"]
#: Active channel -> (voltage input, current state/output).
ACTIVE_CHANNELS = {
    # active channel -> (voltage input, current state/output)
    "primary": ("voltage_primary", "motor_current"),
    "standby": ("voltage_standby", "standby_current"),
}


@dataclass(frozen=True)
class LinearizationSettings:
    """How operating points are found and judged.

    Parameters
    ----------
    min_speed : float
        Half-width of the band around zero nut speed where the point is
        declared "zero speed / stick" [m/s].  Default 1e-5 (0.01 mm/s, a
        motor speed of 0.34 rad/s).
    loadpath_edge_band : float
        Band around the load-path contact edges ``|deflection| = backlash``
        inside which the point is a backlash edge [m].  Default 1e-6.
    pawl_edge_band : float
        Band around a pawl's engagement edge (clearance 0) [rad].  Default 1e-6.
    pawl : {'inside', 'edge'}
        Where the engaged pawl's clearance is put in a steady motion (see the
        module notes).  Default ``'inside'``.
    fd_check : bool
        Cross-check AD with finite differences and detect kinks.  Default True.
    kink_rtol : float
        Relative slope jump reported as a kink [-].  Default 1e-3.
    solver_tol : float
        Largest accepted equation residual of an operating point.  Default 1e-9.
    """

    min_speed: float = 1e-5
    loadpath_edge_band: float = 1e-6
    pawl_edge_band: float = 1e-6
    pawl: Literal["inside", "edge"] = "inside"
    fd_check: bool = True
    kink_rtol: float = 1e-3
    solver_tol: float = 1e-9

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first invalid setting."""
        for name in ("min_speed", "loadpath_edge_band", "pawl_edge_band"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"LinearizationSettings.{name} = {value!r} must be a finite number >= 0")
        for name in ("kink_rtol", "solver_tol"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"LinearizationSettings.{name} = {value!r} must be > 0")
        if self.pawl not in ("inside", "edge"):
            raise ValueError(f"LinearizationSettings.pawl = {self.pawl!r}; valid: 'inside', 'edge'")


@dataclass(frozen=True)
class OperatingCondition:
    """Where the actuator is linearised.

    Parameters
    ----------
    nut_speed : float
        Trim nut speed [m/s], positive extending.
    load_force : float
        Axial load [N], positive compressive: it opposes the motion when
        ``load_force * nut_speed > 0`` and aids it when ``< 0``.
    temperature : float
        Actuator temperature [degC], -55..70 (changes the plant only with
        the ``temperature_friction`` effect).
    active : {'primary', 'standby'}
        Energised motor channel; the other is off (its rotor dragged).

    Examples
    --------
    >>> c = OperatingCondition(5e-3, -20e3, -30.0)
    >>> c.aiding, c.label()
    (True, '5 mm/s, -20 kN (aiding), -30 degC')
    """

    nut_speed: float
    load_force: float
    temperature: float = 25.0
    active: Active = "primary"

    def __post_init__(self) -> None:
        for name in ("nut_speed", "load_force", "temperature"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise ValueError(f"OperatingCondition.{name} = {value!r} is not a number")
            if not math.isfinite(float(value)):
                raise ValueError(f"OperatingCondition.{name} = {value!r} is not finite")
            object.__setattr__(self, name, float(value))
        if not -55.0 <= self.temperature <= 70.0:
            raise ValueError(f"OperatingCondition.temperature = {self.temperature:g} degC outside -55..70 degC")
        if self.active not in ACTIVE_CHANNELS:
            raise ValueError(f"OperatingCondition.active = {self.active!r}; valid: {sorted(ACTIVE_CHANNELS)}")

    @property
    def aiding(self) -> bool:
        """True when the load aids the motion (``load_force * nut_speed < 0``)."""
        return self.load_force * self.nut_speed < 0

    @property
    def opposing(self) -> bool:
        """True when the load opposes the motion (``load_force * nut_speed > 0``)."""
        return self.load_force * self.nut_speed > 0

    def label(self) -> str:
        """Short human-readable label (mm/s, kN, degC)."""
        if self.load_force == 0 or self.nut_speed == 0:
            how = ""
        else:
            how = " (aiding)" if self.aiding else " (opposing)"
        act = "" if self.active == "primary" else ", standby active"
        return (f"{self.nut_speed * 1e3:g} mm/s, {self.load_force * 1e-3:g} kN{how}, "
                f"{self.temperature:g} degC{act}")


@dataclass(frozen=True)
class ConditionGrid:
    """A full grid of operating conditions (SI).

    Points are ordered temperature-major, then speed, then load
    (``numpy.meshgrid(..., indexing='ij')`` of ``temperatures, nut_speeds,
    load_forces``).

    Parameters
    ----------
    nut_speeds : sequence of float
        [m/s].
    load_forces : sequence of float
        [N], compressive positive.
    temperatures : sequence of float
        [degC].
    active : {'primary', 'standby'}
        Energised channel.

    Examples
    --------
    >>> g = ConditionGrid((1e-3, 5e-3), (0.0,), (-30.0, 25.0))
    >>> len(g), g.shape, g.conditions()[1].label()
    (4, (2, 2, 1), '5 mm/s, 0 kN, -30 degC')
    """

    nut_speeds: tuple[float, ...]
    load_forces: tuple[float, ...]
    temperatures: tuple[float, ...] = (25.0,)
    active: Active = "primary"

    def __post_init__(self) -> None:
        for name in ("nut_speeds", "load_forces", "temperatures"):
            values = tuple(float(v) for v in getattr(self, name))
            if not values:
                raise ValueError(f"ConditionGrid.{name} is empty")
            object.__setattr__(self, name, values)

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(n_temperatures, n_speeds, n_loads)``."""
        return (len(self.temperatures), len(self.nut_speeds), len(self.load_forces))

    def __len__(self) -> int:
        return int(np.prod(self.shape))

    def conditions(self) -> tuple[OperatingCondition, ...]:
        """All points, temperature-major."""
        return tuple(
            OperatingCondition(v, f, t, self.active)
            for t in self.temperatures for v in self.nut_speeds for f in self.load_forces
        )


def conditions_tuple(conditions) -> tuple[OperatingCondition, ...]:
    """``conditions`` (one condition, a grid or a sequence of conditions) as a non-empty tuple."""
    if isinstance(conditions, OperatingCondition):
        return (conditions,)
    if isinstance(conditions, ConditionGrid):
        return conditions.conditions()
    out = tuple(conditions)
    for c in out:
        if not isinstance(c, OperatingCondition):
            raise TypeError(f"expected OperatingCondition, got {type(c).__name__}")
    if not out:
        raise ValueError("no operating conditions given")
    return out
