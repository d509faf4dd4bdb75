"""How reports show numbers: metrics in display units, requirements in words, gain margins, verdict colours.

Every unit comes from the one display-unit table
(:data:`thsa_control.data.units.DISPLAY_UNITS`); this module only says which
quantity each loop metric is.  No matplotlib here: the HTML writers and the
plot functions both use it.
"""

from __future__ import annotations

import math

import numpy as np

from ..data.units import DisplayUnit, display_unit
from ..loops.catalog import METRIC_LABELS, METRICS, REQUIREMENT_METRICS

__all__ = ["metric_display", "metric_heading", "fmt", "fmt_metric", "requirement_text", "requirement_limit_text", "gain_margins_text",
           "GAIN_MARGIN_MEANING", "requirement_status", "requirement_for", "NEAR_FRACTION", "STATUS_COLORS",
           "STATUS_LABELS"]

#: Metric -> quantity of the display-unit table (``None``: shown in its own unit, deg, dB, %, -).
_METRIC_QUANTITY = {
    "crossover_hz": "frequency", "bandwidth_hz": "frequency",
    "delay_margin_s": "time", "rise_time_s": "time", "settling_time_s": "time", "load_step_recovery_s": "time",
}
_LOAD_STEP_QUANTITY = {"velocity_loop": "velocity_load_step", "position_loop": "position_load_step"}
#: The position loop's step responses and recovery take seconds: shown in s, not ms.
_SLOW_LOOPS = ("position_loop",)

#: A requirement met with less than this fraction of its limit to spare is shown as "close to the limit".
NEAR_FRACTION = 0.15
#: Status (0 fails, 1 close to the limit, 2 passes with room, 3 no requirement) -> colour.
STATUS_COLORS = ("#ef9a9a", "#ffe082", "#a5d6a7", "#e3e8ef")
STATUS_LABELS = ("fails the requirement", f"passes, within {NEAR_FRACTION:.0%} of the limit",
                 f"passes with more than {NEAR_FRACTION:.0%} to spare", "no requirement on this metric")

#: What the two gain margins of a loop mean, for captions and notes.
GAIN_MARGIN_MEANING = ("Lower gain margin: by how much the loop gain may fall before the loop goes unstable "
                       "(negative dB: the loop is conditionally stable, as with the Stribeck friction under an "
                       "aiding load). Upper gain margin: by how much it may rise. A requirement 'gain margin >= X dB'"
                       " asks both to be at least X dB away from 0 dB.")


def metric_display(loop: str, name: str) -> DisplayUnit:
    """Display unit of metric ``name`` of ``loop``."""
    if name == "load_step_peak":
        return display_unit(_LOAD_STEP_QUANTITY.get(loop, "dimensionless"))
    q = _METRIC_QUANTITY.get(name)
    if q == "time" and loop in _SLOW_LOOPS and name != "delay_margin_s":
        q = "duration"
    if q is None:
        unit = METRICS[name][0]
        return DisplayUnit(name, unit, unit, 1.0)
    return display_unit(q)


def metric_heading(loop: str, name: str) -> str:
    """Column heading: ``"delay margin [ms]"``."""
    return metric_display(loop, name).label(METRIC_LABELS[name])


def fmt(x, digits: int = 4) -> str:
    """A number for a table: ``-`` for none/NaN, ``inf``, ``yes``/``no`` for booleans."""
    if x is None:
        return "-"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    x = float(x)
    if math.isnan(x):
        return "-"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.{digits}g}"


def fmt_metric(loop: str, name: str, value, digits: int = 4, *, unit: bool = False) -> str:
    """``value`` [SI] of metric ``name`` in its display unit (with the unit when ``unit``)."""
    du = metric_display(loop, name)
    text = fmt(du.to_display(value) if value is not None and np.isfinite(value) else value, digits)
    return f"{text} {du.unit}" if unit and du.unit not in ("", "-") and text not in ("-",) else text


def requirement_for(requirements: dict, metric: str) -> tuple[str, float, str] | None:
    """``(key, limit, comparison)`` of the requirement on ``metric`` in one loop's table, else None."""
    for key, limit in requirements.items():
        m, op = REQUIREMENT_METRICS.get(key, (None, None))
        if m == metric:
            return key, float(limit), op
    return None


def requirement_limit_text(loop: str, key: str, limit: float) -> str:
    """``">= 45 deg"``, ``">= 2 ms"``; a gain margin's is ``"|GM| >= 6 dB"``."""
    metric, op = REQUIREMENT_METRICS[key]
    sign = "<=" if op == "<=" else ">="
    return f"{'|GM| ' if op == 'abs>=' else ''}{sign} {fmt_metric(loop, metric, limit, unit=True)}"


def requirement_text(loop: str, key: str, limit: float) -> str:
    """``"phase margin >= 45 deg"``, ``"delay margin >= 2 ms"``, ``"gain margin, lower and upper: |GM| >= 6 dB"``."""
    metric, _ = REQUIREMENT_METRICS[key]
    label = "gain margin, lower and upper:" if metric == "gain_margin_db" else METRIC_LABELS[metric]
    return f"{label} {requirement_limit_text(loop, key, limit)}"


def gain_margins_text(lower_db: float, upper_db: float) -> str:
    """``"lower -13.4 dB / upper +29.0 dB"`` (``"no lower"`` for a margin the loop does not have).

    >>> gain_margins_text(-13.39, 29.04), gain_margins_text(float("inf"), 43.8)
    ('lower -13.4 dB / upper +29.0 dB', 'no lower / upper +43.8 dB')
    """
    def one(name, x):
        return f"no {name}" if x is None or not np.isfinite(x) else f"{name} {x:+.1f} dB"
    return f"{one('lower', lower_db)} / {one('upper', upper_db)}"


def requirement_status(values, limit: float | None, op: str | None, near: float = NEAR_FRACTION) -> np.ndarray:
    """Per value: 0 fails, 1 passes within ``near`` x |limit| of it, 2 passes with room, 3 no requirement.

    NaN values get 3 too (not analysed; the caller hatches them).  ``'abs>='`` compares ``|value|``.
    """
    v = np.asarray(values, float)
    out = np.full(v.shape, 3, dtype=int)
    if limit is None or op is None:
        return out
    x = np.abs(v) if op == "abs>=" else v
    ok = ~np.isnan(x)
    room = near * abs(limit)
    with np.errstate(invalid="ignore"):
        if op.endswith(">="):
            out[ok] = np.where(x[ok] < limit, 0, np.where(x[ok] < limit + room, 1, 2))
        else:
            out[ok] = np.where(x[ok] > limit, 0, np.where(x[ok] > limit - room, 1, 2))
    return out
