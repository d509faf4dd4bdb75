"""Simulation results as rig runs (``thsa-rig-run/1``, FORMAT.md).

The standard columns come first in FORMAT.md units; every other signal
follows as an extra column named ``<signal>_<unit tag>`` in display units
(``surface_position_mm``, ``noback_torque_Nm``, ``pawl_engaged``).  Writing
goes through :func:`thsa_control.data.rigdata.write_run` (atomic, validated).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .rigdata import FORMAT_TAG, write_run
from ..sim.simulate import SimulationResult
from .units import rad_s_to_rpm

__all__ = ["rig_columns", "rig_metadata", "write_simulation", "UNIT_TAGS"]

#: SI unit -> (column suffix, factor to display unit)
UNIT_TAGS: dict[str, tuple[str, float]] = {
    "m": ("mm", 1e3), "m/s": ("mm_s", 1e3), "rad/s": ("rpm", float(rad_s_to_rpm(1.0))), "rad": ("deg", 180 / math.pi),
    "N m": ("Nm", 1.0), "N": ("N", 1.0), "A": ("A", 1.0), "V": ("V", 1.0), "W": ("W", 1.0), "J": ("J", 1.0),
    "degC": ("C", 1.0), "-": ("", 1.0), "N m s/rad": ("Nms_rad", 1.0),
}

# standard column -> (signal, factor)
_STANDARD = {
    "speed_cmd_mm_s": ("speed_cmd", 1e3),
    "load_force_N": ("load_force", 1.0),
    "motor_speed_rpm": ("motor_speed", float(rad_s_to_rpm(1.0))),
    "motor_current_A": ("motor_current", 1.0),
    "nut_position_mm": ("nut_position", 1e3),
    "screw_speed_rpm": ("screw_speed", float(rad_s_to_rpm(1.0))),
    "temperature_C": ("temperature", 1.0),
}


def rig_columns(result: SimulationResult) -> dict[str, np.ndarray]:
    """Columns of ``result`` in FORMAT.md names and units (standard first, then extras)."""
    cols: dict[str, np.ndarray] = {"time_s": np.asarray(result.time)}
    for col, (sig, k) in _STANDARD.items():
        cols[col] = np.asarray(result[sig]) * k
    # inputs as sampled at the output instants
    dec = int(round(result.info["output_period_s"] / result.info["control_period_s"]))
    idx = np.arange(len(result.time)) * dec
    cols["primary_enable"] = np.asarray(result.inputs.signals["primary_enable"])[idx]
    cols["standby_enable"] = np.asarray(result.inputs.signals["standby_enable"])[idx]
    if np.any(np.asarray(result.inputs.signals["position_mode"]) > 0.5):
        cols["position_cmd_mm"] = np.asarray(result.inputs.signals["position_cmd"])[idx] * 1e3
    used = {sig for sig, _ in _STANDARD.values()}
    for name in result.names:
        if name in used:
            continue
        tag, k = UNIT_TAGS.get(result.units.get(name, "-"), ("", 1.0))
        cols[f"{name}_{tag}" if tag else name] = np.asarray(result[name]) * k
    return cols


def rig_metadata(result: SimulationResult, *, level: str | None = None) -> dict:
    """The run's JSON: format tag, controller as it ran, model and scenario."""
    d = result.design
    vmax = result.params.value("inverter.dc_bus_voltage") / math.sqrt(3.0)
    return {
        "format": FORMAT_TAG,
        "name": result.name,
        "description": result.inputs.description,
        "temperature_C": float(np.asarray(result.inputs.signals["temperature"])[0]),
        "sample_rate_hz": 1.0 / result.info["output_period_s"],
        "controller": {
            "velocity_loop": {"kp_A_per_rad_s": d.velocity_kp, "ki_A_per_rad": d.velocity_ki, "current_limit_A": d.current_limit},
            "current_loop": {"kp_V_per_A": d.current_kp, "ki_V_per_A_s": d.current_ki,
                             "voltage_limit_V": d.voltage_limit if d.voltage_limit is not None else vmax},
            "control_period_s": d.control_period,
            # free metadata (FORMAT.md): samples between the measurement and the voltage it produces
            "computation_delay_samples": d.computation_delay_samples,
        },
        "motor_disabled_when_cmd_zero": bool(result.inputs.motor_off_at_zero),
        "rig": {"screw_lead_mm": result.params.value("screw.lead") * 1e3, "gear_ratio": result.params.value("gear.ratio"),
                "motors": 2 if "standby_motor" in result.effects else 1},
        "generator": {"tool": "thsa-control simulate", "level": level, "effects": list(result.effects),
                      "design": d.name, "design_source": d.source, "substeps": result.info["substeps"]},
    }


def write_simulation(result: SimulationResult, stem: str | Path, *, level: str | None = None) -> tuple[Path, Path]:
    """Write ``stem.csv`` and ``stem.json`` (atomically) and return their paths."""
    return write_run(stem, rig_columns(result), rig_metadata(result, level=level))
