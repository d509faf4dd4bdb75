"""Requirements of a design checked over the analysis grid (re-exported by :mod:`thsa_control.loops.analysis`).

Requirements
------------
A design's optional ``[requirements.<loop>]`` tables (``<loop>`` one of
``current_loop``, ``velocity_loop``, ``position_loop``) hold any of
``min_phase_margin_deg``, ``min_gain_margin_db`` (compared with
``|gain_margin_db|``), ``min_delay_margin_s``, ``min_bandwidth_hz``,
``max_sensitivity_peak``, ``max_overshoot_percent``, ``max_settling_time_s``,
``max_rise_time_s``.  :func:`check_requirements` checks them at every valid
grid point; a closed-loop-unstable point fails every requirement of that
loop.  Invalid points (zero speed, backlash edge) are not checked: they are
listed with their reason.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .catalog import REQUIREMENT_METRICS
from .design import REQUIREMENT_KEYS, REQUIREMENT_LOOPS
from ..errors import DesignError
from .linear import OperatingCondition
from .loop_analysis import METRICS, LoopAnalysis

__all__ = ["Violation", "RequirementRow", "RequirementCheck", "check_requirements", "REQUIREMENT_METRICS"]

#: requirement key -> (metric, comparison) (catalog.py holds the table)
_REQUIREMENTS = REQUIREMENT_METRICS
assert set(_REQUIREMENTS) == set(REQUIREMENT_KEYS)  # noqa: S101 - import-time consistency of two constants


@dataclass(frozen=True)
class Violation:
    """A requirement not met at a grid point.

    Attributes
    ----------
    loop, requirement, metric : str
    limit : float
    value : float
        The metric's value there (``|value|`` is compared for gain margins).
    index : int
    condition : OperatingCondition
    """

    loop: str
    requirement: str
    metric: str
    limit: float
    value: float
    index: int
    condition: OperatingCondition

    def text(self) -> str:
        """One line naming the requirement, the point and the value."""
        unit = METRICS[self.metric][0]
        return (f"{self.loop}.{self.requirement} = {self.limit:g} not met at {self.condition.label()}: "
                f"{self.metric} = {self.value:.4g} {unit}")


@dataclass(frozen=True)
class RequirementRow:
    """Summary of one requirement over the grid: worst value, where, how many points fail.

    ``uniform`` is True when the metric is the same at every valid point
    (the current loop's, for instance): then no point is worse than another.
    """

    loop: str
    requirement: str
    metric: str
    limit: float
    worst_value: float
    worst_index: int
    worst_condition: OperatingCondition | None
    n_failed: int
    passed: bool
    uniform: bool = False


@dataclass(frozen=True)
class RequirementCheck:
    """Requirements of a design checked at every valid grid point.

    Attributes
    ----------
    passed : bool
        Every requirement met at every valid point, every loop stable there.
    violations : tuple of Violation
    rows : tuple of RequirementRow
    unstable : tuple of (loop, index, condition)
        Valid points where a loop's closed loop is unstable.
    checked_points, skipped_points : int
        Valid points checked; invalid ones skipped (listed in the analysis).
    """

    passed: bool
    violations: tuple[Violation, ...]
    rows: tuple[RequirementRow, ...]
    unstable: tuple[tuple[str, int, OperatingCondition], ...]
    checked_points: int
    skipped_points: int

    def summary(self) -> str:
        """A few lines: PASS/FAIL, then the worst violation of each requirement."""
        head = "requirements: PASS" if self.passed else (
            f"requirements: FAIL ({len(self.violations)} violation(s) at {self.checked_points} valid points)")
        lines = [head]
        for row in self.rows:
            if not row.passed and row.worst_condition is not None:
                lines.append(f"  {row.loop}.{row.requirement} = {row.limit:g}: worst {row.metric} = "
                             f"{row.worst_value:.4g} at {row.worst_condition.label()} ({row.n_failed} point(s) fail)")
        for loop, _, cond in self.unstable:
            lines.append(f"  {loop}: closed loop unstable at {cond.label()}")
        return "\n".join(lines)

    def report(self) -> str:
        """Each requirement: limit, worst value and where (display units), PASS/FAIL."""
        from ..report.results import format_requirement_check

        return format_requirement_check(self)

    def to_dict(self) -> dict:
        """Verdict, every requirement's worst value, the violations (SI), JSON-able."""
        from ..report.results import requirement_check_to_dict

        return requirement_check_to_dict(self)

    def plot(self, ax=None):
        """Spare of each requirement at its worst point, coloured pass / close / fail; ``ax``: one Axes."""
        from ..report.results import plot_requirements

        return plot_requirements(self, ax)


def check_requirements(analysis: LoopAnalysis, requirements: Mapping | None = None) -> RequirementCheck:
    """Check ``[requirements.<loop>]`` at every valid point of ``analysis``.

    Parameters
    ----------
    analysis : LoopAnalysis
    requirements : mapping, optional
        ``{loop: {key: limit}}``; default ``analysis.design.requirements``.
        Keys: see the module notes (``thsa_control.loops.design.REQUIREMENT_KEYS``).

    Returns
    -------
    RequirementCheck

    Raises
    ------
    DesignError
        For an unknown loop or key.
    """
    req = analysis.design.requirements if requirements is None else requirements
    valid = analysis.valid
    violations, rows, unstable = [], [], []
    for loop, table in req.items():
        if loop not in REQUIREMENT_LOOPS:
            raise DesignError(analysis.design.source, f"unknown table [requirements.{loop}]")
        lm = analysis.loops[loop]
        for k in np.flatnonzero(valid & ~lm.stable):
            unstable.append((loop, int(k), analysis.conditions[k]))
        for key, limit in table.items():
            if key not in _REQUIREMENTS:
                raise DesignError(analysis.design.source, f"unknown key {key!r} in [requirements.{loop}]")
            metric, op = _REQUIREMENTS[key]
            vals = np.asarray(lm.metric(metric), float)
            cmp = np.abs(vals) if op == "abs>=" else vals
            with np.errstate(invalid="ignore"):
                ok = cmp >= limit if op.endswith(">=") else cmp <= limit
            ok = ok & lm.stable & ~np.isnan(cmp)
            fail = np.flatnonzero(valid & ~ok)
            for k in fail:
                violations.append(Violation(loop, key, metric, float(limit), float(vals[k]), int(k),
                                            analysis.conditions[k]))
            score = np.where(valid, cmp, np.nan)
            if np.all(np.isnan(score)):
                wk, wv, wc = -1, float("nan"), None
            else:
                wk = int(np.nanargmin(score) if op.endswith(">=") else np.nanargmax(score))
                wv, wc = float(vals[wk]), analysis.conditions[wk]
            fin = score[np.isfinite(score)]
            uniform = bool(fin.size > 1 and fin.size == np.count_nonzero(~np.isnan(score))
                           and np.ptp(fin) <= 1e-6 * max(np.max(np.abs(fin)), 1e-300))
            rows.append(RequirementRow(loop, key, metric, float(limit), wv, wk, wc, int(fail.size), fail.size == 0,
                                       uniform))
    return RequirementCheck(passed=not violations and not unstable, violations=tuple(violations), rows=tuple(rows),
                            unstable=tuple(unstable), checked_points=int(valid.sum()),
                            skipped_points=int((~valid).sum()))
