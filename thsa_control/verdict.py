"""One requirement set, one verdict: every ``[requirements.<loop>]`` entry and every ``[validation]`` limit.

``thsa tune`` (as constraints, and as the gate before it writes a design),
``thsa check`` and ``thsa report --check`` all judge a design with
:func:`evaluate_design`:

* **linear requirements**: every key of every ``[requirements.<loop>]`` table,
  checked at every valid point of the design's analysis grid
  (``[analysis]`` or the default grid: speeds x loads x temperatures, level B
  with temperature friction and the dragged standby rotor, one sample of
  computation delay) by :func:`thsa_control.loops.requirements.check_requirements`;
  a closed-loop-unstable valid point fails its loop (row ``<loop>.closed_loop_stable``);
* **validation limits**: every ``[validation]`` key (the defaults of
  :data:`~thsa_control.tuning.validation.DEFAULT_VALIDATION_REQUIREMENTS` and the
  current clamp where the design has none), on the nonlinear validation runs
  (:data:`~thsa_control.tuning.validation.VALIDATION_SUITE`) at every level and
  temperature judged (A-D at -55, -30, 25, 70 degC by default).

Each requirement gives one row: its worst value over everything judged, where,
the limit, how many points fail, and a status.  A requirement that could not be
evaluated (no valid point, a crashed simulation) has status ``error``: an error
is a failure, never a pass.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .errors import DesignError
from .loops.design import (
    REQUIREMENT_KEYS,
    REQUIREMENT_LOOPS,
    VALIDATION_KEYS,
    Design,
    validate_requirements,
    validate_validation,
)

__all__ = ["RequirementVerdict", "Verdict", "evaluate_design", "linear_verdict", "simulation_verdict",
           "validation_limits", "rows_from_metrics", "validate_requirements", "validate_validation", "REQUIREMENT_KEYS",
           "REQUIREMENT_LOOPS", "VALIDATION_KEYS", "DEFAULT_LEVELS", "DEFAULT_TEMPERATURES", "VALIDATION_METRICS"]

#: Levels and temperatures of the nonlinear validation runs judged by default.
DEFAULT_LEVELS: tuple[str, ...] = ("A", "B", "C", "D")
DEFAULT_TEMPERATURES: tuple[float, ...] = (-55.0, -30.0, 25.0, 70.0)

#: ``[validation]`` key -> (RunMetrics attribute, unit)
VALIDATION_METRICS: dict[str, tuple[str, str]] = {
    "max_speed_error_percent": ("speed_error_percent", "%"),
    "max_overshoot_percent": ("overshoot_percent", "%"),
    "max_settling_time_s": ("settling_time_s", "s"),
    "max_current_peak_A": ("current_peak_A", "A"),
    "max_current_rate_A_per_s": ("current_rate_peak_A_per_s", "A/s"),
}
assert set(VALIDATION_METRICS) == set(VALIDATION_KEYS)

_UNITS = {"min_phase_margin_deg": "deg", "min_gain_margin_db": "dB", "min_delay_margin_s": "s",
          "min_bandwidth_hz": "Hz", "max_sensitivity_peak": "-", "max_overshoot_percent": "%",
          "max_settling_time_s": "s", "max_rise_time_s": "s"}


@dataclass(frozen=True)
class RequirementVerdict:
    """One requirement judged over everything it applies to.

    Attributes
    ----------
    requirement : str
        ``<loop>.<key>`` (e.g. ``velocity_loop.min_delay_margin_s``), ``<loop>.closed_loop_stable`` or
        ``validation.<key>``.
    kind : str
        ``linear`` (analysis grid), ``simulation`` (nonlinear validation runs) or ``measured`` (rig runs).
    limit : float
    value : float
        The worst value (``|value|`` is what a gain margin is compared by).
    unit : str
    worst_point : str
        Where the worst value is.
    status : str
        ``pass``, ``fail`` or ``error`` (could not be evaluated: counts as a failure).
    checked, failed : int
        Points (or runs) judged and failing.
    origin : str
        ``design`` or where a default limit comes from.
    detail : str
    """

    requirement: str
    kind: str
    limit: float
    value: float
    unit: str
    worst_point: str
    status: str
    checked: int
    failed: int
    origin: str = "design"
    detail: str = ""

    @property
    def passed(self) -> bool:
        return self.status == "pass"

    def text(self) -> str:
        v = "never" if isinstance(self.value, float) and math.isinf(self.value) else (
            "-" if isinstance(self.value, float) and math.isnan(self.value) else f"{self.value:.4g}")
        lim = "" if math.isnan(self.limit) else f"{self.limit:g}"
        extra = f" ({self.failed} of {self.checked} fail)" if self.failed else f" ({self.checked} judged)"
        if self.detail:
            extra += f"; {self.detail}"
        return (f"{self.status.upper():5s} {self.requirement:42s} {v:>10s} {self.unit:4s} limit {lim:>8s}  "
                f"worst at {self.worst_point}{extra}")

    def as_dict(self) -> dict:
        def num(x):
            return None if (isinstance(x, float) and not math.isfinite(x)) else x

        return {"requirement": self.requirement, "kind": self.kind, "limit": num(self.limit),
                "value": num(self.value), "value_text": "never" if self.value == math.inf else None,
                "unit": self.unit, "worst_point": self.worst_point, "status": self.status,
                "checked": self.checked, "failed": self.failed, "origin": self.origin, "detail": self.detail}


@dataclass(frozen=True)
class Verdict:
    """Every requirement of a design judged; ``passed`` only when every row passes."""

    design: str
    rows: tuple[RequirementVerdict, ...]
    scope: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return bool(self.rows) and all(r.passed for r in self.rows)

    @property
    def failures(self) -> tuple[RequirementVerdict, ...]:
        return tuple(r for r in self.rows if not r.passed)

    def failing(self) -> tuple[str, ...]:
        """Names of the requirements not met (or not evaluated)."""
        return tuple(r.requirement for r in self.failures)

    def text(self) -> str:
        lines = [f"{'':5s} {'requirement':42s} {'worst':>10s}"] + [r.text() for r in self.rows]
        if self.passed:
            lines.append(f"verdict: PASS ({len(self.rows)} requirements)")
        else:
            lines.append(f"verdict: FAIL ({len(self.failures)} of {len(self.rows)} requirements not met)")
            for r in self.failures:
                lines.append(f"  {r.requirement} = {r.limit:g}: {r.status} at {r.worst_point}"
                             + (f" ({r.detail})" if r.detail else ""))
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return {"schema": "thsa-verdict/1", "design": self.design, "passed": self.passed,
                "failing": list(self.failing()), "scope": self.scope,
                "requirements": [r.as_dict() for r in self.rows], "runs": self.metrics}


# ------------------------------------------------------------------------------------------------ linear part
def linear_verdict(analysis, requirements: Mapping | None = None) -> list[RequirementVerdict]:
    """Rows of every ``[requirements.<loop>]`` key over the valid points of ``analysis`` (a LoopAnalysis)."""
    from .loops.requirements import check_requirements

    req = analysis.design.requirements if requirements is None else requirements
    chk = check_requirements(analysis, req)
    rows = []
    n_valid = int(chk.checked_points)
    for r in chk.rows:
        key = f"{r.loop}.{r.requirement}"
        if r.worst_condition is None:
            rows.append(RequirementVerdict(key, "linear", r.limit, float("nan"), _UNITS.get(r.requirement, ""),
                                           "-", "error", 0, 0, detail="no valid grid point to judge it at"))
            continue
        where = "every valid point (the same at each)" if r.uniform else r.worst_condition.label()
        value = abs(r.worst_value) if r.requirement == "min_gain_margin_db" else r.worst_value
        rows.append(RequirementVerdict(key, "linear", r.limit, float(value), _UNITS.get(r.requirement, ""), where,
                                       "pass" if r.passed else "fail", n_valid, r.n_failed))
    for loop in req:
        bad = [c for (lp, _, c) in chk.unstable if lp == loop]
        rows.append(RequirementVerdict(f"{loop}.closed_loop_stable", "linear", float("nan"), float(len(bad)),
                                       "pts", bad[0].label() if bad else "-", "fail" if bad else "pass",
                                       n_valid, len(bad), detail="closed loop unstable" if bad else ""))
    return rows


# ------------------------------------------------------------------------------------------------ nonlinear part
def validation_limits(design: Design) -> dict[str, tuple[float, str]]:
    """Limit and origin of every validation requirement judged (design, or the stated default)."""
    from .tuning.validation import DEFAULT_VALIDATION_REQUIREMENTS

    out = {k: (float(v), "default") for k, v in DEFAULT_VALIDATION_REQUIREMENTS.items()}
    out["max_current_peak_A"] = (float(design.current_limit), "default: the current clamp")
    out.update({k: (float(v), "design") for k, v in design.validation.items()})
    return out


def simulation_verdict(design: Design, params, *, levels: Sequence[str] = DEFAULT_LEVELS,
                       temperatures: Sequence[float] = DEFAULT_TEMPERATURES, scenarios: Sequence[str] | None = None,
                       effects: Sequence[str] | None = None,
                       progress: Callable[[str], None] | None = None) -> tuple[list[RequirementVerdict], dict]:
    """Rows of every validation limit over the suite at every level and temperature, and the run metrics.

    A run that crashes makes an ``error`` row naming it (a failure).
    """
    from .loops.analysis import DEFAULT_ANALYSIS_EFFECTS
    from .model import build_plant
    from .sim.simulate import SimulationSettings, Simulator
    from .tuning.validation import VALIDATION_SUITE, get_validation_scenario, run_metrics

    scenarios = tuple(scenarios or VALIDATION_SUITE)
    effects = tuple(DEFAULT_ANALYSIS_EFFECTS if effects is None else effects)
    limits = validation_limits(design)
    metrics, errors = {}, []
    for level in levels:
        sim = Simulator(build_plant(level, effects, params=params), SimulationSettings(output_period=None))
        for T in temperatures:
            if progress:
                progress(f"check: validation runs at level {level}, {T:g} degC ...")
            todo = []
            for name in scenarios:
                where = f"level {level}, {T:g} degC, {name}"
                try:
                    todo.append((name, where, get_validation_scenario(name).with_temperature(T)))
                except Exception as exc:
                    errors.append((where, f"{type(exc).__name__}: {exc}"))
            try:  # the suite at this level and temperature in one batch (each run has the bits of run())
                runs = sim.run_batch([sc for _, _, sc in todo], design, params) if todo else []
            except Exception:  # noqa: BLE001 -- a run fails: one at a time, so that each failure names its run
                runs = None
            for i, (name, where, sc) in enumerate(todo):
                try:
                    m = run_metrics(runs[i] if runs is not None else sim.run(sc, design, params))
                except Exception as exc:
                    errors.append((where, f"{type(exc).__name__}: {exc}"))
                    continue
                metrics[(level, float(T), name)] = m
    rows = rows_from_metrics(limits, metrics, errors, "simulation",
                              lambda key: f"level {key[0]}, {key[1]:g} degC, {key[2]}")
    doc = {f"{lv}|{T:g}|{n}": m.as_dict() for (lv, T, n), m in metrics.items()}
    return rows, doc


def rows_from_metrics(limits, metrics: dict, errors, kind: str, label) -> list[RequirementVerdict]:
    """One row per validation limit over ``metrics`` (key -> RunMetrics); ``errors`` ((where, message), ...)
    are runs that could not be judged (they make the rows ``error``); ``label(key)`` names a run."""
    rows = []
    for key, (limit, origin) in limits.items():
        attr, unit = VALIDATION_METRICS[key]
        worst, wk, n_fail = -math.inf, None, 0
        for k, m in metrics.items():
            v = float(getattr(m, attr))
            if math.isnan(v) or v > limit:
                n_fail += 1
            score = math.inf if math.isnan(v) else v
            if score > worst:
                worst, wk = score, k
        if wk is None:
            why = "; ".join(f"{w}: {e}" for w, e in errors[:3]) if errors else "no run to judge it on"
            rows.append(RequirementVerdict(f"validation.{key}", kind, limit, float("nan"), unit, "-", "error",
                                           len(errors), len(errors), origin, why))
            continue
        m = metrics[wk]
        where = label(wk) + (f" [{m.worst_plateau}]" if attr == "speed_error_percent" else "")
        status = "pass" if n_fail == 0 else "fail"
        detail = ""
        if errors:
            status = "error" if status == "pass" else status
            detail = f"{len(errors)} run(s) could not be judged: " + "; ".join(f"{w}: {e}" for w, e in errors[:3])
        rows.append(RequirementVerdict(f"validation.{key}", kind, limit, float(getattr(m, attr)), unit, where,
                                       status, len(metrics) + len(errors), n_fail + len(errors), origin, detail))
    return rows


# ------------------------------------------------------------------------------------------------ both
def evaluate_design(design: Design, params, *, analysis=None, analysis_settings=None,
                    levels: Sequence[str] = DEFAULT_LEVELS, temperatures: Sequence[float] = DEFAULT_TEMPERATURES,
                    scenarios: Sequence[str] | None = None, effects: Sequence[str] | None = None,
                    linear: bool = True, simulation: bool = True,
                    progress: Callable[[str], None] | None = None) -> Verdict:
    """The verdict on every requirement of ``design``.

    Parameters
    ----------
    analysis : LoopAnalysis, optional
        A grid analysis already computed (``thsa report``); default: the design's analysis grid
        (``AnalysisSettings.from_design(design)``, or ``analysis_settings``).
    levels, temperatures, scenarios, effects
        What the nonlinear validation runs cover.
    linear, simulation : bool
        Judge the linear requirements / the validation runs (a part not judged is stated in ``scope``).
    """
    from .loops.analysis import AnalysisSettings, analyse_loops

    rows: list[RequirementVerdict] = []
    scope: dict = {}
    if linear and design.requirements:
        if analysis is None:
            st = analysis_settings or AnalysisSettings.from_design(design)
            if progress:
                progress(f"check: linear requirements over the analysis grid (level {st.level}, "
                         f"{len(st.nut_speeds)} speeds x {len(st.load_forces)} loads x {len(st.temperatures)} "
                         "temperatures) ...")
            analysis = analyse_loops(design, params, settings=st)
        st = analysis.settings
        scope["linear"] = {"level": st.level, "effects": list(st.effects),
                           "nut_speeds_mm_s": [v * 1e3 for v in st.nut_speeds],
                           "loads_kN": [f / 1e3 for f in st.load_forces], "temperatures_C": list(st.temperatures),
                           "computation_delay_samples": design.computation_delay_samples,
                           "valid_points": int(np.count_nonzero(analysis.valid)), "points": len(analysis.valid)}
        rows += linear_verdict(analysis)
    if simulation:
        srows, metrics = simulation_verdict(design, params, levels=levels, temperatures=temperatures,
                                            scenarios=scenarios, effects=effects, progress=progress)
        from .tuning.validation import VALIDATION_SUITE

        scope["simulation"] = {"levels": list(levels), "temperatures_C": [float(t) for t in temperatures],
                               "scenarios": list(scenarios or VALIDATION_SUITE)}
        rows += srows
    else:
        metrics = {}
    if not rows:
        raise DesignError(design.source, "nothing to judge: no [requirements] table and no validation run")
    return Verdict(f"{design.source} ({design.name})", tuple(rows), scope, metrics)
