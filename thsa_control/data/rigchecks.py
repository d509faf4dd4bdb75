"""Checks of a ``thsa-rig-run/1`` run beyond its syntax (for ``rigdata``).

The JSON metadata and its controller block, gaps in measured columns, the
unit heuristics of the :mod:`~thsa_control.data.rigdata` docstring (rad/s for
rpm, metres for mm, m/s commands, milliseconds, kelvin, kilonewtons) and the
cross-checks of the JSON against the CSV (sample rate vs time column,
temperature column vs JSON temperature).  Problems and warnings are appended
to the lists passed in; nothing is raised here.  Imports numpy, the standard
library and the format module only.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from thsa_control.data.rigformat import (
    _MAX_TEMPERATURE_C,
    _MIN_FIT_SAMPLES,
    _MIN_R2,
    _RAD_S_PER_RPM,
    DEFAULT_GEAR_RATIO,
    DEFAULT_SCREW_LEAD_MM,
    FORMAT_TAG,
    MAX_ROWS_LISTED,
    ColumnSpec,
    CurrentFeedForward,
    CurrentLoopGains,
    PositionLoopGains,
    RigController,
    VelocityLoopGains,
    _add_rows,
    _number,
    true_runs,
    speed_integral,
)

def _fit_scale(measured: np.ndarray, expected: np.ndarray) -> tuple[float, float]:
    """Least-squares ``measured ~ k expected`` through 0: (k, explained fraction)."""
    sxx = float(expected @ expected)
    syy = float(measured @ measured)
    if sxx <= 0.0 or syy <= 0.0:
        return math.nan, 0.0
    k = float(measured @ expected) / sxx
    resid = measured - k * expected
    return k, 1.0 - float(resid @ resid) / syy


def _verdict(k: float, r2: float, tol: float) -> str:
    """Classify a kinematic ratio: ok, rad_s, metre, x1000, sign, other, undecided."""
    if not math.isfinite(k) or r2 < _MIN_R2:
        return "undecided"
    for name, target in (("ok", 1.0), ("x1000", 1000.0), ("sign", -1.0),
                         ("rad_s", _RAD_S_PER_RPM), ("metre", 1e-3)):
        if abs(k / target - 1.0) <= tol:
            return name
    return "other"


# ------------------------------------------------------------------------ JSON
def _load_json(path: Path, problems: list) -> dict | None:
    where = path.name
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        problems.append((where, None, f"JSON file not found: {path}"))
        return None
    except (OSError, UnicodeDecodeError) as exc:
        problems.append((where, None, f"cannot read JSON file: {exc}"))
        return None
    try:
        meta = json.loads(text, parse_constant=_reject_constant)
    except (json.JSONDecodeError, ValueError) as exc:
        problems.append((where, None, f"malformed JSON: {exc}"))
        return None
    except RecursionError:
        problems.append((where, None, "malformed JSON: nested too deeply"))
        return None
    if not isinstance(meta, dict):
        problems.append((where, None, f"top level must be an object, got {type(meta).__name__}"))
        return None
    return meta


def _reject_constant(name: str):
    raise ValueError(f"{name} is not valid JSON")


def _check_metadata(meta: dict, where: str, has_temperature_column: bool, problems: list,
                    default_kinematics: tuple[float, float] | None = None):
    """Validate the JSON object; return (controller, motor_disabled, lead_mm, ratio).

    ``lead_mm, ratio`` are the ``rig`` block's, else ``default_kinematics``, else FORMAT.md's seed values.
    """
    def bad(key: str, message: str) -> None:
        problems.append((f"{where}:{key}", None, message))

    fmt = meta.get("format")
    if "format" not in meta:
        bad("format", f"missing; must be '{FORMAT_TAG}'")
    elif fmt != FORMAT_TAG:
        bad("format", f"is {fmt!r}, expected '{FORMAT_TAG}'")
    if "name" in meta and not isinstance(meta["name"], str):
        bad("name", "must be a string")
    if "temperature_C" in meta:
        temp = _number(meta["temperature_C"])
        if temp is None:
            bad("temperature_C", f"must be a finite number [degC], got {meta['temperature_C']!r}")
        elif temp > _MAX_TEMPERATURE_C:
            bad("temperature_C", f"{temp:g} degC is above {_MAX_TEMPERATURE_C:g} degC: "
                                 "looks like kelvin")
        elif temp < -273.15:
            bad("temperature_C", f"{temp:g} degC is below absolute zero")
    elif not has_temperature_column:
        bad("temperature_C", "missing; required when the CSV has no temperature_C column")
    if "sample_rate_hz" in meta:
        rate = _number(meta["sample_rate_hz"])
        if rate is None or rate <= 0:
            bad("sample_rate_hz", f"must be a positive number [Hz], got {meta['sample_rate_hz']!r}")
    disabled = meta.get("motor_disabled_when_cmd_zero", False)
    if not isinstance(disabled, bool):
        bad("motor_disabled_when_cmd_zero", f"must be true or false, got {disabled!r}")
        disabled = False
    lead_mm, ratio = default_kinematics or (DEFAULT_SCREW_LEAD_MM, DEFAULT_GEAR_RATIO)
    rig = meta.get("rig")
    if rig is not None and not isinstance(rig, dict):
        bad("rig", "must be an object")
    elif isinstance(rig, dict):
        for key in ("screw_lead_mm", "gear_ratio"):
            if key in rig:
                value = _number(rig[key])
                if value is None or value <= 0:
                    bad(f"rig.{key}", f"must be a positive number, got {rig[key]!r}")
                elif key == "screw_lead_mm":
                    lead_mm = value
                else:
                    ratio = value
    controller = _parse_controller(meta["controller"], bad) if "controller" in meta else None
    return controller, disabled, lead_mm, ratio


_LOOPS = {
    "velocity_loop": (VelocityLoopGains, (("kp_A_per_rad_s", "kp", False),
                                          ("ki_A_per_rad", "ki", False),
                                          ("current_limit_A", "current_limit", True))),
    "current_loop": (CurrentLoopGains, (("kp_V_per_A", "kp", False),
                                        ("ki_V_per_A_s", "ki", False),
                                        ("voltage_limit_V", "voltage_limit", True))),
}


def _parse_controller(block: Any, bad: Callable[[str, str], None]) -> RigController | None:
    if not isinstance(block, dict):
        bad("controller", "must be an object")
        return None
    loops, ok = {}, True
    for loop, (cls, keys) in _LOOPS.items():
        sub = block.get(loop)
        if not isinstance(sub, dict):
            bad(f"controller.{loop}", "missing or not an object")
            ok = False
            continue
        values = {}
        for key, attr, strictly_positive in keys:
            value = _number(sub.get(key))
            if key not in sub:
                bad(f"controller.{loop}.{key}", "missing")
            elif value is None:
                bad(f"controller.{loop}.{key}", f"must be a finite number, got {sub[key]!r}")
            elif value < 0 or (strictly_positive and value == 0):
                bad(f"controller.{loop}.{key}",
                    f"must be {'> 0' if strictly_positive else '>= 0'}, got {value:g}")
            else:
                values[attr] = value
                continue
            ok = False
        known = {k for k, _, _ in keys}
        loops[loop] = cls(**values, extra={k: v for k, v in sub.items() if k not in known}) \
            if len(values) == 3 else None
    period = _number(block.get("control_period_s"))
    if period is None or period <= 0:
        bad("controller.control_period_s",
            f"must be a positive number [s], got {block.get('control_period_s', 'nothing')!r}")
        ok = False
    position = _parse_position_loop(block["position_loop"], bad) if "position_loop" in block else None
    feedforward = _parse_feedforward(block["current_feedforward"], bad) if "current_feedforward" in block else None
    if not ok or position is False or feedforward is False:
        return None
    extra = {k: v for k, v in block.items() if k not in _CONTROLLER_KEYS}
    return RigController(loops["velocity_loop"], loops["current_loop"], period, extra, position, feedforward)


_CONTROLLER_KEYS = ("velocity_loop", "current_loop", "control_period_s", "position_loop", "current_feedforward")
#: controller.position_loop: JSON key -> (attribute, SI factor, required)
_POSITION_KEYS = {"kp_1_per_s": ("kp", 1.0, True), "max_speed_mm_s": ("max_speed", 1e-3, False),
                  "accel_limit_mm_s2": ("accel_limit", 1e-3, False), "jerk_limit_mm_s3": ("jerk_limit", 1e-3, False)}


def _parse_position_loop(sub: Any, bad: Callable[[str, str], None]):
    """``controller.position_loop`` (extension): a PositionLoopGains, or False after reporting."""
    where = "controller.position_loop"
    if not isinstance(sub, dict):
        bad(where, f"must be an object, got {sub!r}")
        return False
    values, ok = {}, True
    for key, (attr, factor, required) in _POSITION_KEYS.items():
        if key not in sub:
            if required:
                bad(f"{where}.{key}", "missing (the position loop's P gain [1/s])")
                ok = False
            continue
        value = _number(sub[key])
        if value is None and sub[key] is None and not required:
            continue  # null: unlimited
        if value is None or value <= 0:
            bad(f"{where}.{key}", f"must be a positive number, got {sub[key]!r}")
            ok = False
            continue
        values[attr] = value * factor
    if not ok:
        return False
    return PositionLoopGains(**values, extra={k: v for k, v in sub.items() if k not in _POSITION_KEYS})


def _parse_feedforward(sub: Any, bad: Callable[[str, str], None]):
    """``controller.current_feedforward`` (extension): a CurrentFeedForward, or False after reporting."""
    where = "controller.current_feedforward"
    if not isinstance(sub, dict):
        bad(where, f"must be an object, got {sub!r}")
        return False
    if "offset_A" not in sub and "column" not in sub:
        bad(where, "needs offset_A [A] and/or column (a CSV column in A)")
        return False
    ok, offset, column = True, 0.0, None
    if "offset_A" in sub:
        value = _number(sub["offset_A"])
        if value is None:
            bad(f"{where}.offset_A", f"must be a finite number [A], got {sub['offset_A']!r}")
            ok = False
        else:
            offset = value
    if "column" in sub:
        column = sub["column"]
        if not isinstance(column, str) or not column:
            bad(f"{where}.column", f"must be the name of a CSV column, got {column!r}")
            ok = False
    if not ok:
        return False
    return CurrentFeedForward(offset, column, {k: v for k, v in sub.items() if k not in ("offset_A", "column")})


def _check_controller_columns(controller: RigController | None, columns: dict, extra: dict, where: str,
                              problems: list) -> None:
    """The CSV columns the controller block's extensions need (read_run, after the table)."""
    if controller is None:
        return
    if controller.position_loop is not None and "position_cmd_mm" not in columns:
        problems.append((f"{where}:controller.position_loop", None,
                         "the position loop needs the position command: the CSV has no position_cmd_mm column"))
    ff = controller.current_feedforward
    if ff is None or ff.column is None:
        return
    key = f"{where}:controller.current_feedforward.column"
    if ff.column not in extra:
        standard = " (a standard column, not a current)" if ff.column in columns else ""
        problems.append((key, None, f"names column {ff.column!r}, which the CSV does not have as an extra "
                                    f"column{standard}; extra columns: {', '.join(extra) or 'none'}"))
        return
    values = extra[ff.column]
    if values.dtype.kind not in "fiu":
        problems.append((key, None, f"column {ff.column!r} holds text, not currents [A]"))
        return
    bad_rows = np.flatnonzero(~np.isfinite(values))
    if bad_rows.size:
        _add_rows(problems, ff.column, bad_rows, lambda i: "missing value in the current feed-forward column "
                                                           "(every sample is needed)")


def _check_gaps(spec: ColumnSpec, label: str, empty: np.ndarray, problems: list,
                warnings: list) -> None:
    singles, listed = [], []
    for start, stop in true_runs(empty):
        if stop - start == 1 and spec.role == "measured":
            singles.append(start)
        elif stop - start == 1:
            listed.append((start, "missing value (empty cell)"))
        else:
            listed.append((start, f"gap of {stop - start} samples (rows {start + 1} to {stop}); "
                                  "at most one isolated missing sample is tolerated, and only "
                                  "in a measured column"))
    messages = dict(listed)
    _add_rows(problems, label, np.array([s for s, _ in listed], dtype=int), messages.__getitem__)
    for start in singles[:MAX_ROWS_LISTED]:
        warnings.append(f"column '{label}', row {start + 1}: single missing sample, "
                        "kept as NaN (not interpolated)")
    if len(singles) > MAX_ROWS_LISTED:
        warnings.append(f"column '{label}': {len(singles) - MAX_ROWS_LISTED} more single "
                        "missing samples, kept as NaN")


def _check_units(columns, clean, label_of, meta, lead_mm, ratio, problems, warnings):
    """Kinematic and range heuristics of the module docstring.

    Speed checks need a clean speed command and column only; the time-base and
    position checks also need a clean ``time_s``.
    """
    time_ok = "time_s" in clean
    t = columns.get("time_s")
    dt = np.diff(t) if time_ok else None
    nominal = _number(meta.get("sample_rate_hz")) if meta else None
    if nominal and time_ok:
        r = float(np.median(dt)) * nominal
        if abs(r / 1000.0 - 1.0) <= 0.2:
            problems.append((label_of["time_s"], 2,
                             f"median time step {np.median(dt):.6g} is ~1000x 1/sample_rate_hz "
                             f"({1.0 / nominal:.6g} s): time_s looks like milliseconds"))
            return  # the kinematic checks below integrate over time
        elif abs(r - 1.0) > SAMPLE_RATE_TOLERANCE:
            problems.append((label_of["time_s"], None,
                             f"median time step {np.median(dt):.6g} s ({1.0 / np.median(dt):.6g} Hz) contradicts "
                             f"the JSON's sample_rate_hz {nominal:g} (more than "
                             f"{SAMPLE_RATE_TOLERANCE:.0%} apart)"))
            return
    _check_temperature(columns, clean, label_of, meta, problems)
    if "speed_cmd_mm_s" not in clean:
        return
    _check_kilonewtons(columns, clean, label_of, lead_mm, ratio, problems)
    cmd = columns["speed_cmd_mm_s"]
    enabled = np.ones(cmd.shape, dtype=bool)
    if "primary_enable" in columns or "standby_enable" in columns:
        enabled = (columns.get("primary_enable", np.ones(cmd.shape)) == 1) | \
                  (columns.get("standby_enable", np.zeros(cmd.shape)) == 1)
    peak = float(np.max(np.abs(cmd)))
    verdicts: dict[str, tuple[str, float, np.ndarray]] = {}
    screw_rpm_per_mm_s = 60.0 / lead_mm
    for column, gain in (("motor_speed_rpm", screw_rpm_per_mm_s * ratio),
                         ("screw_speed_rpm", screw_rpm_per_mm_s)):
        if column not in clean or peak <= 0:
            continue
        meas = columns[column]
        moving = (np.abs(cmd) >= 0.25 * peak) & enabled & np.isfinite(meas)
        if moving.sum() >= _MIN_FIT_SAMPLES:
            k, r2 = _fit_scale(meas[moving], gain * cmd[moving])
            verdicts[column] = (_verdict(k, r2, 0.25), k, np.flatnonzero(moving))
    if "nut_position_mm" in clean and time_ok and t.size >= _MIN_FIT_SAMPLES:
        pos = columns["nut_position_mm"]
        ok = np.isfinite(pos)
        travel = speed_integral(t, cmd)
        x, y = travel[ok] - travel[ok].mean(), pos[ok] - pos[ok].mean()
        k, r2 = _fit_scale(y, x)
        verdicts["nut_position_mm"] = (_verdict(k, r2, 0.3), k, np.flatnonzero(ok))
    kinds = {v[0] for v in verdicts.values()}
    if "x1000" in kinds and "ok" not in kinds:
        first = min(int(v[2][0]) for v in verdicts.values() if v[0] == "x1000")
        problems.append((label_of["speed_cmd_mm_s"], first + 1,
                         "measured speeds/position are ~1000x the kinematic prediction: "
                         "speed_cmd_mm_s looks like m/s"))
        return
    expected = {"motor_speed_rpm": f"{screw_rpm_per_mm_s * ratio:g} rpm per mm/s",
                "screw_speed_rpm": f"{screw_rpm_per_mm_s:g} rpm per mm/s",
                "nut_position_mm": "1 mm per mm of integrated speed command"}
    for column, (verdict, k, rows) in verdicts.items():
        label = label_of[column]
        what = (f"{k:.4g} x the kinematic prediction ({expected[column]}, least-squares fit "
                f"over {rows.size} samples, rows {rows[0] + 1} to {rows[-1] + 1})")
        if verdict == "rad_s" and column != "nut_position_mm":
            problems.append((label, int(rows[0]) + 1, f"{what}: looks like rad/s, not rpm"))
        elif verdict == "metre" and column == "nut_position_mm":
            problems.append((label, int(rows[0]) + 1, f"{what}: looks like metres, not mm"))
        elif verdict == "sign":
            warnings.append(f"column '{label}': {what}: sign convention reversed?")
        elif verdict not in ("ok", "undecided"):
            warnings.append(f"column '{label}': {what}: check its unit and the rig kinematics")


#: JSON sample_rate_hz and the CSV's median time step may differ by this fraction.
SAMPLE_RATE_TOLERANCE = 0.1
#: JSON temperature_C may lie this far outside the range of the CSV's temperature column [K].
TEMPERATURE_TOLERANCE_K = 10.0
#: Seed motor torque constant [N m/A] (papers: 1.5 p psi = 1.5 x 3 x 0.072); only its order of
#: magnitude matters to the kN check, which needs a slope 100..10000x the prediction.
_SEED_TORQUE_CONSTANT = 0.324
_KN_MAX_LOAD = 200.0  # [N]: a run in newtons whose largest load is below this is unloaded
_KN_MIN_R2 = 0.5


def _check_temperature(columns, clean, label_of, meta, problems):
    """JSON temperature_C against the CSV's temperature column (both given)."""
    temp = _number(meta.get("temperature_C")) if meta else None
    if temp is None or "temperature_C" not in clean:
        return
    col = columns["temperature_C"]
    col = col[np.isfinite(col)]
    if not col.size:
        return
    lo, hi = float(col.min()), float(col.max())
    if temp < lo - TEMPERATURE_TOLERANCE_K or temp > hi + TEMPERATURE_TOLERANCE_K:
        problems.append((label_of["temperature_C"], None,
                         f"ranges {lo:g} .. {hi:g} degC, which contradicts the JSON's temperature_C = {temp:g} "
                         f"degC (more than {TEMPERATURE_TOLERANCE_K:g} K apart)"))


def _check_kilonewtons(columns, clean, label_of, lead_mm, ratio, problems):
    """``load_force_N`` in kN: tiny loads that the motor current follows ~1000x too steeply.

    During motion the motor's quadrature current grows with the load by about
    ``lead / (2 pi N Kt)`` A per N (1e-4 A/N for the seed actuator).  A run
    whose largest |load| is below 200 "N" but whose current rises with |load|
    100 to 10000 times faster than that (a linear fit explaining half of the
    current's variance) carries kilonewtons.  No current column, no motion,
    constant load or a poor fit: no verdict.
    """
    if "load_force_N" not in clean or "motor_current_A" not in clean:
        return
    force, current, cmd = columns["load_force_N"], columns["motor_current_A"], columns["speed_cmd_mm_s"]
    if not np.isfinite(force).all() or float(np.max(np.abs(force))) > _KN_MAX_LOAD:
        return
    peak = float(np.max(np.abs(cmd)))
    if peak <= 0:
        return
    moving = (np.abs(cmd) >= 0.25 * peak) & np.isfinite(current)
    if moving.sum() < _MIN_FIT_SAMPLES:
        return
    x, y = np.abs(force[moving]), np.abs(current[moving])
    x0, y0 = x - x.mean(), y - y.mean()
    sxx, syy = float(x0 @ x0), float(y0 @ y0)
    if sxx <= 0.0 or syy <= 0.0:
        return
    slope = float(x0 @ y0) / sxx
    r2 = 1.0 - float(((y0 - slope * x0) ** 2).sum()) / syy
    expected = lead_mm * 1e-3 / (2.0 * math.pi * ratio * _SEED_TORQUE_CONSTANT)  # [A/N]
    k = slope / expected
    if r2 >= _KN_MIN_R2 and 100.0 <= k <= 10000.0:
        rows = np.flatnonzero(moving)
        problems.append((label_of["load_force_N"], int(rows[0]) + 1,
                         f"largest |load| is {float(np.max(np.abs(force))):.3g} but the motor current rises "
                         f"{slope:.3g} A per unit of load during motion, {k:.0f}x the {expected:.2g} A/N the "
                         f"kinematics and a ~{_SEED_TORQUE_CONSTANT} N m/A motor predict (fit over {rows.size} "
                         "samples): load_force_N looks like kN"))
