"""Simulation results as rig runs (``thsa-rig-run/1``, FORMAT.md).

The standard columns come first in FORMAT.md units; every other signal
follows as an extra column named ``<signal>_<unit tag>`` in display units
(``noback_torque_Nm``, ``pawl_engaged``, ``model_nut_position_mm``).  The
LVDT column ``nut_position_mm`` is the surface (output rod) position, the
current column the active motor's.  Writing
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

#: Extra column of a varying current added at the velocity loop's output [A] (controller.current_feedforward).
FEEDFORWARD_COLUMN = "current_ff_A"

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
    "nut_position_mm": ("surface_position", 1e3),  # the LVDT reads the output rod (= nut when rigid)
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
    # FORMAT.md: the current column is the active motor's (the standby's after a switch-over)
    standby_active = (cols["standby_enable"] > 0.5) & (cols["primary_enable"] < 0.5)
    cols["motor_current_A"] = np.where(standby_active, np.asarray(result["standby_current"]), cols["motor_current_A"])
    if np.any(np.asarray(result.inputs.signals["position_mode"]) > 0.5):
        cols["position_cmd_mm"] = np.asarray(result.inputs.signals["position_cmd"])[idx] * 1e3
    ff = np.asarray(result.inputs.signals["current_ff"], float)
    if ff.size and np.ptp(ff) > 0:  # a varying current at the controller output: its own column (JSON names it)
        cols[FEEDFORWARD_COLUMN] = ff[idx]
    used = {sig for sig, _ in _STANDARD.values()}
    for name in result.names:
        if name in used:
            continue
        tag, k = UNIT_TAGS.get(result.units.get(name, "-"), ("", 1.0))
        key = f"{name}_{tag}" if tag else name
        if key in cols:  # the model's nut position next to the LVDT column
            key = f"model_{key}"
        cols[key] = np.asarray(result[name]) * k
    return cols


def _controller_extensions(result: SimulationResult) -> dict:
    """``position_loop`` / ``current_feedforward`` of the controller block (docs/rig_format.md), when the run used them.

    Raises ``ValueError`` for a run whose position loop is closed only part
    of the time: the format's ``position_loop`` holds for the whole run.
    """
    d, inputs = result.design, result.inputs
    out: dict = {}
    mode = np.asarray(inputs.signals["position_mode"]) > 0.5
    if mode.all() and d.position_kp > 0:
        pl = {"kp_1_per_s": d.position_kp, "max_speed_mm_s": d.max_speed * 1e3}
        if math.isfinite(inputs.accel_limit):
            pl["accel_limit_mm_s2"] = inputs.accel_limit * 1e3
        if math.isfinite(inputs.jerk_limit):
            pl["jerk_limit_mm_s3"] = inputs.jerk_limit * 1e3
        out["position_loop"] = pl
    elif mode.any() and d.position_kp > 0:
        raise ValueError(f"run {result.name!r} closes the position loop only part of the time; the rig format's "
                         "controller.position_loop holds for the whole run")
    ff = np.asarray(inputs.signals["current_ff"], float)
    if ff.size and np.ptp(ff) > 0:
        out["current_feedforward"] = {"column": FEEDFORWARD_COLUMN}
    elif ff.size and ff[0] != 0:
        out["current_feedforward"] = {"offset_A": float(ff[0])}
    return out


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
            **_controller_extensions(result),
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
