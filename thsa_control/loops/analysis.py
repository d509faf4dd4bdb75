"""Loop analysis of the THSA cascade on linear models: the public entry points.

Everything a report needs for one design (:func:`analyse_design`): the grid
analysis of the three discrete loops (:mod:`.loop_analysis`: margins,
bandwidth, Ms, steps, load steps, worst points, invalid points), the
requirement check (:mod:`.requirements`), describing-function limit cycles
(:mod:`.describing`), the active/standby configurations (here) and the
nonlinear switch-over transient (:mod:`.switching`).  The loops as
python-control objects at one operating point are in :mod:`.statespace`.
Every public name of those modules is importable from here.  This module
owns no plotting (``report/analysis_report.py`` draws the results).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

from .loopmath import MarginSet, StepMetrics, loop_margins, step_metrics
from .describing import LimitCycle, describing_functions, predict_limit_cycles
from .design import Design
from .linear import DEFAULT_EFFECTS, DEFAULT_LEVEL, ConditionGrid, PlantModel, plant_model
from .loop_analysis import (
    LOOPS,
    METRIC_LABELS,
    METRICS,
    AnalysisSettings,
    LoopAnalysis,
    LoopMetrics,
    WorstPoint,
    analyse_loops,
    metric_unit,
)
from .requirements import RequirementCheck, RequirementRow, Violation, check_requirements
from ..model.params import ParameterSet, default_parameters
from .statespace import closed_loop, open_loop

__all__ = [
    "DEFAULT_ANALYSIS_EFFECTS",
    "DEFAULT_LEVEL",
    "LOOPS",
    "METRICS",
    "METRIC_LABELS",
    "metric_unit",
    "AnalysisSettings",
    "MarginSet",
    "loop_margins",
    "StepMetrics",
    "step_metrics",
    "LoopMetrics",
    "LoopAnalysis",
    "WorstPoint",
    "analyse_loops",
    "Violation",
    "RequirementRow",
    "RequirementCheck",
    "check_requirements",
    "LimitCycle",
    "describing_functions",
    "predict_limit_cycles",
    "DesignAnalysis",
    "analyse_design",
    "ConfigurationAnalysis",
    "analyse_configurations",
    "open_loop",
    "closed_loop",
]

#: Effects the analysis adds to its level by default (CLI and API alike): the cold friction law and the
#: standby motor, whose rotor the primary drags (an alias of ``loops.linear.DEFAULT_EFFECTS``).
DEFAULT_ANALYSIS_EFFECTS: tuple[str, ...] = DEFAULT_EFFECTS


# ----------------------------------------------------------------------------------------------------------------
# active / standby configurations
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ConfigurationAnalysis:
    """Loops of the two channel configurations (``standby_motor`` added).

    Attributes
    ----------
    primary : LoopAnalysis
        Primary active, standby off with its rotor dragged.
    standby : LoopAnalysis
        Standby active, primary off (its rotor dragged).
    """

    primary: LoopAnalysis
    standby: LoopAnalysis

    def rows(self) -> list[dict]:
        """One row per configuration, loop and point: the margins (nan, and ``stable`` None, where the point
        is not analysed)."""
        out = []
        for name, a in (("primary active", self.primary), ("standby active", self.standby)):
            for loop, lm in a.loops.items():
                for k, c in enumerate(a.conditions):
                    m = lm.margins
                    ok = bool(a.valid[k])  # no numbers where there is no linear loop
                    out.append({"configuration": name, "loop": loop, "condition": c.label(), "valid": ok,
                                "crossover_hz": float(m.crossover_hz[k]) if ok else float("nan"),
                                "phase_margin_deg": float(m.phase_margin_deg[k]) if ok else float("nan"),
                                "gain_margin_db": float(m.gain_margin_db[k]) if ok else float("nan"),
                                "gain_margin_lower_db": float(m.gain_margin_lower_db[k]) if ok else float("nan"),
                                "gain_margin_upper_db": float(m.gain_margin_upper_db[k]) if ok else float("nan"),
                                "bandwidth_hz": float(m.bandwidth_hz[k]) if ok else float("nan"),
                                "ms": float(m.ms[k]) if ok else float("nan"),
                                "stable": bool(lm.stable[k]) if ok else None})
        return out


def analyse_configurations(design: Design, params: ParameterSet | None = None, *,
                           settings: AnalysisSettings | None = None, temperatures: Sequence[float] | None = None,
                           loads: Sequence[float] | None = None, nut_speed: float | None = None,
                           model: PlantModel | None = None) -> ConfigurationAnalysis:
    """Linear models and margins of the primary-active and standby-active configurations.

    Both plants have the two rotors (``standby_motor`` effect): the active
    one driven by its current loop, the other off and dragged (its current
    decays through the inverter's diodes).  Evaluated at the reference
    speed, for each temperature and load.

    Parameters
    ----------
    design : Design
    params : ParameterSet, optional
    settings : AnalysisSettings, optional
        Level and effects (``standby_motor`` is added when missing).
    temperatures, loads : sequence of float, optional
        [degC], [N]; default those of ``settings``.
    nut_speed : float, optional
        [m/s]; default ``settings.reference_speed``.
    model : PlantModel, optional
        The wrapped two-rotor plant (its effects must include ``standby_motor``);
        built from ``settings`` when not given.

    Returns
    -------
    ConfigurationAnalysis
    """
    settings = settings or AnalysisSettings()
    params = params or default_parameters()
    effects = _two_rotor_effects(settings.effects)
    if model is None:
        model = plant_model(settings.level, effects, params, settings=settings.linearization)
    elif "standby_motor" not in model.effects:
        raise ValueError("analyse_configurations: the model must include the standby_motor effect")
    temps = tuple(settings.temperatures if temperatures is None else temperatures)
    loads = tuple(settings.load_forces if loads is None else loads)
    v = settings.reference_speed if nut_speed is None else nut_speed
    out = {}
    for active in ("primary", "standby"):
        grid = ConditionGrid((v,), loads, temps, active)
        out[active] = analyse_loops(design, params, grid, settings=replace(settings, effects=effects), model=model)
    return ConfigurationAnalysis(out["primary"], out["standby"])


def _two_rotor_effects(effects: Sequence[str]) -> tuple[str, ...]:
    return tuple(effects) + (() if "standby_motor" in effects else ("standby_motor",))


# ----------------------------------------------------------------------------------------------------------------
# everything for one design (what the report draws)
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class DesignAnalysis:
    """Everything the analysis report shows for one design.

    Attributes
    ----------
    design : Design
    params : ParameterSet
    settings : AnalysisSettings
    loops : LoopAnalysis
        The grid.
    requirements : RequirementCheck
    limit_cycles : tuple of LimitCycle
    configurations : ConfigurationAnalysis or None
    switching : thsa_control.loops.switching.SwitchoverAnalysis or None
        The nonlinear switch-over transient (None when not run).
    timings : dict
        Wall time of each part [s].
    """

    design: Design
    params: ParameterSet
    settings: AnalysisSettings
    loops: LoopAnalysis
    requirements: RequirementCheck
    limit_cycles: tuple[LimitCycle, ...]
    configurations: ConfigurationAnalysis | None
    switching: object | None
    timings: dict

    def report(self) -> str:
        """Requirements, worst margins and invalid points, as ``thsa report`` prints."""
        from ..report.results import format_design_analysis

        return format_design_analysis(self)

    def to_dict(self) -> dict:
        """``analysis.json`` (format ``thsa-analysis/1``, docs/analysis_schema.json)."""
        from ..report.analysis_json import analysis_to_dict

        return analysis_to_dict(self)

    def plot(self, ax=None):
        """Velocity-loop margin maps coloured against the requirements (a grid analysis); ``ax`` is not supported."""
        from ..report.analysis_plots import plot_margin_maps

        if ax is not None:
            raise ValueError("DesignAnalysis.plot draws a grid of maps in a figure of its own; call "
                             "self.loops.plot(ax=...) or self.requirements.plot(ax=...) to draw into given axes")
        return plot_margin_maps(self.loops)


def analyse_design(design: Design, params: ParameterSet | None = None, *, settings: AnalysisSettings | None = None,
                   switching=True, configurations: bool = True, limit_cycles: bool = True) -> DesignAnalysis:
    """Grid analysis, requirement check, describing functions, configurations and switch-over of a design.

    Parameters
    ----------
    design : Design
    params : ParameterSet, optional
    settings : AnalysisSettings, optional
    switching : bool or SwitchoverAnalysis
        True: run :func:`thsa_control.loops.switching.analyse_switchover` (the
        nonlinear ``motor_fault_switch`` transient over detection delays) at
        the analysis level; False: skip; or a result computed beforehand.
    configurations, limit_cycles : bool
        Run :func:`analyse_configurations` / :func:`describing_functions`.

    Returns
    -------
    DesignAnalysis
    """
    settings = settings or AnalysisSettings()
    params = params or default_parameters()
    timings = {}
    t0 = time.perf_counter()
    # the wrapped plant is built once here and handed to every part (the configurations need the two
    # rotors: the same model when the analysis effects already have them, else one two-rotor model)
    model = plant_model(settings.level, settings.effects, params, settings=settings.linearization)
    loops = analyse_loops(design, params, settings=settings, model=model)
    timings["grid_s"] = time.perf_counter() - t0
    check = check_requirements(loops)
    t0 = time.perf_counter()
    cycles = describing_functions(design, params, settings=settings, model=model) if limit_cycles else ()
    timings["describing_functions_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if configurations:
        two = model if "standby_motor" in model.effects else plant_model(
            settings.level, _two_rotor_effects(settings.effects), params, settings=settings.linearization)
        configs = analyse_configurations(design, params, settings=settings, model=two)
    else:
        configs = None
    timings["configurations_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if switching is True:
        from .switching import analyse_switchover

        sw = analyse_switchover(design, params, level=settings.level)
    else:
        sw = switching or None
    timings["switching_s"] = time.perf_counter() - t0
    return DesignAnalysis(design, params, settings, loops, check, tuple(cycles), configs, sw, timings)
