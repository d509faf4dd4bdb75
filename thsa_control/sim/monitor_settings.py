"""Settings of the monitors and of the reconfiguration logic (data only).

The defaults are the workbench's nominal monitor design; every value is an
assumption (the papers give the logic, not its numbers) and ``thsa faults``
sweeps them and prints the false-alarm margin on the normal scenarios.

Examples
--------
>>> m = MonitorSettings()
>>> m.vector().shape
(10,)
>>> MonitorSettings(speed_threshold=-1.0).validate()
Traceback (most recent call last):
...
ValueError: MonitorSettings.speed_threshold = -1.0 must be positive and finite
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

__all__ = ["MonitorSettings", "MONITOR_PARAMETERS"]

#: order of the monitor parameters in the fault loop's parameter vector
MONITOR_PARAMETERS = (
    "discrepancy_threshold", "discrepancy_confirmation", "lvdt_threshold", "lvdt_confirmation",
    "speed_threshold", "speed_confirmation", "takeover_delay", "speed_rearm", "reconfigure", "brakes_on_safe",
)


@dataclass(frozen=True)
class MonitorSettings:
    """Thresholds, confirmation times and reconfiguration of the monitors.

    Parameters
    ----------
    discrepancy_threshold : float
        Motor position (motor sensor, integrated, divided by the gear ratio)
        minus RVDT screw angle [rad at the screw] beyond which the drive train
        is declared slipping or jammed.  Assumed 0.5 rad (8 % of a screw
        turn, 0.95 mm of nut travel): above the elastic twist at the largest
        normal torque (0.017 rad) and the brief limiter slips of the normal
        scenarios (up to 0.25 rad), well below one slip revolution.
    discrepancy_confirmation : float
        Time the discrepancy must stay beyond its threshold [s] (assumed 10 ms).
    lvdt_threshold : float
        Upper-gimbal displacement beyond which the primary load path is
        declared failed [m] (assumed 0.5 mm: between the primary attachment's
        elastic deflection at the largest load and the secondary clearance).
    lvdt_confirmation : float
        [s] (assumed 5 ms).
    speed_threshold : float
        Motor speed reference minus measured motor speed [rad/s] beyond which
        the active channel is declared failed, while a channel is energised
        (assumed 100 rad/s = 2.9 mm/s of nut speed; the normal scenarios
        reach 59 rad/s at a no-back breakaway).
    speed_confirmation : float
        [s] (assumed 5 ms).
    takeover_delay : float
        From a confirmed channel failure to the standby channel's enable [s]
        (the primary is disabled at once).  Assumed 5 ms; with the detection
        it gives about the papers' 15 ms from fault to take-over.
    speed_rearm : float
        The speed monitor is inhibited for this long after a take-over [s]
        (the standby's start-up transient); a second confirmed failure then
        safes the actuator.  Assumed 0.3 s (papers: recovery in about 0.15 s).
    reconfigure : bool
        True: the monitors switch the enables and the brakes; False: flags only.
    brakes_on_safe : bool
        Engage the motor brakes when the actuator is safed (both channels off).
    """

    discrepancy_threshold: float = 0.5
    discrepancy_confirmation: float = 0.01
    lvdt_threshold: float = 0.5e-3
    lvdt_confirmation: float = 0.005
    speed_threshold: float = 100.0
    speed_confirmation: float = 0.005
    takeover_delay: float = 0.005
    speed_rearm: float = 0.3
    reconfigure: bool = True
    brakes_on_safe: bool = True

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad field."""
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("reconfigure", "brakes_on_safe"):
                if not isinstance(v, bool):
                    raise ValueError(f"MonitorSettings.{f.name} = {v!r} must be true or false")
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"MonitorSettings.{f.name} = {v!r} must be positive and finite")
            if f.name.endswith("threshold") and v <= 0:
                raise ValueError(f"MonitorSettings.{f.name} = {v!r} must be positive and finite")
            if v < 0:
                raise ValueError(f"MonitorSettings.{f.name} = {v!r} must be >= 0")

    def vector(self) -> np.ndarray:
        """Values in ``MONITOR_PARAMETERS`` order (booleans as 0/1)."""
        self.validate()
        return np.array([float(getattr(self, n)) for n in MONITOR_PARAMETERS])

    def as_dict(self) -> dict:
        """Plain dict (JSON/TOML)."""
        return asdict(self)
